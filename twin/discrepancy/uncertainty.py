"""Honest intervals of fitted values: the statistical error, the split-to-split scatter and the
model-form error together.

A fit's standard error σ√((JᵀJ)⁻¹) (:class:`twin.data.fitting.ParameterFit`) holds only if the
model's form is right and the rows' errors are independent. Neither is so between the predictor
and a twin or a rig: their model forms differ by a structured error (the twin's 0.17 mm over the
thesis grid, reports/crosscheck), correlated from row to row, and a fit folds whatever part of it
resembles the effect's own signature into the fitted value. Measured on hidden twin cases
(``scripts/interval_coverage.py``), ± 1.96 standard errors covered the truth in half of them.

The interval here adds, in quadrature, three terms to the standard error se:

* **split scatter** s: the standard deviation of the same fit on ``splits`` random halves of the
  fitted configurations (a delete-half jackknife: about se where the rows are independent,
  more where the value depends on which configurations are fitted, as model-form errors make it);
* **model form** f: the spread of the value that a model-form error of size m makes, m the
  3-D RMS by which the model and what made the data differ at a configuration: an error the
  same on a configuration's repeated rows, in the direction of its three axes that moves the
  value most, and independent over at most :data:`PATTERNS` configurations. Over n rows in C
  configurations and the fit's residual standard deviation σ per axis,

      f = se / σ · m · √(n / min(C, PATTERNS))

  (se / σ is √((JᵀJ)⁻¹ᵢᵢ)). An error of the model's form is smooth over the workspace: a
  denser grid samples the same error again, it does not average new ones out, so f stops
  shrinking with more configurations where se goes on. m is the larger of the model-form level
  the workflow is given (``model_form_m``) and the structure beyond noise the fitted model still
  leaves (its Find step): the data's own measure of what the model does not capture.

* **model-form shift** b: what one model-form error of the robot's own shape does to the value:
  the predictor's tip minus the twin's at each fitted configuration (:func:`model_form_reference`,
  the cross-check at the data's commands), d, moves a least-squares fit by b = −(JᵀJ)⁻¹Jᵀd
  (J the fit's Jacobian). f assumes an error that resembles the effect no more than chance over
  :data:`PATTERNS` configurations; an error that resembles it more, as the helical robot's twin
  does friction (its ten elements discretise the helix: 0.09 mm median, 0.28 mm worst from the
  predictor, 0.02 / 0.06 mm at twenty; the shift −0.0075 … −0.0082 in μ, 3–3.5 f), is b. On
  data of the twin b is what the fit reads off for the twin's model form; on a rig's, where the
  model differs by other errors as well, one instance of their size and shape.

    u = √(se² + s² + f² + b²),  95 % interval value ± 1.96 u.

The terms overlap where the errors are independent: the interval errs wide rather than narrow,
and no term is a constant of one effect. A model-form error that lay along the value's own
signature in every configuration at once would shift it by up to se / σ · m · √n (~6 times f
on 36 configurations). Measured on hidden twin cases on six robots (scripts/interval_coverage.py):
the errors of a weight, a base tilt and a tracker offset stay within 2 f, the interval covering
every one, and so do friction's on the endoscope, three-tendon, stiff-long and two-segment
robots (μ mostly within 2 %, up to 6 % at μ = 0.05); on the long robot μ lies up to 5 % low, not
by the frictionless model form (b −0.0004 … −0.001), within 1.5 u; on the helical robot μ lies
0.008-0.011 low at every μ (4-14 %), of which b accounts for 0.0075-0.0082 (README).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from tqdm import tqdm

from twin.data.dataset import Dataset
from twin.data.fitting import ParameterFit, fit_parameters
from twin.discrepancy.naming import split_rows
from twin.discrepancy.noise import configuration_keys
from twin.params import Params

__all__ = ["LEVEL_SIGMA", "PATTERNS", "SPLITS", "Uncertainty", "honest_uncertainty", "model_form_reference"]

# Halves the split scatter is taken over: the fits cost four times the named one's; three
# degrees of freedom for the scatter, which adds to se and f, not replaces them.
SPLITS = 4
# Half-width of the 95 % interval in standard uncertainties (normal).
LEVEL_SIGMA = 1.96
# Configurations over which a model-form error counts as independent (module doc): a sixth of the
# thesis grid (3 curvatures, every other plane, 2 loads). Chosen by measurement, not derived: the
# twin-predictor error over the thesis grid (reports/crosscheck) correlates 0.5-0.9 between
# neighbouring curvatures, planes and loads, as few as 2-5 independent configurations by an AR(1)
# count, which would make f 3-4 times wider than the errors the fits show (within 2 f on 36);
# counting all configurations (216 on a full sweep) let a friction twin's μ interval (0.1435 …
# 0.1495) miss the twin's 0.15. On sweeps of twice 36 (scripts/interval_coverage.py
# --every-plane) the capped interval covers as on 36 (README).
PATTERNS = 36


@dataclasses.dataclass(frozen=True)
class Uncertainty:
    """The uncertainty of one fitted value (all in the parameter's own unit).

    Attributes:
        parameter: its label.
        value: the fitted value.
        std_error: the statistical standard error se.
        split_scatter: the standard deviation s of the value over the split halves (NaN when no
            half could be fitted).
        model_form: the model-form term f (module doc).
        model_form_level_m: the 3-D structured RMS m (m) f was taken at.
        model_form_shift: the shift b the reference model-form error (module doc) makes in the
            value (signed: the fit reads so much off for it; 0 without a reference).
    """

    parameter: str
    value: float
    std_error: float
    split_scatter: float
    model_form: float
    model_form_level_m: float
    model_form_shift: float = 0.0

    @property
    def total(self) -> float:
        """u = √(se² + s² + f² + b²) (a NaN scatter or shift counts as none)."""
        s = self.split_scatter if math.isfinite(self.split_scatter) else 0.0
        b = self.model_form_shift if math.isfinite(self.model_form_shift) else 0.0
        return math.sqrt(self.std_error**2 + s**2 + self.model_form**2 + b**2)

    def interval(self, level_sigma: float = LEVEL_SIGMA) -> tuple[float, float]:
        """value ± level_sigma · u (default the 95 % interval)."""
        return self.value - level_sigma * self.total, self.value + level_sigma * self.total

    def to_dict(self) -> dict:
        low, high = self.interval()
        return {"value": self.value, "std_error": self.std_error, "split_scatter": self.split_scatter,
                "model_form": self.model_form, "model_form_level_m": self.model_form_level_m,
                "model_form_shift": self.model_form_shift,
                "uncertainty": self.total, "ci95": [low, high],
                "ci95_statistical": [self.value - LEVEL_SIGMA * self.std_error,
                                     self.value + LEVEL_SIGMA * self.std_error]}


def model_form_reference(dataset: Dataset, params: Params, rows: np.ndarray | None = None) -> np.ndarray:
    """(rows, 3) the predictor's tip minus the twin's (m) at each row's commanded configuration
    (κ, φ, tip mass), both of ``params`` at rest (:func:`twin.sim.crosscheck.crosscheck`: the
    twin on ideal tension sources at the configuration's tensions, no noise): the model-form
    error of the robot's own shape (module doc). Zero on rows the two cannot be compared at: a
    free pose (no command), a plane the tendons cannot bend, a twin not at rest or a predictor
    that did not converge. With ``rows`` (a boolean mask), those rows only (the rest zero): the
    twin's settling is the cost, ~10 ms of CPU per configuration at 10 elements, 75 at 20.

    Raises:
        twin.sim.plant.SimulationError: MuJoCo warned while the twin settled.
    """
    from twin.sim.crosscheck import crosscheck

    out = np.zeros((len(dataset), 3))
    commanded = ~dataset.free & (np.ones(len(dataset), dtype=bool) if rows is None else np.asarray(rows, dtype=bool))
    if not commanded.any():
        return out
    table = np.stack([np.asarray(dataset[c], dtype=float) for c in ("kappa_cmd_per_m", "phi_cmd_deg", "tip_mass_kg")],
                     axis=1)
    keys = np.round(table, 9)
    configs = np.unique(keys[commanded], axis=0)
    result = crosscheck(params, configs=[(k, *map(float, c)) for k, c in enumerate(configs)])
    difference = result.rod_tip_m - result.twin_tip_m
    compared = result.settled & result.rod_converged & np.all(np.isfinite(difference), axis=1)
    found = {tuple(np.round(row[1:], 9)): d for row, d, ok in zip(result.rows, difference, compared) if ok}
    for i in np.flatnonzero(commanded):
        out[i] = found.get(tuple(keys[i]), 0.0)
    return out


def honest_uncertainty(dataset: Dataset, fit: ParameterFit, *, rows: np.ndarray | None = None,
                       model_form_m: float, structured_rms_m: float = 0.0, splits: int = SPLITS,
                       reference_errors_m: np.ndarray | None = None,
                       max_evaluations: int = 25, seed: int = 0, progress: bool = False) -> list[Uncertainty]:
    """The uncertainty of each of ``fit``'s values (module doc).

    Args:
        dataset: the measurements ``fit`` was made on.
        fit: the fit (of ``rows`` of ``dataset``).
        rows: boolean mask of the rows it was fitted on (default all).
        model_form_m: the model-form level (3-D structured RMS, m) between the model and what
            made the data (the workflow's ``model_form_m``).
        structured_rms_m: the structured RMS (3-D, m) beyond noise the fitted model leaves on
            the data (its Find step); the larger of the two is taken.
        splits: halves to take the scatter over (>= 2).
        reference_errors_m: (rows of ``dataset``, 3) a model-form error of the robot's own shape
            (:func:`model_form_reference`), whose shift b of each value enters u; None: no b.
        max_evaluations: optimiser iterations per half's fit.
        seed: the halves are drawn with seeds seed, seed + 1, ….
        progress: a progress bar over the halves on stderr.

    Raises:
        ValueError: ``splits`` < 2, a level that is not a finite length >= 0, or a reference
            of another shape than the dataset's rows.
    """
    if splits < 2:
        raise ValueError(f"splits = {splits!r}: must be >= 2")
    for name, level in (("model_form_m", model_form_m), ("structured_rms_m", structured_rms_m)):
        if not (math.isfinite(level) and level >= 0):
            raise ValueError(f"{name} = {level!r}: must be a finite length >= 0 (m)")
    mask = np.ones(len(dataset), dtype=bool) if rows is None else np.asarray(rows, dtype=bool)
    fitted = dataset.subset(mask)
    shifts = np.zeros(len(fit.values))
    if reference_errors_m is not None:
        reference = np.asarray(reference_errors_m, dtype=float)
        if reference.shape != (len(dataset), 3):
            raise ValueError(f"reference_errors_m of shape {reference.shape}: expected ({len(dataset)}, 3)")
        shifts = _shifts(fit, np.nan_to_num(reference[mask]))
    halves = []
    for k in tqdm(range(splits), desc="split scatter", unit="half", disable=not progress, leave=False):
        try:
            half = split_rows(fitted, 0.5, seed=seed + k)[0]
        except ValueError:  # too few configurations to halve
            break
        try:
            # From the fitted values, in the fitted model (a variant's settings stay as fitted).
            halves.append(fit_parameters(fitted, fit.params, fit.parameters, x0=[float(v) for v in fit.values], rows=half,
                                         max_evaluations=max_evaluations).values)
        except ValueError:  # a half the model cannot predict at the fitted values
            continue
    scatter = np.std(halves, axis=0, ddof=1) if len(halves) >= 2 else np.full(len(fit.values), np.nan)
    share = len(fitted) / min(len(np.unique(configuration_keys(fitted))), PATTERNS)
    level_m = max(model_form_m, structured_rms_m)
    sigma = fit.residual_sigma_m
    out = []
    for p, value, se, s, b in zip(fit.parameters, fit.values, fit.std_errors, scatter, shifts):
        form = se / sigma * level_m * math.sqrt(share) if sigma > 0 and math.isfinite(se) else math.inf
        out.append(Uncertainty(p.label, float(value), float(se), float(s), float(form), level_m, float(b)))
    return out


def _shifts(fit: ParameterFit, errors_m: np.ndarray) -> np.ndarray:
    """b = −(JᵀJ)⁻¹Jᵀd per fitted value: how far the fit moves each value for an error d
    ((fitted rows, 3), m, predictor minus what made the data) in the residuals, to first order;
    NaN where the fit's Jacobian is not finite (its standard errors are infinite then)."""
    jac = fit.jacobian
    if jac is None or jac.shape[0] != errors_m.size or not np.all(np.isfinite(jac)):
        return np.full(len(fit.values), np.nan)
    return -np.linalg.lstsq(jac, errors_m.reshape(-1), rcond=1e-12)[0]
