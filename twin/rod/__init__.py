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

import importlib

# name → the module that defines it
_EXPORTS = {
    "RodModel": "twin.rod.model", "TendonRoute": "twin.rod.model",
    "TipJacobian": "twin.rod.jacobian", "solve_with_jacobian": "twin.rod.jacobian", "tip_jacobian": "twin.rod.jacobian",
    "ConvergenceError": "twin.rod.solver", "LoadCase": "twin.rod.solver", "NewtonIteration": "twin.rod.solver",
    "Predictor": "twin.rod.solver", "RodSolution": "twin.rod.solver", "SolverStatus": "twin.rod.solver",
    "solve": "twin.rod.solver", "solve_batch": "twin.rod.solver",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'twin.rod' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | _EXPORTS.keys())
