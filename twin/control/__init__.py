"""Control on top of the device interface: load compensation from the Cosserat predictor, the
length-vs-tension study of an antagonistic pair, the tension PID gains (tuned against the env
by :mod:`twin.tuning`, which sits above the env) and whether the board's loops settle
(:mod:`twin.control.settling`, ``twin bench hold``).

Example:
    >>> from twin import load_params
    >>> from twin.rod import RodModel
    >>> from twin.pose import HORIZONTAL
    >>> from twin.control import hold_tensions
    >>> plan = hold_tensions(RodModel.from_params(load_params()), [2.0, 1.35, 1.2, 1.35],
    ...                      [0.0, 0.0, -0.0981], base_rotation=HORIZONTAL, floor_n=1.0)
    >>> plan.reached
    True
"""

from typing import TYPE_CHECKING

from twin.lazy import lazy_exports

if TYPE_CHECKING:
    from twin.control.compensation import Compensation, compensate_tensions, correct_tensions, hold_tensions
    from twin.control.pretension import pretension_straight

# name → the module that defines it, imported when the name is first used
_EXPORTS = {
    "Compensation": "twin.control.compensation", "compensate_tensions": "twin.control.compensation",
    "correct_tensions": "twin.control.compensation", "hold_tensions": "twin.control.compensation",
    "pretension_straight": "twin.control.pretension",
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["Compensation", "compensate_tensions", "correct_tensions", "hold_tensions", "pretension_straight"]
