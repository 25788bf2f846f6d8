"""Intrinsic tip force sensing: the tip wrench from tendon tensions and the tracked tip pose.

Example:
    >>> from twin import load_params
    >>> from twin.force import estimate_tip_wrench
    >>> # est = estimate_tip_wrench(load_params(), tensions_n, tip_position_m, tip_rotation)
"""

from twin.force.estimator import WrenchEstimate, estimate_tip_wrench, rotation_vector

__all__ = ["WrenchEstimate", "estimate_tip_wrench", "rotation_vector"]
