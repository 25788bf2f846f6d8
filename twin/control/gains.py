"""Gains of the board's tension PID (firmware tension mode, :meth:`twin.device.Device.set_gains`):
the firmware's defaults and the tuned set the controllers run on (found by :mod:`twin.tuning`)."""

__all__ = ["DEFAULT_TENSION_GAINS", "TUNED_TENSION_GAINS"]

# The firmware's defaults (firmware/core/controller.cpp).
DEFAULT_TENSION_GAINS = {"kp": 0.003, "ki": 0.3, "kd": 0.0, "output_limit": 0.2}
# ``python -m twin.tuning --quick`` (nominal twin, seed 0) moves the duty clamp from 0.2
# to ~0.037 (the step rollout's 10 N fault cost → 0.66 N RMS); kp was then lowered to 0.001 by
# hand, because at the 1 N floor of the compensation trial kp 0.003 still drove the slack ↔ taut
# limit cycles that tripped the limit. A clamp of 0.035 bounds the stall pull at ~5.4 N, under the
# 6 N limit.
TUNED_TENSION_GAINS = {"kp": 0.001, "ki": 0.3, "kd": 0.0, "output_limit": 0.035}
