"""Known causes outside the effect library, fitted only to check that a named effect is the only
explanation the data allow.

A static sweep sees an effect only through the tip positions it moves, and several physical
causes move them alike. Three that no parameter of the model carries are common on rigs and
each mimics a library effect on a validation sweep:

``tip_moment``
    a constant external moment at the tip (N·m, world frame: x, y, z), as a cable, a tube or a
    contact puts there. About the axis of an antagonist pair it is the moment a load-cell offset
    between the pair's cells makes.
``tracker_rotation``
    the tracker's frame turned about the base origin (rotation vector, deg, world axes), as a
    registration error leaves it: every measured position is R · p. Near the straight pose it
    moves the tip as a base tilt, a tracker offset or a load-cell offset does.
``intrinsic_curvature``
    the backbone's unloaded curvature (body frame, 1/m, about the body x and y axes), as a
    backbone set in a curve has (:attr:`twin.rod.RodModel.precurvature_per_m`). A constant
    internal moment along the whole rod, it is what a load-cell offset between antagonists
    makes, for every pose and load.

A probe is never named and never written into a parameter set: the workflow fits each on the
training rows (:func:`fit_probe`) and scores it on the held-out rows as a candidate, and when
one explains the data as well as the named effect, the answer is ``ambiguous``; when one
explains them better, the library's answer is not the explanation (``unexplained``), see
:mod:`twin.discrepancy.workflow`. Each probe names the experiments that tell it from the library
(:attr:`Probe.deciding_experiments`, in :data:`twin.discrepancy.decide.MANUAL_EXPERIMENTS` or
:data:`twin.discrepancy.decide.DESIGNS`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from twin.data.dataset import Dataset
from twin.data.fitting import _covariance
from twin.data.prediction import predict_rows
from twin.params import Params
from twin.rod import RodModel

__all__ = ["PROBES", "Probe", "ProbeFit", "fit_probe"]

# Error (m per axis) charged for a row a probe's model cannot predict (as the candidates' fits).
_FAILED_ROW_PENALTY_M = 0.05
# Finite-difference step of the probes' fits, in each parameter's typical size: the solves are
# warm-started and agree to the solver's tolerance, far below what such a step moves the tip.
_DIFF_STEP = 1e-3


@dataclasses.dataclass(frozen=True)
class Probe:
    """One cause outside the library.

    Attributes:
        name: e.g. ``tip_moment``.
        description: one line: what it is.
        labels: each fitted value's label, its unit in it.
        scales: each value's typical size (the fit's variable unit, the finite-difference step's base).
        deciding_experiments: the experiments that tell it from the library effects it mimics.
        predictor: ``(params, data, guesses) -> (values -> (tip_m (n, 3), converged (n,)))``.
    """

    name: str
    description: str
    labels: tuple[str, ...]
    scales: tuple[float, ...]
    deciding_experiments: tuple[str, ...]
    predictor: Callable

    @property
    def effects(self) -> tuple[str, ...]:
        return (self.name,)


def _rows(params: Params, data: Dataset, guesses: list, **extra):
    return predict_rows(params, data.base_rotation, data.tensions_n, data["tip_mass_kg"], data.lengths_m,
                        guesses=guesses, sliding_state=data.sliding_state, **extra)[:2]


def _tip_moment(params, data, guesses):
    return lambda values: _rows(params, data, guesses, tip_moment_nm=np.asarray(values, dtype=float))


def _tracker_rotation(params, data, guesses):
    tip, ok = _rows(params, data, guesses)  # the rotation does not change the solves

    def predict(values):
        rotation = Rotation.from_rotvec(np.radians(np.asarray(values, dtype=float))).as_matrix()
        return tip @ rotation.T, ok
    return predict


def _intrinsic_curvature(params, data, guesses):
    model = RodModel.from_params(params)
    return lambda values: _rows(params, data, guesses,
                                model=model.replace(precurvature_per_m=(float(values[0]), float(values[1]), 0.0)))


PROBES: dict[str, Probe] = {p.name: p for p in (
    Probe("tip_moment", "a constant external moment at the tip (a cable, a tube, a contact)",
          ("tip_moment_x_nm", "tip_moment_y_nm", "tip_moment_z_nm"), (1e-3, 1e-3, 1e-3), ("pose",), _tip_moment),
    Probe("tracker_rotation", "the tracker's frame turned about the base origin (a registration error)",
          ("tracker_rotation_x_deg", "tracker_rotation_y_deg", "tracker_rotation_z_deg"), (1.0, 1.0, 1.0),
          ("register",), _tracker_rotation),
    Probe("intrinsic_curvature", "the backbone curved when unloaded (set in a curve)",
          ("precurvature_x_per_m", "precurvature_y_per_m"), (1.0, 1.0), ("zero",), _intrinsic_curvature),
)}


@dataclasses.dataclass(frozen=True)
class ProbeFit:
    """A probe's least-squares fit on the training rows.

    Attributes:
        probe: its name.
        labels, values, std_errors: what was fitted (units in the labels), with standard errors
            from σ²(JᵀJ)⁻¹ (inf where the data leave a direction undetermined).
        rms_m: training RMS of |p̂ − p*| at the optimum (m).
        rss_m2: training residual sum of squares (m²).
        converged: the optimiser met its tolerance; ``message`` says why it stopped.
        heldout_errors_m: (held-out rows, 3) p̂ − p* with the probe (m).
        params: the parameter set the probe was fitted on (unchanged: a probe is never written).
    """

    probe: str
    labels: tuple[str, ...]
    values: np.ndarray
    std_errors: np.ndarray
    rms_m: float
    rss_m2: float
    converged: bool
    message: str
    heldout_errors_m: np.ndarray
    params: Params

    def table(self) -> list[dict]:
        """Rows as :meth:`twin.data.fitting.ParameterFit.table` gives them."""
        return [{"parameter": label, "value": float(v), "std_error": float(e), "ci95_low": float(v - 1.96 * e),
                 "ci95_high": float(v + 1.96 * e)} for label, v, e in zip(self.labels, self.values, self.std_errors)]


def fit_probe(probe: Probe, dataset: Dataset, params: Params, train: np.ndarray, test: np.ndarray, *,
              guesses: list | None = None, max_evaluations: int = 25) -> ProbeFit:
    """Fit ``probe`` on top of ``params`` to the ``train`` rows and predict the ``test`` rows with it.

    Args:
        guesses: per row of ``dataset``, a solution to start its solves from (not changed).
        max_evaluations: optimiser iterations (each predicts the training rows once per parameter and once).
    """
    guesses = guesses if guesses is not None else [None] * len(dataset)
    train_data, test_data = dataset.subset(train), dataset.subset(test)
    predict = probe.predictor(params, train_data, [guesses[i] for i in np.flatnonzero(train)])
    measured = train_data.tip_positions_m
    scales = np.asarray(probe.scales, dtype=float)

    def residuals(z):
        tip, ok = predict(z * scales)
        err = tip - measured
        err[~ok] = _FAILED_ROW_PENALTY_M
        return err.ravel()

    result = least_squares(residuals, np.zeros(len(scales)), method="trf", diff_step=_DIFF_STEP,
                           max_nfev=max_evaluations, xtol=1e-6, ftol=1e-8, gtol=1e-6)
    r = residuals(result.x)
    sigma2 = float(r @ r) / max(1, r.size - len(scales))
    cov = _covariance(result.jac, sigma2)
    with np.errstate(invalid="ignore"):
        std = np.sqrt(np.clip(np.diag(cov), 0, None)) * scales
    values = result.x * scales
    tip, ok = probe.predictor(params, test_data, [guesses[i] for i in np.flatnonzero(test)])(values)
    heldout = tip - test_data.tip_positions_m
    heldout[~ok] = _FAILED_ROW_PENALTY_M
    err3 = r.reshape(-1, 3)
    return ProbeFit(probe.name, probe.labels, values, std, float(math.sqrt(np.mean(np.sum(err3**2, axis=1)))),
                    float(r @ r), bool(result.status > 0), str(result.message), heldout, params)
