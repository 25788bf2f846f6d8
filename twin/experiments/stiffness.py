"""Stiffness characterisation (thesis §8.2): fit E and G to the sag under gravity and tip loads.

Tendons uncoupled (slack), the endoscope horizontal, tip masses 0/5/10 g each applied twice;
the tip position from the tracker. The thesis grid-searched E and G; here they are fitted by
least squares on the Cosserat model (in log space), with standard errors, their correlation,
and 95% profile-likelihood intervals (:func:`profile_intervals`): each modulus is stepped away
from its optimum, the other refitted at every step, until the residual sum of squares has
risen by χ²₁(0.95) times the residual variance. Where the cost stays that flat out to a
:data:`PROFILE_SPAN` factor the interval is open on that side (one-sided or unbounded) and the
modulus is *not identifiable* from the design: the Jacobian's symmetric interval there would
mean nothing (it can run to a negative modulus). The summed-error surface of thesis Fig. 15 is
computed for a plot.
"""

from __future__ import annotations

import dataclasses

import math

import numpy as np
from scipy import stats

from twin.data.dataset import Dataset
from twin.data.prediction import predict_rows
from twin.data.fitting import FitParameter, ParameterFit, fit_parameters
from twin.params import Params

__all__ = ["PIN_SHEAR", "PROFILE_SPAN", "STIFFNESS_MASSES_KG", "STIFFNESS_REPEATS", "ProfileInterval",
           "StiffnessResult", "fit_stiffness", "error_surface", "plot_error_surface", "profile_intervals"]

STIFFNESS_MASSES_KG = (0.0, 0.005, 0.010)  # thesis §8.2: 0, 0.0491, 0.0981 N
STIFFNESS_REPEATS = 2  # thesis §8.2: each load applied twice
MODULI = (FitParameter("backbone.youngs_modulus_pa", log=True), FitParameter("backbone.shear_modulus_pa", log=True))
# Farthest factor from the optimum a profile interval is followed to; beyond it a modulus whose
# cost is still flat is not identifiable (the thesis's own G and the isotropic one differ 58×).
PROFILE_SPAN = 1000.0
# Factor of each outward step of a profile, before the crossing is bisected.
_PROFILE_STEP = 2.0
_BISECTIONS = 8
# What pins the shear modulus where the sag under tip masses does not: in the thesis's design the
# tip loads bend the endoscope, and shear carries a fraction of a per cent of the sag.
PIN_SHEAR = ("a torsion test (a tip torque about the backbone axis, twist from the tracker's orientation), or "
             "short-lever sideways tip loads, where shear carries a larger share of the deflection")


@dataclasses.dataclass(frozen=True)
class ProfileInterval:
    """A 95 % profile-likelihood interval of one modulus.

    Attributes:
        parameter: its label.
        value: the fitted value (Pa).
        low, high: the interval's ends (Pa); None where the cost stays within the threshold out
            to :data:`PROFILE_SPAN` (open on that side).
        identifiable: both ends found.
        evaluations: refits it took.
    """

    parameter: str
    value: float
    low: float | None
    high: float | None
    evaluations: int

    @property
    def identifiable(self) -> bool:
        return self.low is not None and self.high is not None

    def describe(self) -> str:
        """``a … b``, ``≥ a (unbounded above)``, ``≤ b (unbounded below)`` or ``unbounded``."""
        if self.identifiable:
            return f"{self.low:.4g} … {self.high:.4g}"
        if self.low is not None:
            return f"≥ {self.low:.4g} (no upper bound within ×{PROFILE_SPAN:g})"
        if self.high is not None:
            return f"≤ {self.high:.4g} (no lower bound within ÷{PROFILE_SPAN:g})"
        return f"unbounded (flat within ÷/×{PROFILE_SPAN:g})"


@dataclasses.dataclass(frozen=True)
class StiffnessResult:
    """The fit and the error surface around it.

    Attributes:
        fit: the :class:`ParameterFit` of E and G (its Jacobian intervals are local; ``profile``
            holds the honest ones).
        profile: the 95 % profile-likelihood interval of each modulus (:func:`profile_intervals`).
        youngs_grid_pa, shear_grid_pa: surface axes.
        summed_error_m: (len(G grid), len(E grid)) summed |p̂ − p*| over the rows (m), as thesis Fig. 15.
    """

    fit: ParameterFit
    youngs_grid_pa: np.ndarray
    shear_grid_pa: np.ndarray
    summed_error_m: np.ndarray
    profile: tuple[ProfileInterval, ...] = ()

    @property
    def youngs_modulus_pa(self) -> float:
        return float(self.fit.values[0])

    @property
    def shear_modulus_pa(self) -> float:
        return float(self.fit.values[1])


def fit_stiffness(dataset: Dataset, params: Params | None = None, *, surface_points: int = 15,
                  surface_span: float = 3.0, profile: bool = True) -> StiffnessResult:
    """Fit E and G to a stiffness dataset and map the summed error around the optimum.

    Args:
        dataset: stiffness measurements (tendons slack; tensions as measured, near zero).
        params: starting parameter set (default the dataset's).
        surface_points: grid points per axis of the error surface (0 = none).
        surface_span: the surface spans optimum / span … optimum × span on each axis.
        profile: compute the profile-likelihood intervals.
    """
    params = params or dataset.params
    fit = fit_parameters(dataset, params, MODULI)
    intervals = profile_intervals(dataset, fit) if profile else ()
    e_opt, g_opt = fit.values
    if surface_points:
        e_grid = e_opt * np.geomspace(1 / surface_span, surface_span, surface_points)
        g_grid = g_opt * np.geomspace(1 / surface_span, surface_span, surface_points)
        summed = error_surface(dataset, params, e_grid, g_grid)
    else:
        e_grid = g_grid = np.array([])
        summed = np.zeros((0, 0))
    return StiffnessResult(fit, e_grid, g_grid, summed, intervals)


def profile_intervals(dataset: Dataset, fit: ParameterFit, level: float = 0.95) -> tuple[ProfileInterval, ...]:
    """The ``level`` profile-likelihood interval of each fitted (log) modulus of ``fit`` (module doc).

    The threshold is a rise of the residual sum of squares by χ²₁(level) times the fit's residual
    variance, which holds whatever the model misses as well as the tracker noise.
    """
    rss0 = fit.residual_sigma_m**2 * max(1, 3 * len(dataset) - len(fit.parameters))
    limit = rss0 + stats.chi2.ppf(level, 1) * fit.residual_sigma_m**2
    out = []
    for i, p in enumerate(fit.parameters):
        others = [q for q in fit.parameters if q is not p]
        count = [0]

        def cost(value: float) -> float:
            count[0] += 1
            fixed = fit.params.replace({p.key: float(value)}, source="profile")
            if not others:
                tip, ok, _, _ = predict_rows(fixed, dataset.base_rotation, dataset.tensions_n, dataset["tip_mass_kg"],
                                             dataset.lengths_m, sliding_state=dataset.sliding_state)
                err = np.where(ok[:, None], tip - dataset.tip_positions_m, 0.05)
                return float(np.sum(err**2))
            try:
                refit = fit_parameters(dataset, fixed, others, max_evaluations=30, tolerance=1e-8)
            except ValueError:
                return math.inf
            return refit.residual_sigma_m**2 * max(1, 3 * len(dataset) - len(others))

        value = float(fit.values[i])
        ends = []
        for direction in (-1.0, 1.0):
            inside, step, found = 0.0, math.log(_PROFILE_STEP), None
            while abs(inside) < math.log(PROFILE_SPAN):
                trial = min(abs(inside) + step, math.log(PROFILE_SPAN)) * direction
                if cost(value * math.exp(trial)) > limit:
                    lo, hi = inside, trial  # the crossing, in log of the factor
                    for _ in range(_BISECTIONS):
                        mid = 0.5 * (lo + hi)
                        lo, hi = (mid, hi) if cost(value * math.exp(mid)) <= limit else (lo, mid)
                    found = value * math.exp(0.5 * (lo + hi))
                    break
                inside = trial
            ends.append(found)
        out.append(ProfileInterval(p.label, value, ends[0], ends[1], count[0]))
    return tuple(out)


def error_surface(dataset: Dataset, params: Params, youngs_grid_pa, shear_grid_pa) -> np.ndarray:
    """Summed tip error (m) over the rows for each (G, E) pair; NaN where a prediction fails."""
    out = np.full((len(shear_grid_pa), len(youngs_grid_pa)), np.nan)
    for i, g in enumerate(shear_grid_pa):
        for j, e in enumerate(youngs_grid_pa):
            trial = params.replace({"backbone.youngs_modulus_pa": float(e), "backbone.shear_modulus_pa": float(g)})
            tip, ok, _, _ = predict_rows(trial, dataset.base_rotation, dataset.tensions_n, dataset["tip_mass_kg"],
                                         dataset.lengths_m, sliding_state=dataset.sliding_state)
            if ok.all():
                out[i, j] = float(np.sum(np.linalg.norm(tip - dataset.tip_positions_m, axis=1)))
    return out


def plot_error_surface(result: StiffnessResult, path) -> None:
    """Contour plot of the summed error over (E, G) with the optimum marked (thesis Fig. 15)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    e, g = np.meshgrid(result.youngs_grid_pa, result.shear_grid_pa)
    cs = ax.contourf(e, g, result.summed_error_m * 1e3, levels=20, cmap="viridis")
    fig.colorbar(cs, label="summed tip error (mm)")
    ax.plot(result.youngs_modulus_pa, result.shear_modulus_pa, "o", mfc="none", mec="red", ms=12, mew=2,
            label="fitted (E, G)")
    ax.legend(loc="upper right", fontsize=8)
    ax.set(xscale="log", yscale="log", xlabel="Young's modulus E (Pa)", ylabel="shear modulus G (Pa)",
           title="stiffness fit: summed tip error")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
