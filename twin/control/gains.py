"""Gains of the board's tension PID (firmware tension mode, :meth:`twin.driver.Device.set_gains`):
the firmware's defaults and the tuned set the controllers run on (found by :mod:`twin.tuning`)."""

from twin.params import Params

__all__ = ["DEFAULT_TENSION_GAINS", "TUNED_TENSION_GAINS", "PROPORTIONAL_LOOP_GAIN", "tension_gains_for"]

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
# The proportional loop gain of the tension loop on a rig: kp (duty/N) times the stall force at
# full duty (N), the firmware default's 0.003 /N × 153.8 N (firmware/core/controller.cpp). A
# tendon that friction sticks in the disc holes is a stiff load (tendon against 2.7 kg of
# reflected rotor, a lightly damped 20-40 Hz resonance behind the 80 Hz load cell) on which the
# tuned kp's 0.92 rang: `twin bench hold` at μ = 0.3, 0.6 N peak to peak on the 100 mm robot and
# 0.065 N on the helical one; at 0.46 every robot of the zoo holds within the load cells' noise
# for μ 0-0.3 (measured on the twin, README "Tension mode under friction").
PROPORTIONAL_LOOP_GAIN = 0.46


def tension_gains_for(params: Params) -> dict:
    """The tuned gains for the rig of ``params``: kp (duty per newton) the
    :data:`PROPORTIONAL_LOOP_GAIN` over this rig's stall force (``rig.motor_stall_force_n``), so
    that a tendon friction sticks does not make the loop ring; ki and kd as tuned, scaled by the
    tuned rig's stall pull over this rig's, so that an integrated newton of error asks the same
    pull of another motor; the duty clamp scaled so the clamped stall pull is the same share of
    this rig's ``rig.tension_limit_n`` as the tuned clamp's is of the endoscope's 6 N (0.90): a
    rig with a 30 N limit can pull 27 N instead of being held at 5.4 N, far under what a stiff
    robot needs to bend."""
    share = TUNED_TENSION_GAINS["output_limit"] * _TUNED_STALL_N / _TUNED_LIMIT_N
    stall_n = params.rig.motor_stall_force_n
    scale = _TUNED_STALL_N / stall_n
    return {**TUNED_TENSION_GAINS, **{k: TUNED_TENSION_GAINS[k] * scale for k in ("ki", "kd")},
            "kp": PROPORTIONAL_LOOP_GAIN / stall_n,
            "output_limit": min(1.0, share * params.rig.tension_limit_n / stall_n)}
