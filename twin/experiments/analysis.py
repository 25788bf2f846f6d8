"""Validation-sweep analysis (thesis §8.3, §9.2): errors per configuration, axis, plane and load.

Everything here works on a dataset and its :class:`~twin.data.prediction.Predictions`;
:func:`plot_validation` draws the thesis's Figs. 17–22 (error magnitude and per-axis error over
the bending plane, grouped by curvature, one panel per tip mass; front views with error circles).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from twin.data.dataset import Dataset
from twin.data.prediction import Predictions, predict_dataset
from twin.params import Params

__all__ = ["ValidationResult", "analyse_validation", "plot_validation"]


@dataclasses.dataclass(frozen=True)
class ValidationResult:
    """Per-row predictions and the summaries of a validation dataset."""

    dataset: Dataset
    predictions: Predictions

    @property
    def error_mm(self) -> np.ndarray:
        return self.predictions.error_norm_m * 1e3

    def summary(self) -> dict:
        """Median, RMS, worst error (mm), per-axis RMS (mm), failures, rows."""
        ok = self.predictions.converged
        e = self.error_mm[ok]
        axes = self.predictions.errors_m[ok] * 1e3
        return {
            "rows": len(self.dataset),
            "failed_predictions": self.predictions.failures,
            "median_error_mm": float(np.median(e)) if e.size else float("nan"),
            "rms_error_mm": float(np.sqrt(np.mean(e**2))) if e.size else float("nan"),
            "worst_error_mm": float(np.max(e)) if e.size else float("nan"),
            "worst_config": int(self.dataset["config"][ok][np.argmax(e)]) if e.size else None,
            "rms_x_mm": float(np.sqrt(np.mean(axes[:, 0] ** 2))) if e.size else float("nan"),
            "rms_y_mm": float(np.sqrt(np.mean(axes[:, 1] ** 2))) if e.size else float("nan"),
            "rms_z_mm": float(np.sqrt(np.mean(axes[:, 2] ** 2))) if e.size else float("nan"),
            "mean_z_mm": float(np.mean(axes[:, 2])) if e.size else float("nan"),
        }

    def by_group(self, column: str) -> list[dict]:
        """RMS and worst error (mm) and failures for each value of ``column`` (e.g. tip_mass_kg)."""
        out = []
        values = self.dataset[column]
        for v in np.unique(values):
            mask = values == v
            ok = mask & self.predictions.converged
            e = self.error_mm[ok]
            out.append({column: float(v), "rows": int(mask.sum()), "failed": int((mask & ~self.predictions.converged).sum()),
                        "rms_error_mm": float(np.sqrt(np.mean(e**2))) if e.size else float("nan"),
                        "worst_error_mm": float(e.max()) if e.size else float("nan")})
        return out

    def rows_table(self) -> list[dict]:
        """One dict per row: the configuration and its errors (mm)."""
        d, p = self.dataset, self.predictions
        err = p.errors_m * 1e3
        return [{"config": int(d["config"][i]), "kappa_cmd_per_m": float(d["kappa_cmd_per_m"][i]),
                 "phi_cmd_deg": float(d["phi_cmd_deg"][i]), "tip_mass_kg": float(d["tip_mass_kg"][i]),
                 "converged": bool(p.converged[i]), "error_mm": float(self.error_mm[i]),
                 "error_x_mm": float(err[i, 0]), "error_y_mm": float(err[i, 1]), "error_z_mm": float(err[i, 2])}
                for i in range(len(d))]


def analyse_validation(dataset: Dataset, params: Params | None = None, *, progress: bool = False) -> ValidationResult:
    """Predict every row (measured tensions, known loads) and keep the errors."""
    return ValidationResult(dataset, predict_dataset(dataset, params, progress=progress))


# Figures are at most this wide (inches at the 100 dpi they are saved with): a report page's width.
_MAX_WIDTH_IN = 15.0


def _nice_at_most(value: float) -> float:
    """The largest 1, 2 or 5 × 10^n not above ``value`` (> 0): a reference size a reader reads at once."""
    exponent = np.floor(np.log10(value))
    for mantissa in (5.0, 2.0, 1.0):
        if mantissa * 10**exponent <= value:
            return float(mantissa * 10**exponent)
    return float(10 ** (exponent - 1) * 5.0)


def plot_validation(result: ValidationResult, folder: str | Path) -> dict[str, Path]:
    """Write the thesis-style figures into ``folder``; returns name → path. The first,
    ``error_magnitude``, answers the sweep's question (how far off is the prediction)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    d, p = result.dataset, result.predictions
    masses = np.unique(d["tip_mass_kg"])
    kappas = np.unique(d["kappa_cmd_per_m"])
    err = p.errors_m * 1e3
    # The sign convention is on every axis: e = p̂ − p*, predicted minus measured, in the base frame.
    quantities = {"error_magnitude": (result.error_mm, "prediction error |e_p| = |p̂ − p*| (mm)")}
    quantities.update({f"error_{axis}": (err[:, i], f"e_{axis} = {axis}̂ − {axis}* (mm)\n(predicted − measured)")
                       for i, axis in enumerate("xyz")})
    paths: dict[str, Path] = {}
    for name, (values, label) in quantities.items():
        fig, axes = plt.subplots(1, len(masses), figsize=(min(4.2 * len(masses), _MAX_WIDTH_IN), 3.6), sharey=True,
                                 squeeze=False)
        for ax, mass in zip(axes[0], masses):
            for kappa in kappas:
                sel = (d["tip_mass_kg"] == mass) & (d["kappa_cmd_per_m"] == kappa)
                order = np.argsort(d["phi_cmd_deg"][sel])
                phi = d["phi_cmd_deg"][sel][order]
                ok = p.converged[sel][order]
                ax.plot(phi[ok], values[sel][order][ok], "o-", ms=3, lw=1, label=f"κ={kappa:g}")
            ax.set(title=f"tip mass {mass * 1e3:g} g", xlabel="bending plane φ (deg)")
            ax.grid(alpha=0.3)
        axes[0][0].set_ylabel(label)
        axes[0][-1].legend(fontsize=7, title="curvature (1/m)", title_fontsize=7)
        fig.tight_layout()
        paths[name] = folder / f"{name}.png"
        fig.savefig(paths[name], dpi=100)
        plt.close(fig)
    # Front views (yz plane) with error circles, thesis Figs. 21-22; failed predictions in red.
    # A circle's radius is the error magnified ``gain`` times (the largest one 6 mm on the plot);
    # a reference circle of a round error in each panel's corner is the scale.
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(1, len(masses), figsize=(min(4.2 * len(masses), _MAX_WIDTH_IN), 4.4), squeeze=False)
    worst_mm = float(np.nanmax(result.error_mm[p.converged])) if p.converged.any() else 0.0
    gain = 6.0 / worst_mm if worst_mm > 1e-9 else 1.0
    reference_mm = _nice_at_most(worst_mm) if worst_mm > 1e-9 else 1.0
    for ax, mass in zip(axes[0], masses):
        sel = d["tip_mass_kg"] == mass
        tips = d.tip_positions_m[sel] * 1e3
        ok = p.converged[sel]
        ax.scatter(tips[ok, 1], tips[ok, 2], s=6, c="k", label="measured tip")
        if (~ok).any():
            ax.scatter(tips[~ok, 1], tips[~ok, 2], s=14, c="red", label="no prediction")
        for (_, y, z), e in zip(tips[ok], result.error_mm[sel][ok]):
            ax.add_patch(plt.Circle((y, z), gain * e, fill=False, lw=0.8, color="tab:blue"))
        ax.set(title=f"front view, {mass * 1e3:g} g", xlabel="y (mm)", ylabel="z (mm)", aspect="equal")
        ax.autoscale_view()
        x0, (y0, y1) = ax.get_xlim()[0], ax.get_ylim()
        radius = gain * reference_mm
        # Room above the data for the reference circle, in the upper left corner.
        ax.set_ylim(y0, y1 + 3.0 * radius)
        centre = (x0 + 1.5 * radius, y1 + 1.5 * radius)
        ax.add_patch(plt.Circle(centre, radius, fill=False, lw=1.2, color="tab:blue"))
        ax.annotate(f"{reference_mm:g} mm error", (centre[0] + 1.3 * radius, centre[1]), va="center", fontsize=7,
                    color="tab:blue")
        ax.grid(alpha=0.3)
    handles = {h.get_label(): h for ax in axes[0] for h in ax.get_legend_handles_labels()[0]}
    handles[f"prediction error |e_p| (circle radius = |e_p| × {gain:.3g})"] = Line2D(
        [], [], marker="o", ls="", mfc="none", mec="tab:blue", ms=8)
    fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=len(handles), fontsize=8)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    paths["front_view"] = folder / "front_view.png"
    fig.savefig(paths["front_view"], dpi=100)
    plt.close(fig)
    return paths
