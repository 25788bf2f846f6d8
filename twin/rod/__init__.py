"""The coupled Cosserat rod–tendon predictor (Rucker & Webster 2011), compiled with Numba.

Example:
    >>> from twin import load_params
    >>> from twin.rod import RodModel, solve
    >>> from twin.pose import HORIZONTAL
    >>> model = RodModel.from_params(load_params())
    >>> sol = solve(model, [2.0, 1.35, 1.35, 1.35], base_rotation=HORIZONTAL)
    >>> sol.converged
    True
"""

from twin.rod.model import RodModel, TendonRoute
from twin.rod.jacobian import TipJacobian, solve_with_jacobian, tip_jacobian
from twin.rod.solver import (ConvergenceError, LoadCase, NewtonIteration, Predictor, RodSolution, SolverStatus, solve,
                             solve_batch)

__all__ = [
    "ConvergenceError", "LoadCase", "NewtonIteration", "Predictor", "RodModel", "RodSolution", "SolverStatus",
    "TendonRoute", "TipJacobian", "solve", "solve_batch", "solve_with_jacobian", "tip_jacobian",
]
