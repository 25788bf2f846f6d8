"""Gains of the board's tension PID (firmware tension mode, :meth:`twin.device.Device.set_gains`):
the firmware's defaults and the tuned set the controllers run on (found by :mod:`twin.tuning`)."""

__all__ = ["DEFAULT_TENSION_GAINS", "TUNED_TENSION_GAINS"]

# The firmware's defaults (firmware/core/controller.cpp).
DEFAULT_TENSION_GAINS = {"kp": 0.003, "ki": 0.3, "kd": 0.0, "output_limit": 0.2}
# The firmware caps the pull at 0.9 × the tension limit itself, so the defaults no longer fault
# and the duty clamp only matters below that cap: 0.035 bounds the stall pull at ~5.4 N.
# ``python -m twin.tuning --quick`` (nominal twin, seed 0) then finds kp ~0.0085 with a slow
# integral (ki ~0.03, 0.58 N RMS on the step rollout); the tip tracker needs a faster integral
# (ki ~0.15, see the tracking stage), and with it kp 0.006 is the better of a kp × ki grid
# (0.70 N RMS against the defaults' 0.73 N).
TUNED_TENSION_GAINS = {"kp": 0.006, "ki": 0.15, "kd": 0.0, "output_limit": 0.035}
