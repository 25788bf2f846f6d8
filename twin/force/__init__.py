"""Intrinsic tip force sensing: the tip wrench from tendon tensions and the tracked tip pose.

Example:
    >>> from twin import load_params
    >>> from twin.force import estimate_tip_wrench
    >>> # est = estimate_tip_wrench(load_params(), tensions_n, tip_position_m, tip_rotation)
"""

from typing import TYPE_CHECKING

from twin.lazy import lazy_exports

if TYPE_CHECKING:
    from twin.force.estimator import WrenchEstimate, estimate_tip_wrench, rotation_vector

# name → the module that defines it, imported when the name is first used
_EXPORTS = {
    "WrenchEstimate": "twin.force.estimator", "estimate_tip_wrench": "twin.force.estimator",
    "rotation_vector": "twin.force.estimator",
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["WrenchEstimate", "estimate_tip_wrench", "rotation_vector"]
