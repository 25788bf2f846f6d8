"""The fixture of ``sim://`` and of ``twin emulate``: the experiments' manual steps done on the
twin's plant (:class:`twin.driver.fixture.Fixture` names them)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Iterable

import numpy as np

from twin.driver.fixture import Fixture, check_channels, check_mass

if TYPE_CHECKING:
    from twin.device.board import EmulatedBoard

__all__ = ["SimFixture"]


class SimFixture(Fixture):
    """Fixture actions on the emulated board's plant.

    Calibration masses: the plant models no mass hanging over a pulley, so the board pulls each
    tendon at the spool with the mass's weight (m·g with the twin's gravity) by ideal tension
    sources, and the load cells read that tension; meanwhile the firmware's motor outputs are
    ignored (see :meth:`EmulatedBoard.hold_tensions`) until :meth:`remove_calibration_masses`.

    Args:
        board: the emulated board.
        settle: lets simulated time pass (s), e.g. ``device.wait``.
        settle_s: simulated time each action is given to come to rest (s).
    """

    def __init__(self, board: EmulatedBoard, settle: Callable[[float], None], *, settle_s: float = 0.5):
        self._board = board
        self._settle = settle
        self.settle_s = settle_s
        self._calibration_g = np.zeros(board.plant.tendon_count)

    def hang_tip_mass(self, mass_kg: float) -> None:
        self._board.plant.set_tip_mass_kg(check_mass("mass_kg", mass_kg))
        self._settle(self.settle_s)

    def apply_tip_load(self, force_n=(0.0, 0.0, 0.0), moment_nm=(0.0, 0.0, 0.0)) -> None:
        self._board.plant.set_tip_load(force_n, moment_nm)
        self._settle(self.settle_s)

    def engage_holder(self) -> None:
        # A rod that friction holds bent is clamped in stages (Plant.engage_holder says why).
        # Imported here: listing the sim:// scheme imports this module, and must not load MuJoCo.
        from twin.sim.plant import HOLDER_STAGE_S
        plant = self._board.plant
        for _ in range(plant.engage_holder() - 1):
            self._settle(HOLDER_STAGE_S)
            plant.close_holder()
        self._settle(self.settle_s)

    def release_holder(self) -> None:
        self._board.plant.release_holder()
        self._settle(self.settle_s)

    def hang_calibration_mass(self, mass_g: float, channels: Iterable[int]) -> None:
        mass_g = check_mass("mass_g", mass_g)
        self._calibration_g[list(check_channels(channels, len(self._calibration_g)))] = mass_g
        gravity = self._board.plant.params.environment.gravity_m_s2
        self._board.hold_tensions(self._calibration_g * 1e-3 * gravity)
        self._settle(self.settle_s)

    def remove_calibration_masses(self) -> None:
        self._calibration_g[:] = 0.0
        self._board.release_tensions()
        self._settle(self.settle_s)
