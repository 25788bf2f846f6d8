"""Stiffness characterisation (thesis §8.2): fit E and G to the sag under gravity and tip loads.

Tendons uncoupled (slack), the endoscope horizontal, tip masses 0/5/10 g each applied twice;
the tip position from the tracker. The thesis grid-searched E and G; here they are fitted by
least squares on the Cosserat model (in log space), with standard errors, 95% intervals and
their correlation, and the summed-error surface of thesis Fig. 15 is computed for a plot.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from twin.data.dataset import Dataset
from twin.data.prediction import predict_rows
from twin.data.fitting import FitParameter, ParameterFit, fit_parameters
from twin.params import Params

__all__ = ["STIFFNESS_MASSES_KG", "STIFFNESS_REPEATS", "StiffnessResult", "fit_stiffness", "error_surface",
           "plot_error_surface"]

STIFFNESS_MASSES_KG = (0.0, 0.005, 0.010)  # thesis §8.2: 0, 0.0491, 0.0981 N
STIFFNESS_REPEATS = 2  # thesis §8.2: each load applied twice
MODULI = (FitParameter("backbone.youngs_modulus_pa", log=True), FitParameter("backbone.shear_modulus_pa", log=True))


@dataclasses.dataclass(frozen=True)
class StiffnessResult:
    """The fit and the error surface around it.

    Attributes:
        fit: the :class:`ParameterFit` of E and G.
        youngs_grid_pa, shear_grid_pa: surface axes.
        summed_error_m: (len(G grid), len(E grid)) summed |p̂ − p*| over the rows (m), as thesis Fig. 15.
    """

    fit: ParameterFit
    youngs_grid_pa: np.ndarray
    shear_grid_pa: np.ndarray
    summed_error_m: np.ndarray

    @property
    def youngs_modulus_pa(self) -> float:
        return float(self.fit.values[0])

    @property
    def shear_modulus_pa(self) -> float:
        return float(self.fit.values[1])


def fit_stiffness(dataset: Dataset, params: Params | None = None, *, surface_points: int = 15,
                  surface_span: float = 3.0) -> StiffnessResult:
    """Fit E and G to a stiffness dataset and map the summed error around the optimum.

    Args:
        dataset: stiffness measurements (tendons slack; tensions as measured, near zero).
        params: starting parameter set (default the dataset's).
        surface_points: grid points per axis of the error surface (0 = none).
        surface_span: the surface spans optimum / span … optimum × span on each axis.
    """
    params = params or dataset.params
    fit = fit_parameters(dataset, params, MODULI)
    e_opt, g_opt = fit.values
    if surface_points:
        e_grid = e_opt * np.geomspace(1 / surface_span, surface_span, surface_points)
        g_grid = g_opt * np.geomspace(1 / surface_span, surface_span, surface_points)
        summed = error_surface(dataset, params, e_grid, g_grid)
    else:
        e_grid = g_grid = np.array([])
        summed = np.zeros((0, 0))
    return StiffnessResult(fit, e_grid, g_grid, summed)


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
