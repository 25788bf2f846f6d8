"""Least-squares identification of parameters from a dataset, with uncertainties.

Shared by the stiffness characterisation (:mod:`twin.experiments.stiffness`) and the
discrepancy workflow (:mod:`twin.discrepancy`): the residuals are the predicted minus measured
tracker positions (m) of every row, the parameters any entries of the parameter set (list-valued
keys by index), optionally fitted in log space (positive moduli spanning decades).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np
from scipy.optimize import least_squares

from twin.data.dataset import Dataset
from twin.data.prediction import predict_rows
from twin.effects import FitParameter
from twin.params import Params

__all__ = ["FitParameter", "ParameterFit", "fit_parameters", "fit_determined", "apply_values", "current_value"]

# Penalty (m per axis) for a row whose prediction fails during a fit: large against any
# plausible error, so the optimiser steers away from parameters the model cannot solve.
_FAILED_ROW_PENALTY_M = 0.05
# Distance from a bound (optimiser variable: log, or value / scale) within which a value is on it.
_BOUND_TOLERANCE = 1e-3
# Finite-difference step in the optimiser's variable (relative above 1).
_DIFF_STEP = 1e-4


@dataclasses.dataclass(frozen=True)
class ParameterFit:
    """The outcome of :func:`fit_parameters`.

    Attributes:
        parameters: what was fitted.
        values: fitted values (in the parameter's own unit).
        std_errors: standard errors from σ²(JᵀJ)⁻¹ (same units; for log parameters the delta method).
        correlation: (p, p) correlation matrix of the estimates.
        rms_m: RMS of the 3-D tip error |p̂ − p*| over the rows at the optimum (m).
        residual_sigma_m: the per-axis residual standard deviation σ (m).
        converged: the optimiser met its tolerance; ``message`` says why it stopped.
        failed_rows: rows whose prediction failed at the optimum.
        evaluations: model evaluations spent.
        params: the parameter set with the fitted values written in (source ``fitted``).
    """

    parameters: tuple[FitParameter, ...]
    values: np.ndarray
    std_errors: np.ndarray
    correlation: np.ndarray
    rms_m: float
    residual_sigma_m: float
    converged: bool
    message: str
    failed_rows: int
    evaluations: int
    params: Params
    #: (3 · fitted rows, p) ∂(p̂ − p*)/∂value at the optimum (m per parameter unit), rows' x, y, z
    #: in turn: how each parameter moves the residuals, for what a given error would shift it.
    jacobian: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)

    def confidence_interval(self, level_sigma: float = 1.96) -> np.ndarray:
        """(p, 2) intervals value ± level_sigma · std_error (default ≈ 95%)."""
        return np.stack([self.values - level_sigma * self.std_errors, self.values + level_sigma * self.std_errors], 1)

    def undetermined(self) -> list[int]:
        """Indices of the parameters the data leave undetermined: a standard error above half the
        value (log-fitted) or above the typical size ``scale`` (others), or a value on a physical
        bound (:attr:`FitParameter.bounds`), where the data pushed it past what is possible."""
        out = []
        for i, (p, value, std) in enumerate(zip(self.parameters, self.values, self.std_errors)):
            limit = 0.5 * abs(value) if p.log else p.scale
            if not np.isfinite(std) or std > limit or _at_bound(p, value):
                out.append(i)
        return out

    def table(self) -> list[dict]:
        ci = self.confidence_interval()
        return [{"parameter": p.label, "value": float(v), "std_error": float(s), "ci95_low": float(c[0]),
                 "ci95_high": float(c[1])} for p, v, s, c in zip(self.parameters, self.values, self.std_errors, ci)]


def apply_values(params: Params, parameters: Sequence[FitParameter], values, source: str) -> Params:
    """``params`` with each fitted scalar written into its key (list keys at their index), and
    the keys a parameter carries (:attr:`FitParameter.follows`) moved with it."""
    changes: dict[str, Any] = {}
    for p, v in zip(parameters, values):
        if p.index is None:
            changes[p.key] = float(v)
        else:
            current = list(changes.get(p.key, params.get(p.key)))
            current[p.index] = float(v)
            changes[p.key] = current
        for key, slope in p.follows:
            changes[key] = float(changes.get(key, params.get(key))) + slope * (float(v) - current_value(params, p))
    return params.replace(changes, source=source)


def _to_z(p: FitParameter, value: float) -> float:
    """The optimiser's variable for a value: log(value), or value / scale."""
    if p.log:
        return math.log(value) if value > 0 else -math.inf
    return value / p.scale


def _at_bound(p: FitParameter, value: float) -> bool:
    """Whether ``value`` sits on one of ``p``'s bounds (a thousandth of the variable's unit)."""
    z = _to_z(p, value)
    return any(math.isfinite(b) and abs(z - _to_z(p, b)) < _BOUND_TOLERANCE for b in p.bounds if not (p.log and b <= 0))


def current_value(params: Params, p: FitParameter) -> float:
    """The value ``p`` has in ``params`` (a list key's entry at its index)."""
    value = params.get(p.key)
    return float(value if p.index is None else value[p.index])


def _covariance(jac: np.ndarray, sigma2: float) -> np.ndarray:
    """sigma2 · (JᵀJ)⁻¹ on the directions the data determine; inf for the parameters they do not.

    A parameter that moves no residual (its column of J numerically zero, or a combination of
    columns that cancels) makes JᵀJ singular. Inverting it whole would give every parameter an
    infinite or meaningless variance — a well-determined E would be dropped with an
    undetermined G. The eigen-directions below 1e-12 of the largest are left out, and only the
    parameters with weight in them are marked undetermined (variance inf, correlations NaN).
    """
    k = jac.shape[1]
    if not np.all(np.isfinite(jac)):
        return np.full((k, k), np.inf)
    w, v = np.linalg.eigh(jac.T @ jac)
    good = w > max(float(w.max()), 0.0) * 1e-12 if w.size else w.astype(bool)
    cov = sigma2 * (v[:, good] / w[good]) @ v[:, good].T
    loose = np.sum(v[:, ~good] ** 2, axis=1) > 1e-6
    cov[loose, :] = np.nan
    cov[:, loose] = np.nan
    cov[loose, loose] = np.inf
    return cov


def fit_parameters(dataset: Dataset, params: Params, parameters: Sequence[FitParameter], *,
                   x0: Sequence[float] | None = None, source: str = "fitted", max_evaluations: int = 200,
                   rows: np.ndarray | None = None, guesses: list | None = None,
                   tolerance: float = 1e-10) -> ParameterFit:
    """Fit ``parameters`` so the model's tip predictions best match the measured tips.

    Each parameter stays within its :attr:`FitParameter.bounds`; each row's solve starts from
    its own last solution (:func:`twin.data.prediction.predict_rows`), so an evaluation near the
    last one costs a Newton step or two per row.

    Args:
        dataset: the measurements (its base rotation and loads are used).
        params: the parameter set to start from (other values stay as they are).
        parameters: what to fit.
        x0: starting values (default: the current values in ``params``; moved inside the bounds).
        source: provenance written for the fitted keys.
        max_evaluations: cap on model evaluations (each predicts every row).
        rows: boolean mask of the rows to fit on (default all).
        guesses: per fitted row, a solution to start its first solve from (e.g. of ``params``);
            not changed.
        tolerance: the optimiser stops when a step changes the variables (log, or value / scale)
            or the gradient by less than this, or the cost by less than a hundredth of it
            (relative).

    Raises:
        ValueError: nothing to fit, or the starting point cannot be predicted at all.
        DatasetError: ``params`` is of a robot with another tendon count than the data's.
    """
    parameters = tuple(parameters)
    if not parameters:
        raise ValueError("fit_parameters: no parameters to fit")
    dataset.check_robot(params)
    data = dataset if rows is None else dataset.subset(rows)
    start = np.array([current_value(params, p) for p in parameters] if x0 is None else x0, dtype=float)
    for p, v in zip(parameters, start):
        if p.log and v <= 0:
            raise ValueError(f"{p.label} = {v!r}: a log-fitted parameter must start > 0")
    scales = np.array([1.0 if p.log else p.scale for p in parameters])

    def to_values(z):
        return np.array([math.exp(zi) if p.log else zi * s for p, zi, s in zip(parameters, z, scales)])

    lower = np.array([_to_z(p, p.bounds[0]) if not (p.log and p.bounds[0] <= 0) else -np.inf for p in parameters])
    upper = np.array([_to_z(p, p.bounds[1]) for p in parameters])
    # least_squares starts strictly inside the bounds.
    margin = 10 * _BOUND_TOLERANCE
    z0 = np.clip([_to_z(p, v) for p, v in zip(parameters, start)], lower + margin, upper - margin)
    base_rotation = data.base_rotation
    tensions, masses, lengths, measured = data.tensions_n, data["tip_mass_kg"], data.lengths_m, data.tip_positions_m
    solutions = list(guesses) if guesses is not None else [None] * len(data)
    evaluations = 0
    failed = [0]
    last: list = [None, None]  # the last variable evaluated and its residuals

    def residuals(z):
        nonlocal evaluations
        evaluations += 1
        try:
            trial = apply_values(params, parameters, to_values(z), source)
        except (ValueError, OverflowError):  # out of range, or a log parameter stepped past exp's range
            return np.full(measured.size, _FAILED_ROW_PENALTY_M)
        tip, ok, _, _ = predict_rows(trial, base_rotation, tensions, masses, lengths, guesses=solutions,
                                  sliding_state=data.sliding_state)
        err = tip - measured
        err[~ok] = _FAILED_ROW_PENALTY_M
        failed[0] = int(np.count_nonzero(~ok))
        last[:] = [np.array(z, dtype=float), err.ravel()]
        return last[1]

    def jacobian(z):
        """Forward differences of _DIFF_STEP in the variable (at least that, also where it is 0;
        backwards where a bound is nearer): the solves are warm-started, so their results agree
        to the solver's tolerance, not to rounding, and a step must move the tip well beyond it."""
        r0 = last[1] if last[0] is not None and np.array_equal(last[0], z) else residuals(z)
        out = np.empty((r0.size, len(z)))
        for i in range(len(z)):
            h = _DIFF_STEP * max(1.0, abs(z[i]))
            if z[i] + h > upper[i]:
                h = -h
            step = np.array(z, dtype=float)
            step[i] += h
            out[:, i] = (residuals(step) - r0) / h
        last[:] = [np.array(z, dtype=float), r0]
        return out

    residuals(z0)
    if failed[0] == len(measured):
        raise ValueError("fit_parameters: no row can be predicted at the starting parameters")
    result = least_squares(residuals, z0, jac=jacobian, method="trf", x_scale="jac", bounds=(lower, upper),
                           max_nfev=max_evaluations, xtol=tolerance, ftol=tolerance * 1e-2, gtol=tolerance)
    r = residuals(result.x)
    values = to_values(result.x)
    jac = result.jac
    dof = max(1, r.size - len(parameters))
    sigma2 = float(r @ r) / dof
    cov_z = _covariance(jac, sigma2)
    # Delta method: d value / d z is value for log parameters, the scale otherwise.
    dvdz = np.array([v if p.log else s for p, v, s in zip(parameters, values, scales)])
    # An undetermined log parameter may have run off to a huge value: its variance is inf anyway.
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        cov = cov_z * np.outer(dvdz, dvdz)
        std = np.sqrt(np.clip(np.diag(cov), 0, None))
        corr = cov / np.outer(std, std)
        jac_values = jac / dvdz[None, :]
    err3 = r.reshape(-1, 3)
    return ParameterFit(
        parameters=parameters,
        values=values,
        std_errors=std,
        correlation=corr,
        rms_m=float(np.sqrt(np.mean(np.sum(err3**2, axis=1)))),
        residual_sigma_m=math.sqrt(sigma2),
        converged=bool(result.status > 0),
        message=str(result.message),
        failed_rows=failed[0],
        evaluations=evaluations,
        params=apply_values(params, parameters, values, source),
        jacobian=jac_values,
    )


def fit_determined(dataset: Dataset, params: Params, parameters: Sequence[FitParameter], *,
                   x0: Sequence[float] | None = None,
                   **options) -> tuple[ParameterFit | None, list[tuple[FitParameter, float, float]]]:
    """:func:`fit_parameters`, then without what the data leave undetermined, until all is determined.

    A parameter the data do not determine (:meth:`ParameterFit.undetermined`: too uncertain, or
    on a physical bound) is dropped and the rest refitted, so it keeps its value in ``params``
    and is never written into a parameter set as if measured.

    Args:
        dataset, params, parameters, x0: as for :func:`fit_parameters`.
        **options: the other keywords of :func:`fit_parameters`.

    Returns:
        (the fit of the determined parameters, or None when none is; the dropped ones as
        (parameter, value, standard error) when they were dropped).
    """
    parameters = list(parameters)
    start = list(x0) if x0 is not None else [current_value(params, p) for p in parameters]
    dropped: list[tuple[FitParameter, float, float]] = []
    while parameters:
        fit = fit_parameters(dataset, params, parameters, x0=start, **options)
        loose = fit.undetermined()
        if not loose:
            return fit, dropped
        dropped += [(parameters[i], float(fit.values[i]), float(fit.std_errors[i])) for i in loose]
        parameters = [p for i, p in enumerate(parameters) if i not in loose]
        start = [float(v) for i, v in enumerate(fit.values) if i not in loose]
    return None, dropped
