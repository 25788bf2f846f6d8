"""Load compensation on a device over the validation grid: PCC length setpoints against
model-compensated tensions, the tip error under 5 g and 10 g.

For each (κ, φ): pretension straight, drive the PCC tendon lengths in length mode and record the
unloaded tip — the target — and the tensions; hang each mass with the lengths held
(**uncompensated**, the thesis's experiment); then switch to tension mode and, for each mass,
apply the tensions :func:`twin.control.compensation.hold_tensions` computes from the measured
unloaded tensions and the known load before hanging it (**compensated**). The error is the
distance of the settled, loaded tip from the target, both read by the tracker. A configuration
whose tensions trip the board's limit is recorded as faulted, not dropped.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from twin.control.compensation import hold_tensions
from twin.control.pretension import pretension_straight
from twin.control.tuning import TUNED_TENSION_GAINS
from twin.device import CommandRejected
from twin.experiments.protocols import ProtocolError, measure, settle
from twin.experiments.report import markdown_table
from twin.params import Params
from twin.pcc import GRID_KAPPA_PER_M, GRID_PHI_DEG, tendon_length_changes_m
from twin.pose import HORIZONTAL
from twin.rod import RodModel
from twin.rod.grid import GRAVITY_TIP_FORCE_N

__all__ = ["CompensationTrial", "run_compensation_trial", "QUICK_CONFIGS"]

# A few (κ 1/m, φ deg) across curvature and bending direction (up, down, sideways), for --quick.
QUICK_CONFIGS = ((8.7, 0.0), (13.0, 90.0), (17.5, 180.0), (26.2, 270.0), (4.5, 30.0), (17.5, 240.0))


@dataclasses.dataclass(frozen=True)
class CompensationTrial:
    """Tip errors under load, uncompensated and compensated, one row per (κ, φ, mass).

    Row keys: ``kappa_per_m``, ``phi_deg``, ``mass_g``, ``uncompensated_mm``, ``compensated_mm``,
    ``reduction_pct``, ``model_residual_mm`` (the predictor's own miss), ``tensions_n`` (the
    compensating tensions), ``reached`` (the predictor reached the target within the bounds),
    ``fault`` (empty, or the board fault that stopped the row; its errors are then NaN).
    """

    rows: list[dict]
    device: str
    floor_n: float
    limit_n: float

    def summary(self) -> dict:
        """Median and worst errors and the median error reduction, per tip mass and overall, over the
        rows that ran to the end; ``faulted`` counts those the board's tension limit stopped."""
        out = {}
        for label, group in [("all", self.rows)] + [(f"{m:g} g", [r for r in self.rows if r["mass_g"] == m])
                                                    for m in sorted({r["mass_g"] for r in self.rows})]:
            rows = [r for r in group if not r["fault"]]
            u = np.array([r["uncompensated_mm"] for r in rows])
            c = np.array([r["compensated_mm"] for r in rows])
            out[label] = {"configurations": len(rows), "faulted": len(group) - len(rows), "uncompensated_median_mm": float(np.median(u)),
                          "compensated_median_mm": float(np.median(c)), "uncompensated_worst_mm": float(u.max()),
                          "compensated_worst_mm": float(c.max()),
                          "median_reduction_pct": float(np.median([r["reduction_pct"] for r in rows])),
                          "reduction_of_medians_pct": float(100 * (1 - np.median(c) / np.median(u)))}
        return out

    def plot(self, path: str | Path) -> Path:
        """Bar chart of the errors per configuration, uncompensated against compensated."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        path = Path(path)
        labels = [f"κ{r['kappa_per_m']:g} φ{r['phi_deg']:g} {r['mass_g']:g}g" for r in self.rows]
        x = np.arange(len(self.rows))  # faulted rows are NaN: an empty slot, not a bar
        fig, ax = plt.subplots(figsize=(max(6.0, 0.28 * len(x)), 4.0))
        ax.bar(x - 0.2, [r["uncompensated_mm"] for r in self.rows], 0.4, label="PCC lengths (uncompensated)")
        ax.bar(x + 0.2, [r["compensated_mm"] for r in self.rows], 0.4, label="compensated tensions")
        ax.set_xticks(x, labels, rotation=90, fontsize=6)
        ax.set_ylabel("tip error under load (mm)")
        ax.legend()
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)
        return path

    def write_report(self, folder: str | Path) -> Path:
        """``report.md`` (summary and per-configuration table), ``compensation.png``, ``summary.json``."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        figure = self.plot(folder / "compensation.png")
        summary = self.summary()
        (folder / "summary.json").write_text(json.dumps({"summary": summary, "rows": self.rows}, indent=1))
        lines = ["# Load compensation over the validation grid", "",
                 f"Device `{self.device}`, endoscope horizontal. Target: the tip with 0 g under the PCC "
                 "tendon-length setpoints. **Uncompensated**: those lengths held in length mode while the "
                 "mass hangs. **Compensated**: tension mode, tensions from the Cosserat predictor and its "
                 f"Jacobian for the known load (bounded least squares, floor {self.floor_n:g} N, ceiling "
                 f"{self.limit_n:g} N), target = the predictor's tip at the measured unloaded tensions. "
                 "Errors are tracker distances to the target after settling. Goal: ≥ 80 % reduction.", "",
                 "## Summary", "",
                 markdown_table([{"tip mass": k, **v} for k, v in summary.items()]), "",
                 f"![errors per configuration]({figure.name})", "",
                 "## Per configuration", "",
                 markdown_table([{k: v for k, v in r.items() if k != "tensions_n"} | {
                     "tensions_n": " ".join(f"{t:.2f}" for t in r["tensions_n"])} for r in self.rows])]
        path = folder / "report.md"
        path.write_text("\n".join(lines))
        return path


def run_compensation_trial(device, params: Params, *, configs: Sequence[tuple[float, float]] | None = None,
                           masses_kg: Sequence[float] = (0.005, 0.010), floor_n: float = 1.0,
                           limit_n: float = 5.0, settle_timeout_s: float = 6.0,
                           tension_gains: dict | None = None, progress=None) -> CompensationTrial:
    """Run the trial on a connected device with a fixture and a tracker (endoscope horizontal).

    Args:
        device: the :class:`twin.device.Device`.
        params: parameter set of the predictor and of the PCC setpoints.
        configs: (κ 1/m, φ deg) pairs; default the thesis grid without κ = 0 (60 bends).
        masses_kg: tip masses (kg).
        floor_n, limit_n: tension bounds of the compensation (N).
        settle_timeout_s: longest wait for the tip to come to rest (device s).
        tension_gains: ``{"kp", "ki", "kd", "output_limit"}`` of the board's tension mode;
            default :data:`twin.control.tuning.TUNED_TENSION_GAINS`.
        progress: called with a one-line status after each configuration, or None.
    """
    model = RodModel.from_params(params)
    configs = list(configs or [(k, p) for k in GRID_KAPPA_PER_M if k > 0 for p in GRID_PHI_DEG])
    g = params.environment.gravity_m_s2
    rows = []
    for kappa, phi in configs:
        device.disable()
        device.set_gains("tensions", **(tension_gains or TUNED_TENSION_GAINS))
        zero = pretension_straight(device, params, mode="lengths")
        device.set_lengths(zero + tendon_length_changes_m(kappa, phi, params))
        settle(device, timeout_s=settle_timeout_s)
        unloaded = measure(device)
        target = unloaded.tip_position_m
        uncompensated = {}
        for mass in masses_kg:
            device.fixture.hang_tip_mass(mass)
            settle(device, timeout_s=settle_timeout_s)
            uncompensated[mass] = float(np.linalg.norm(measure(device).tip_position_m - target))
        device.fixture.hang_tip_mass(0.0)
        settle(device, timeout_s=settle_timeout_s)
        unloaded_tensions = measure(device).tensions_n
        bounds = dict(base_rotation=HORIZONTAL, floor_n=floor_n, limit_n=limit_n)
        hold = hold_tensions(model, unloaded_tensions, np.zeros(3), **bounds).tensions_n
        device.set_mode("tensions")
        device.set_tensions(hold)
        for mass in masses_kg:
            plan = hold_tensions(model, unloaded_tensions, GRAVITY_TIP_FORCE_N(mass, g), **bounds)
            row = {"kappa_per_m": kappa, "phi_deg": phi, "mass_g": round(mass * 1e3, 3),
                   "uncompensated_mm": uncompensated[mass] * 1e3, "compensated_mm": math.nan,
                   "reduction_pct": math.nan, "model_residual_mm": plan.residual_m * 1e3, "reached": plan.reached,
                   "fault": "", "tensions_n": plan.tensions_n.round(4).tolist()}
            rows.append(row)
            try:
                device.set_tensions(plan.tensions_n)
                device.fixture.hang_tip_mass(mass)
                settle(device, timeout_s=settle_timeout_s)
                error = float(np.linalg.norm(measure(device).tip_position_m - target))
                device.fixture.hang_tip_mass(0.0)
                device.set_tensions(hold)
            except (ProtocolError, CommandRejected) as exc:
                # A tripped tension limit is a result, not a crash: record it and go on.
                row["fault"] = str(exc).split(";")[0]
                device.fixture.hang_tip_mass(0.0)
                break
            row["compensated_mm"] = error * 1e3
            row["reduction_pct"] = 100.0 * (1.0 - error / uncompensated[mass])
        device.disable()
        if progress is not None:
            last = rows[-len(masses_kg):]
            progress(f"κ {kappa:g} φ {phi:g}: " + ", ".join(
                f"{r['mass_g']:g} g {r['uncompensated_mm']:.2f} → {r['compensated_mm']:.2f} mm" for r in last))
    return CompensationTrial(rows=rows, device=device.url, floor_n=floor_n, limit_n=limit_n)
