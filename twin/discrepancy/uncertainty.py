"""Honest intervals of fitted values: the statistical error, the split-to-split scatter and the
model-form error together.

A fit's standard error σ√((JᵀJ)⁻¹) (:class:`twin.data.fitting.ParameterFit`) holds only if the
model's form is right and the rows' errors are independent. Neither is so between the predictor
and a twin or a rig: their model forms differ by a structured error (the twin's 0.17 mm over the
thesis grid, reports/crosscheck), correlated from row to row, and a fit folds whatever part of it
resembles the effect's own signature into the fitted value. Measured on hidden twin cases
(``scripts/interval_coverage.py``), ± 1.96 standard errors covered the truth in half of them.

The interval here adds, in quadrature, two terms to the standard error se:

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

    u = √(se² + s² + f²),  95 % interval value ± 1.96 u.

The terms overlap where the errors are independent: the interval errs wide rather than narrow,
and no term is a constant of one effect. A model-form error that lay along the value's own
signature in every configuration at once would shift it by up to se / σ · m · √n (~6 times f
on 36 configurations). Measured on hidden twin cases on five robots (scripts/interval_coverage.py):
the errors of a weight, a base tilt and a tracker offset stay within 2 f, the interval covering
every one, and so do friction's on the endoscope, three-tendon, stiff-long and two-segment
robots (μ mostly within 2 %, up to 6 % at μ = 0.05); on the long robot μ lies 0-5 % low, the
most at the smallest μ, where the frictionless model-form error weighs most, two cases in
eighteen beyond 2 f; on the helical robot, whose frictionless error (0.16-0.22 mm) exceeds the
workflow's level, μ lies 4-12 % low and the interval misses (README).
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

__all__ = ["LEVEL_SIGMA", "PATTERNS", "SPLITS", "Uncertainty", "honest_uncertainty"]

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
    """

    parameter: str
    value: float
    std_error: float
    split_scatter: float
    model_form: float
    model_form_level_m: float

    @property
    def total(self) -> float:
        """u = √(se² + s² + f²) (a NaN scatter counts as none)."""
        s = self.split_scatter if math.isfinite(self.split_scatter) else 0.0
        return math.sqrt(self.std_error**2 + s**2 + self.model_form**2)

    def interval(self, level_sigma: float = LEVEL_SIGMA) -> tuple[float, float]:
        """value ± level_sigma · u (default the 95 % interval)."""
        return self.value - level_sigma * self.total, self.value + level_sigma * self.total

    def to_dict(self) -> dict:
        low, high = self.interval()
        return {"value": self.value, "std_error": self.std_error, "split_scatter": self.split_scatter,
                "model_form": self.model_form, "model_form_level_m": self.model_form_level_m,
                "uncertainty": self.total, "ci95": [low, high],
                "ci95_statistical": [self.value - LEVEL_SIGMA * self.std_error,
                                     self.value + LEVEL_SIGMA * self.std_error]}


def honest_uncertainty(dataset: Dataset, fit: ParameterFit, *, rows: np.ndarray | None = None,
                       model_form_m: float, structured_rms_m: float = 0.0, splits: int = SPLITS,
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
        max_evaluations: optimiser iterations per half's fit.
        seed: the halves are drawn with seeds seed, seed + 1, ….
        progress: a progress bar over the halves on stderr.

    Raises:
        ValueError: ``splits`` < 2, or a level that is not a finite length >= 0.
    """
    if splits < 2:
        raise ValueError(f"splits = {splits!r}: must be >= 2")
    for name, level in (("model_form_m", model_form_m), ("structured_rms_m", structured_rms_m)):
        if not (math.isfinite(level) and level >= 0):
            raise ValueError(f"{name} = {level!r}: must be a finite length >= 0 (m)")
    mask = np.ones(len(dataset), dtype=bool) if rows is None else np.asarray(rows, dtype=bool)
    fitted = dataset.subset(mask)
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
    for p, value, se, s in zip(fit.parameters, fit.values, fit.std_errors, scatter):
        form = se / sigma * level_m * math.sqrt(share) if sigma > 0 and math.isfinite(se) else math.inf
        out.append(Uncertainty(p.label, float(value), float(se), float(s), float(form), level_m))
    return out
