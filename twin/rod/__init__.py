"""The coupled Cosserat rod–tendon predictor (Rucker & Webster 2011), compiled with Numba.

The names below load their module (and Numba) on first use, so that importing a light module of
the package (``twin.rod.grid``), or a command's parser, does not compile or load the kernels.

Example:
    >>> from twin import load_params
    >>> from twin.rod import RodModel, solve
    >>> from twin.pose import HORIZONTAL
    >>> model = RodModel.from_params(load_params())
    >>> sol = solve(model, [2.0, 1.35, 1.35, 1.35], base_rotation=HORIZONTAL)
    >>> sol.converged
    True
"""

from typing import TYPE_CHECKING

from twin.lazy import lazy_exports

if TYPE_CHECKING:
    from twin.rod.jacobian import TipJacobian, solve_with_jacobian, tip_jacobian
    from twin.rod.model import RodModel, TendonRoute
    from twin.rod.solver import (ConvergenceError, LoadCase, NewtonIteration, Predictor, RodSolution, SolverStatus,
                                 solve, solve_batch)

# name → the module that defines it
_EXPORTS = {
    "RodModel": "twin.rod.model", "TendonRoute": "twin.rod.model",
    "TipJacobian": "twin.rod.jacobian", "solve_with_jacobian": "twin.rod.jacobian", "tip_jacobian": "twin.rod.jacobian",
    "ConvergenceError": "twin.rod.solver", "LoadCase": "twin.rod.solver", "NewtonIteration": "twin.rod.solver",
    "Predictor": "twin.rod.solver", "RodSolution": "twin.rod.solver", "SolverStatus": "twin.rod.solver",
    "solve": "twin.rod.solver", "solve_batch": "twin.rod.solver",
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = sorted(_EXPORTS)
