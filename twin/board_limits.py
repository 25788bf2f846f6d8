"""What the firmware accepts of a rig's load cells and tension limit (firmware/PROTOCOL.md).

A leaf module: the parameter loader checks a robot's rig against these bounds and the device
driver checks every calibration and limit it sends, so both read them here.
"""

from __future__ import annotations

__all__ = ["GAIN_TOLERANCE", "MAX_OFFSET_COUNTS", "MAX_TENSION_LIMIT_N", "RATED_GAIN_COUNTS_PER_N"]

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
