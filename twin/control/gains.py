"""Gains of the board's tension PID (firmware tension mode, :meth:`twin.driver.Device.set_gains`):
the firmware's defaults and the tuned set the controllers run on (found by :mod:`twin.tuning`)."""

from twin.params import Params

__all__ = ["DEFAULT_TENSION_GAINS", "TUNED_TENSION_GAINS", "tension_gains_for"]

# The firmware's defaults (firmware/core/controller.cpp).
DEFAULT_TENSION_GAINS = {"kp": 0.003, "ki": 0.3, "kd": 0.0, "output_limit": 0.2}
# The firmware caps the pull at 0.9 × the tension limit itself, so the defaults no longer fault
# and the duty clamp only matters below that cap: 0.035 bounds the stall pull at ~5.4 N.
# ``python -m twin.tuning --quick`` (nominal twin, seed 0) then finds kp ~0.0085 with a slow
# integral (ki ~0.03, 0.58 N RMS on the step rollout); the tip tracker needs a faster integral
# (ki ~0.15, see the tracking stage), and with it kp 0.006 is the better of a kp × ki grid
# (0.70 N RMS against the defaults' 0.73 N).
TUNED_TENSION_GAINS = {"kp": 0.006, "ki": 0.15, "kd": 0.0, "output_limit": 0.035}
# The rig the gains were tuned on (models/endoscope): its stall pull, 0.5 N·m on a 3.25 mm
# spool (N), and its tension limit (N). The tuned clamp holds 5.38 N of it, 0.90 of the limit.
_TUNED_STALL_N = 0.5 / 0.00325
_TUNED_LIMIT_N = 6.0


def tension_gains_for(params: Params) -> dict:
    """The tuned gains for the rig of ``params``: kp, ki and kd (duty per newton of error)
    scaled by the tuned rig's stall pull over this rig's (``rig.motor_stall_force_n``), so that a
    newton of error asks the same pull of another motor, and the duty clamp scaled so the
    clamped stall pull is the same share of this rig's ``rig.tension_limit_n`` as the tuned
    clamp's is of the endoscope's 6 N (0.90). The endoscope's rig gets
    :data:`TUNED_TENSION_GAINS` itself; a rig with a 30 N limit can pull 27 N instead of being
    held at 5.4 N, far under what a stiff robot needs to bend."""
    share = TUNED_TENSION_GAINS["output_limit"] * _TUNED_STALL_N / _TUNED_LIMIT_N
    stall_n = params.rig.motor_stall_force_n
    scale = _TUNED_STALL_N / stall_n
    return {**TUNED_TENSION_GAINS, **{k: TUNED_TENSION_GAINS[k] * scale for k in ("kp", "ki", "kd")},
            "output_limit": min(1.0, share * params.rig.tension_limit_n / stall_n)}
