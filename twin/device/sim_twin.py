"""The twin behind a ``sim://`` device: its ground truth and what only a simulation can do.

Code above the device layer (the env, experiments, tests) reads the twin's true state and resets
it through :class:`SimTwin` (``device.twin``) and never through the transport, the emulated
board or the plant, which belong to the device layer. On a rig there is no such thing:
``device.twin`` raises there (:attr:`twin.driver.Device.twin`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from twin.device.board import EmulatedBoard
    from twin.device.sim_fixture import SimFixture
    from twin.params import Params
    from twin.sim.events import EventSchedule, HiddenEvent
    from twin.sim.plant import DriveMode

__all__ = ["SimTwin"]


class SimTwin:
    """Ground truth and reset of an emulated board's plant.

    Args:
        board: the emulated board (``sim://``, or the board of a
            :class:`twin.device.pty_board.PtyBoard`).
        fixture: the fixture acting on it (``device.fixture`` on ``sim://``); None when the
            host's fixture is elsewhere (a pseudo-terminal board's host asks an operator).

    Attributes:
        fixture: the :class:`twin.device.sim_fixture.SimFixture`, or None.
    """

    def __init__(self, board: EmulatedBoard, fixture: SimFixture | None = None):
        self._board = board
        self.fixture = fixture
        self._changes: EventSchedule | None = None

    @property
    def params(self) -> Params:
        """The twin's parameter set now (with the changes :meth:`change` made)."""
        return self._board.plant.params

    def change(self, event: HiddenEvent) -> None:
        """Make the change ``event`` describes (:mod:`twin.sim.events`, its time ignored) to the
        twin now: how a shadow re-calibrates the parameter it found changed."""
        from twin.sim.events import EventSchedule

        if self._changes is None:
            self._changes = EventSchedule([])
        self._changes.apply_now(self._board.plant, event)

    def reset(self, seed: int | None = None) -> None:
        """Back to the twin's start (straight, at rest, no tip mass, holder released; sensor
        noise reseeded with ``seed``, or the last seed if None) and power-cycle the board on it:
        the firmware starts afresh (disabled, no handshake), so the host must
        :meth:`twin.driver.Device.reconnect` before it commands again. Much faster than opening
        a new ``sim://`` device, which rebuilds the MuJoCo model."""
        self._board.plant.reset(seed)
        self._board.power_cycle()

    @property
    def time_s(self) -> float:
        """Simulated time since the last :meth:`reset` (s); telemetry's ``time_s`` is the board's
        clock, which restarts at each power cycle."""
        return self._board.plant.time_s

    @property
    def tick_s(self) -> float:
        """The emulated board's control tick (s), the finest step at which the twin's truth can
        be sampled between telemetry frames."""
        from twin.device.board import TICK_S
        return TICK_S

    def tip_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """True tip position (3,) m and rotation (3, 3), world frame, base at the origin."""
        return self._board.plant.tip_pose()

    def backbone_positions_m(self) -> np.ndarray:
        """(N + 2, 3) true positions of the base, each station and the tip, world frame (m)."""
        return self._board.plant.backbone_positions_m()

    def spool_positions_m(self) -> np.ndarray:
        """(N,) true travel of each spool's rim from its zero (m): what a perfect encoder reads."""
        return self._board.plant.spool_positions_m()

    def true_tensions_n(self) -> np.ndarray:
        """(N,) true tension at the spool end of each tendon (N): what a perfect load cell reads."""
        return self._board.plant.true_tensions_n()

    @property
    def sliding_state(self) -> np.ndarray | None:
        """(N,) ground truth: the sliding state σ the twin's tendon friction is in (+1 pulled …
        −1 released), or None when the twin has no friction; what a rig's record of it
        (:class:`twin.effects.SlidingState`) is checked against."""
        return self._board.plant.sliding_state

    def peak_tensions_n(self) -> np.ndarray:
        """(N,) largest true tension of each tendon (N) at any physics step since
        :meth:`clear_peak_tensions` or :meth:`reset`: what a bound on tension must hold, including
        what happens between load-cell samples."""
        return self._board.plant.peak_tensions_n()

    def clear_peak_tensions(self) -> None:
        """Start :meth:`peak_tensions_n` afresh from the tensions now."""
        self._board.plant.clear_peak_tensions()

    @property
    def tip_mass_kg(self) -> float:
        """The nominal mass hung at the tip (kg)."""
        return self._board.plant.tip_mass_kg

    @property
    def holder_engaged(self) -> bool:
        """True while the reference holder clamps the discs straight."""
        return self._board.plant.holder_engaged

    @property
    def held_tensions_n(self) -> np.ndarray | None:
        """Tensions (N) that calibration masses put on the tendons instead of the motors, or
        None while the motors drive."""
        return self._board.held_tensions_n

    @property
    def drive_mode(self) -> DriveMode:
        """How the spools are driven (:class:`twin.sim.plant.DriveMode`): ``"pwm"`` (the
        firmware's duty), ``"coast"`` (H-bridges off: disabled or faulted), ..."""
        return self._board.plant.mode

    def camera(self, **options):
        """An offscreen :class:`twin.sim.render.TwinCamera` on the twin (``options`` its size and
        view), for pictures and videos of the twin as it runs.

        Raises:
            twin.sim.render.RenderError: no OpenGL backend.
        """
        from twin.sim.render import TwinCamera

        return TwinCamera(self._board.plant, **options)

    def viewer(self):
        """MuJoCo's interactive viewer on the twin (needs a display), passive: call its ``sync()``
        after each step; ``close()`` it at the end."""
        import mujoco.viewer

        return mujoco.viewer.launch_passive(self._board.plant.model, self._board.plant.data)
