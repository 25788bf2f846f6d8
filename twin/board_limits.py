"""What the firmware accepts of a rig's load cells, tension limit and motors (firmware/PROTOCOL.md).

A leaf module: the parameter loader checks a robot's rig against these bounds and the device
driver checks every calibration and limit it sends, so both read them here.
"""

from __future__ import annotations

__all__ = ["GAIN_TOLERANCE", "MAX_OFFSET_COUNTS", "MAX_TENSION_LIMIT_N", "MOTOR_BOUNDS", "RATED_GAIN_COUNTS_PER_N",
           "motor_problems"]

# Calibrations the firmware accepts (firmware/PROTOCOL.md, its kGainTolerance and
# kMaxOffsetCounts): counts per N within 25 % either way of the load cells' rated sensitivity
# (the parameter set's sensors.loadcell_gain_counts_per_n, which the host sends with the limits),
# and an unloaded offset within 2^20 counts, an eighth of the 24-bit range. Outside them a
# calibration would blind the tension limit.
GAIN_TOLERANCE = 1.25
MAX_OFFSET_COUNTS = float(2**20)

# Largest per-channel tension limit the firmware accepts (N): its kMaxTensionLimitN.
MAX_TENSION_LIMIT_N = 50.0

# Rated sensitivities the firmware accepts (counts/N; its kMinRatedGainCountsPerN and
# kMaxRatedGainCountsPerN): the largest limit at the largest calibrated gain on the largest offset
# reads below the HX711's saturation, and a count is at most 10 mN.
RATED_GAIN_COUNTS_PER_N = (100.0, (2**23 - 1 - MAX_OFFSET_COUNTS) / (MAX_TENSION_LIMIT_N * GAIN_TOLERANCE))

# Motors the firmware accepts (SET_MOTORS; its kMin/kMax StallForceN, NoLoadSpeedMPerS and
# ReflectedMassKg), as seen at the tendon: the name, unit and range of each value it is sent.
MOTOR_BOUNDS: dict[str, tuple[str, float, float]] = {
    "stall_force_n": ("N", 1.0, 1.0e4),
    "no_load_speed_m_per_s": ("m/s", 1.0e-3, 10.0),
    "reflected_mass_kg": ("kg", 0.01, 1000.0),
}


def motor_problems(values: dict[str, float]) -> list[str]:
    """One line per motor value (at the tendon, named as in :data:`MOTOR_BOUNDS`) that is not
    finite or outside what the firmware accepts; empty when all are fine."""
    problems = []
    for name, (unit, low, high) in MOTOR_BOUNDS.items():
        value = values[name]
        if not low <= value <= high:  # NaN fails too
            problems.append(f"{name} = {value!r}: must be in {low:g}..{high:g} {unit}, what the firmware accepts")
    return problems
