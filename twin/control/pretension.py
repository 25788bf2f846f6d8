"""Bring any device to the pretensioned straight start every controller run begins from.

Tension mode needs taut tendons and a calibration: started from slack tendons the tension loop
winds the line in at full clamp until it bites, and the tension spikes past the limit. So the
tendons are first pulled to the pretension by dead weights over the load-cell pulleys (the
fixture: ideal tension sources on the twin, the operator on the rig) while the reference holder
keeps the endoscope straight; the board then takes over in the requested mode, bumplessly, and
the weights come off.

The weights go on *before* the holder closes: equal tensions pull a bent or loaded endoscope back
near straight first, so the holder does not have to snap it there.
"""

from __future__ import annotations

import numpy as np

from twin.experiments.protocols import apply_calibration, nominal_calibration, pretension
from twin.params import Params

__all__ = ["pretension_straight"]


def pretension_straight(device, params: Params, *, mode: str, tension_n: float | None = None,
                        calibration: dict | None = None, limit_n: float | None = None) -> np.ndarray:
    """Pretension the straight endoscope and leave the board enabled in ``mode``, holder released.

    Args:
        device: a connected :class:`twin.driver.Device` with a fixture.
        params: the parameter set (pretension, gravity and the nominal calibration).
        mode: ``"lengths"``, ``"pairs"`` or ``"tensions"``: the mode the board is enabled in.
        tension_n: pretension per tendon (N); default ``tendons.pretension_n``.
        calibration: ``{"gain_counts_per_n": [...], "offset_counts": [...]}`` for the load cells;
            default the parameter set's nominal one.
        limit_n: the board's tension limit (N); default ``rig.tension_limit_n``.

    Returns:
        (N,) relative tendon lengths (m) of the pretensioned straight endoscope, one per tendon:
        the origin of length setpoints.

    Raises:
        ValueError: ``tension_n`` is not in (0, limit).
    """
    tension = params.tendons.pretension_n if tension_n is None else float(tension_n)
    limit = params.rig.tension_limit_n if limit_n is None else float(limit_n)
    if not 0 < tension < limit:
        raise ValueError(f"tension_n = {tension!r}: must be in (0, {limit}) N")
    calibration = calibration or nominal_calibration(params)
    device.disable()
    device.fixture.hang_tip_mass(0.0)
    apply_calibration(device, calibration)
    device.set_limits(tension_limit_n=limit)
    pretension(device, params, mode=mode, tension_n=tension, tare_lengths=True)
    device.fixture.release_holder()
    return device.latest().tendon_lengths_m.copy()
