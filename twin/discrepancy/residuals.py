"""Find: where the model and a dataset disagree, and whether that disagreement has structure.

The residuals e = p̂ − p* (predicted minus measured tracker position, base frame, m) are broken
down by axis, configuration, bending plane φ, curvature κ and tip load, and set against the
measurement noise (:mod:`twin.discrepancy.noise`).

Is there structured disagreement beyond noise? Two numbers answer it:

* **F-test of a low-order structured fit.** Each axis's residual is regressed on a few smooth
  functions of the configuration — 1, κ, κ², m, κ cos φ, κ sin φ, κ cos 2φ, κ sin 2φ, κ m cos φ,
  κ m sin φ (every physical effect in :data:`twin.effects.EFFECTS` moves the tip smoothly with
  these) — and F = ((RSS₀ − RSS₁)/p) / (RSS₁/(N − p)) compares it with "zero-mean noise".
  It needs no noise estimate (the structured fit's leftovers calibrate it). Structure is
  declared when p < :data:`STRUCTURE_ALPHA`.
* **χ² against the noise estimate**: Σ (e/σ)² over all axes, with its per-degree value; ≈ 1
  when the model is right and the noise estimate is honest.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import stats

from twin.discrepancy.noise import NoiseEstimate, estimate_noise
from twin.data.dataset import Dataset
from twin.data.prediction import Predictions, predict_dataset
from twin.params import Params

__all__ = ["MIN_ROWS", "STRUCTURE_ALPHA", "LevelTest", "StructureTest", "ResidualMap", "find_discrepancy",
           "level_test", "structure_test", "thesis_signature"]

STRUCTURE_ALPHA = 1e-3
# Fewest predicted rows the Find step analyses: below it neither the structured fit's leftovers
# nor a held-out split say anything about noise.
MIN_ROWS = 10
AXES = ("x", "y", "z")


@dataclasses.dataclass(frozen=True)
class StructureTest:
    """The verdict on structured disagreement.

    Attributes:
        f_statistic, p_value, dof: F-test of the structured fit against zero-mean noise; dof = (p, N − p).
        structured_rms_m: RMS per row (3-D) of the structured part of the residuals (m).
        chi2_per_dof, chi2_p_value: Σ (e/σ)² / N against the noise estimate, and its upper-tail p.
        beyond_noise: structure found (p_value < :data:`STRUCTURE_ALPHA`).
    """

    f_statistic: float
    p_value: float
    dof: tuple[int, int]
    structured_rms_m: float
    chi2_per_dof: float
    chi2_p_value: float
    beyond_noise: bool

    def statement(self, noise: NoiseEstimate, rms_m: float) -> str:
        """One sentence for a person: is there structured disagreement beyond noise?"""
        verdict = "Structured disagreement beyond noise" if self.beyond_noise else "No structured disagreement beyond noise"
        return (f"{verdict}: residual RMS {rms_m * 1e3:.3g} mm against {noise.rms_3d_m * 1e3:.3g} mm of noise "
                f"({noise.source}); a smooth function of (κ, φ, load) explains {self.structured_rms_m * 1e3:.3g} mm "
                f"of it, F({self.dof[0]}, {self.dof[1]}) = {self.f_statistic:.3g}, p = {self.p_value:.2g} "
                f"(threshold {STRUCTURE_ALPHA:g}); χ²/dof = {self.chi2_per_dof:.3g} against the noise estimate.")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True)
class LevelTest:
    """Whether an error left is within what noise and the model's form allow, whatever its shape.

    The structure test sees only disagreement that is a smooth function of the configuration; a
    disagreement that depends on the path to a configuration (hysteresis, friction without its
    sliding state) or on time (drift) escapes it however large it is. This test does not look at
    the shape: with a right model every row's 3-D error has mean square σ² + m² (σ the noise's
    :attr:`~twin.discrepancy.noise.NoiseEstimate.rms_3d_m`, m the model-form level), so
    Σ|e|² / ((σ² + m²)/3) over n rows is at most χ² with 3n degrees of freedom, and the error is
    beyond that level when its upper-tail p is below :data:`STRUCTURE_ALPHA` (the Find step's own
    false-alarm rate).

    Attributes:
        rms_m: RMS of |e| over the rows tested (m).
        allowed_rms_m: the largest RMS within the level at that rate (m).
        p_value: upper-tail p of the χ² statistic.
        rows: rows tested.
        within: ``rms_m`` ≤ ``allowed_rms_m``.
    """

    rms_m: float
    allowed_rms_m: float
    p_value: float
    rows: int
    within: bool

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def level_test(errors_m: np.ndarray, noise: NoiseEstimate, model_form_m: float) -> LevelTest:
    """:class:`LevelTest` of ``errors_m`` (rows, 3; m) against ``noise`` and the model-form level
    ``model_form_m`` (a 3-D RMS, m)."""
    e = np.asarray(errors_m, dtype=float).reshape(-1, 3)
    n = e.shape[0]
    level2 = noise.rms_3d_m**2 + model_form_m**2
    rms = float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) if n else 0.0
    if n == 0 or level2 <= 0:
        return LevelTest(rms, 0.0, 1.0 if rms == 0 else 0.0, n, rms == 0)
    dof = 3 * n
    chi2 = float(np.sum(e**2)) / (level2 / 3.0)
    allowed = float(np.sqrt(level2 * stats.chi2.isf(STRUCTURE_ALPHA, dof) / dof))
    return LevelTest(rms, allowed, float(stats.chi2.sf(chi2, dof)), n, rms <= allowed)


def _basis(kappa, phi_deg, mass_kg) -> np.ndarray:
    """(rows, 10) smooth functions of the configuration, each of order one on the thesis grid."""
    k = np.asarray(kappa, dtype=float) / 26.2
    m = np.asarray(mass_kg, dtype=float) / 0.01
    phi = np.radians(phi_deg)
    return np.stack([np.ones_like(k), k, k**2, m, k * np.cos(phi), k * np.sin(phi), k * np.cos(2 * phi),
                     k * np.sin(2 * phi), k * m * np.cos(phi), k * m * np.sin(phi)], axis=1)


def structure_test(errors_m: np.ndarray, kappa, phi_deg, mass_kg, noise: NoiseEstimate) -> StructureTest:
    """Fit the residuals of converged rows with :func:`_basis` per axis and test it (see module doc).

    Raises:
        ValueError: fewer than :data:`MIN_ROWS` rows, or too few distinct configurations to leave
            the structured fit any residual to estimate the noise from.
    """
    n = errors_m.shape[0]
    if n < MIN_ROWS:
        raise ValueError(f"{n} predicted row(s): too few to tell structure from noise (at least {MIN_ROWS})")
    basis = _basis(kappa, phi_deg, mass_kg)
    rank = int(np.linalg.matrix_rank(basis))
    fitted = np.zeros_like(errors_m)
    for axis in range(3):
        coef, *_ = np.linalg.lstsq(basis, errors_m[:, axis], rcond=None)
        fitted[:, axis] = basis @ coef
    rss0 = float(np.sum(errors_m**2))
    rss1 = float(np.sum((errors_m - fitted) ** 2))
    p, dof = 3 * rank, 3 * n - 3 * rank
    if dof <= 0:
        raise ValueError(f"{n} rows in {len(np.unique(np.stack([kappa, phi_deg, mass_kg], 1), axis=0))} "
                         f"configurations: a smooth function of (κ, φ, load) with {rank} terms fits them exactly, "
                         "nothing is left to estimate the noise from")
    if rss1 <= 0:
        f_stat, p_value = (float("inf"), 0.0) if rss0 > 0 else (0.0, 1.0)
    else:
        f_stat = ((rss0 - rss1) / p) / (rss1 / dof)
        p_value = float(stats.f.sf(f_stat, p, dof))
    chi2 = float(np.sum((errors_m / noise.sigma_m) ** 2))
    return StructureTest(
        f_statistic=float(f_stat), p_value=p_value, dof=(p, dof),
        structured_rms_m=float(np.sqrt(np.mean(np.sum(fitted**2, axis=1)))),
        chi2_per_dof=chi2 / (3 * n), chi2_p_value=float(stats.chi2.sf(chi2, 3 * n)),
        beyond_noise=bool(p_value < STRUCTURE_ALPHA),
    )


# Group widths of free poses in the plane and curvature tables: 30° of plane, and the largest
# curvature in this many steps.
_FREE_PLANE_STEP_DEG = 30.0
_FREE_CURVATURE_STEPS = 5


def grouping_values(dataset, column: str) -> np.ndarray:
    """(rows,) the values of ``column`` to group rows by: the column, except that for
    ``kappa_cmd_per_m`` and ``phi_cmd_deg`` a free pose takes its arc's (:meth:`Dataset.bends`),
    rounded to groups (:data:`_FREE_PLANE_STEP_DEG`, :data:`_FREE_CURVATURE_STEPS`)."""
    values = np.asarray(dataset[column], dtype=float)
    free = dataset.free
    if column not in ("kappa_cmd_per_m", "phi_cmd_deg") or not free.any():
        return values
    kappa, phi = dataset.bends()
    if column == "phi_cmd_deg":
        rounded = np.round(phi / _FREE_PLANE_STEP_DEG) * _FREE_PLANE_STEP_DEG % 360.0
    else:
        step = max(float(np.max(kappa)), 1e-9) / _FREE_CURVATURE_STEPS
        rounded = np.round(np.round(kappa / step) * step, 2)
    return np.where(free, rounded, values)


def thesis_signature(errors_m: np.ndarray, phi_deg) -> dict:
    """The thesis §9.2 pattern in a set of residuals (rows, 3), base frame with gravity along −z.

    Returns:
        ``mean_z_m`` and ``positive_z_fraction`` (thesis: z errors always positive),
        ``corr_y_minus_sin_phi``, the correlation of e_y with −sin φ (thesis: "an inverted sine";
        φ = 90° bends towards +y in this frame), and ``y_sine_amplitude_m``, the least-squares
        amplitude a of e_y ≈ a·(−sin φ) (m): the size of that sine, which the correlation alone
        does not show once the residuals are down to noise.
    """
    e = np.asarray(errors_m, dtype=float)
    s = -np.sin(np.radians(phi_deg))
    corr = float(np.corrcoef(e[:, 1], s)[0, 1]) if np.std(e[:, 1]) > 0 and np.std(s) > 0 else 0.0
    amplitude = float(e[:, 1] @ s / (s @ s)) if s @ s > 0 else 0.0
    return {"mean_z_m": float(np.mean(e[:, 2])), "positive_z_fraction": float(np.mean(e[:, 2] > 0)),
            "corr_y_minus_sin_phi": corr, "y_sine_amplitude_m": amplitude}


@dataclasses.dataclass(frozen=True)
class ResidualMap:
    """Residuals of one parameter set against a dataset, and the verdict.

    Attributes:
        dataset: the rows analysed.
        predictions: the model's predictions of them.
        noise: the noise estimate.
        structure: the structure test.
    """

    dataset: Dataset
    predictions: Predictions
    noise: NoiseEstimate
    structure: StructureTest

    @property
    def converged(self) -> np.ndarray:
        return self.predictions.converged

    @property
    def errors_m(self) -> np.ndarray:
        """(converged rows, 3) p̂ − p* (m)."""
        return self.predictions.errors_m[self.converged]

    def rms_m(self) -> float:
        """RMS of |p̂ − p*| over converged rows (m)."""
        return self.predictions.rms_m()

    def axis_rms_m(self) -> np.ndarray:
        """(3,) RMS per axis (m)."""
        return np.sqrt(np.mean(self.errors_m**2, axis=0))

    @property
    def statement(self) -> str:
        return self.structure.statement(self.noise, self.rms_m())

    def by(self, column: str) -> list[dict]:
        """Per value of ``column`` (``phi_cmd_deg``, ``kappa_cmd_per_m``, ``tip_mass_kg``): rows, failures,
        RMS of |e| and mean error per axis (mm). Free poses (:meth:`twin.data.dataset.Dataset.bends`)
        join the plane and curvature groups by their arc's values, rounded to 30° and to a fifth of
        the largest curvature."""
        values = grouping_values(self.dataset, column)
        out = []
        for v in np.unique(values):
            rows = values == v
            ok = rows & self.converged
            e = self.predictions.errors_m[ok] * 1e3
            entry = {column: float(v), "rows": int(rows.sum()), "failed": int((rows & ~self.converged).sum()),
                     "rms_mm": float(np.sqrt(np.mean(np.sum(e**2, axis=1)))) if e.size else float("nan")}
            for i, axis in enumerate(AXES):
                entry[f"mean_{axis}_mm"] = float(e[:, i].mean()) if e.size else float("nan")
            out.append(entry)
        return out

    def by_axis(self) -> list[dict]:
        """Per axis: RMS, mean and the noise σ (mm)."""
        e = self.errors_m * 1e3
        return [{"axis": axis, "rms_mm": float(np.sqrt(np.mean(e[:, i] ** 2))), "mean_mm": float(e[:, i].mean()),
                 "noise_mm": float(self.noise.sigma_m[i] * 1e3)} for i, axis in enumerate(AXES)]

    def by_configuration(self) -> list[dict]:
        """One entry per row: configuration, |e| and e per axis (mm); a free pose's κ and φ are
        its arc's (:meth:`twin.data.dataset.Dataset.bends`)."""
        d, err = self.dataset, self.predictions.errors_m * 1e3
        kappa, phi = d.bends()
        return [{"config": int(d["config"][i]), "kappa_cmd_per_m": round(float(kappa[i]), 3),
                 "phi_cmd_deg": round(float(phi[i]), 2), "tip_mass_kg": float(d["tip_mass_kg"][i]),
                 "converged": bool(self.converged[i]), "error_mm": float(np.linalg.norm(err[i])),
                 "error_x_mm": float(err[i, 0]), "error_y_mm": float(err[i, 1]), "error_z_mm": float(err[i, 2])}
                for i in range(len(d))]

    def signature(self) -> dict:
        """:func:`thesis_signature` of the converged rows."""
        return thesis_signature(self.errors_m, self.dataset.bends()[1][self.converged])

    def to_dict(self) -> dict:
        return {"rows": len(self.dataset), "failed_predictions": self.predictions.failures, "rms_m": self.rms_m(),
                "axis_rms_m": self.axis_rms_m().tolist(), "noise": self.noise.to_dict(),
                "structure": self.structure.to_dict(), "beyond_noise": self.structure.beyond_noise,
                "statement": self.statement, "signature": self.signature()}


def find_discrepancy(dataset: Dataset, params: Params | None = None, *, progress: bool = False,
                     noise: NoiseEstimate | None = None, guesses: list | None = None) -> ResidualMap:
    """Predict every row with ``params`` (default the dataset's), estimate the noise and test for structure.

    Args:
        noise: the noise estimate to test against (default: estimated from these residuals),
            e.g. the starting model's when checking what a fitted one leaves.
        guesses: per row, a solution to start its solve from, replaced by the new one (as for
            :func:`twin.data.prediction.predict_rows`).

    Raises:
        ValueError: no row can be predicted, or too few to tell structure from noise
            (:func:`structure_test`).
    """
    params = params or dataset.params
    if len(dataset) < MIN_ROWS:
        raise ValueError(f"{dataset.path or 'dataset'}: {len(dataset)} row(s), too few to estimate the noise and "
                         f"tell structure from it (at least {MIN_ROWS})")
    predictions = predict_dataset(dataset, params, progress=progress, guesses=guesses)
    ok = predictions.converged
    if not ok.any():
        raise ValueError(f"find_discrepancy: none of the {len(dataset)} rows can be predicted with these parameters")
    if noise is None:
        noise = estimate_noise(dataset, params, predictions.errors_m, ok)
    kappa, phi = dataset.bends()
    structure = structure_test(predictions.errors_m[ok], kappa[ok], phi[ok], dataset["tip_mass_kg"][ok], noise)
    return ResidualMap(dataset, predictions, noise, structure)
