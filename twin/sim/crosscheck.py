"""Cross-check of the twin against the predictor over the thesis validation grid (SPEC §5).

Both are settled in statics under the same tendon tensions: for each grid configuration
(κ, φ, tip mass) the tensions that realise the PCC arc on top of the pretension,

    τ_i = pretension + (EI κ / r) · max(0, cos(φ − α_i)),

the endoscope horizontal, gravity on, the mass hung at the tip. The twin is driven by ideal
tension sources and settled configuration after configuration in the thesis's order (each from
its neighbour's state); the predictor (:mod:`twin.rod`) solves the same loads. The report gives
the tip difference per configuration in mm and in % of L, the median and the worst, and the
causes of the difference measured on a subset of the grid: element count, straight tendon
chords between discs against the predictor's continuous routing, the shear softness of the
thesis's G, and settling.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from twin.params import Params, load_params
from twin.pcc import validation_grid
from twin.pose import HORIZONTAL
from twin.sim.plant import Plant

__all__ = ["CrosscheckResult", "crosscheck", "grid_tensions_n", "run_crosscheck", "write_report"]

# Configurations the cause studies re-run (κ 1/m, φ deg, tip mass kg): both bending planes of
# the tendons, the largest curvature, unloaded and with the heaviest load.
CAUSE_SUBSET = ((8.7, 0.0, 0.0), (26.2, 0.0, 0.0), (26.2, 90.0, 0.01), (26.2, 180.0, 0.01),
                (13.0, 270.0, 0.005), (17.5, 30.0, 0.0))


def grid_tensions_n(params: Params, kappa_per_m: float, phi_deg: float) -> np.ndarray:
    """(n,) tensions (N) realising a PCC configuration on top of the pretension."""
    alpha = np.radians(params.tendons.angles_deg)
    bend = params.backbone.bending_stiffness_nm2 * kappa_per_m / params.tendons.radius_m
    return params.tendons.pretension_n + bend * np.maximum(0.0, np.cos(np.radians(phi_deg) - alpha))


@dataclasses.dataclass(frozen=True)
class CrosscheckResult:
    """Per-configuration tips of both models.

    Attributes:
        rows: (config, κ 1/m, φ deg, mass kg) per configuration.
        twin_tip_m, rod_tip_m: (K, 3) tips (m, world frame); NaN where a model failed.
        settled: (K,) whether the twin settled.
        rod_converged: (K,) whether the predictor converged.
        length_m: backbone length L.
        elements: the twin's element count.
        wall_s: wall time of the run.
    """

    rows: list
    twin_tip_m: np.ndarray
    rod_tip_m: np.ndarray
    settled: np.ndarray
    rod_converged: np.ndarray
    length_m: float
    elements: int
    wall_s: float

    @property
    def difference_m(self) -> np.ndarray:
        return np.linalg.norm(self.twin_tip_m - self.rod_tip_m, axis=1)

    def summary(self) -> dict:
        """Median and worst difference (mm and % of L) over configurations where both answered."""
        d = self.difference_m
        ok = np.isfinite(d) & self.settled
        pct = 100.0 * d / self.length_m
        worst = int(np.nanargmax(np.where(ok, d, np.nan))) if ok.any() else -1
        return {
            "configurations": len(self.rows),
            "compared": int(ok.sum()),
            "median_mm": float(np.median(d[ok]) * 1e3) if ok.any() else math.nan,
            "median_pct": float(np.median(pct[ok])) if ok.any() else math.nan,
            "worst_mm": float(d[worst] * 1e3) if worst >= 0 else math.nan,
            "worst_pct": float(pct[worst]) if worst >= 0 else math.nan,
            "worst_config": self.rows[worst] if worst >= 0 else None,
            "unsettled": int((~self.settled).sum()),
            "rod_failed": int((~self.rod_converged).sum()),
        }


def crosscheck(params: Params | None = None, *, configs=None, elements: int | None = None,
               tendon_sites: str = "discs", settle_tol_m: float = 1e-6) -> CrosscheckResult:
    """Settle twin and predictor over ``configs`` (default the 216 of the validation grid).

    Args:
        params: parameter set (default ``models/endoscope.toml``).
        configs: iterable of (config, κ, φ, mass) as :func:`twin.pcc.validation_grid` yields.
        elements, tendon_sites: the twin's discretisation (see :class:`twin.sim.plant.Plant`).
        settle_tol_m: the twin's settling tolerance (:meth:`twin.sim.plant.Plant.settle`).
    """
    from twin.rod import ConvergenceError, RodModel, solve

    params = params if params is not None else load_params()
    rows = list(validation_grid() if configs is None else configs)
    plant = Plant(params, base_rotation=HORIZONTAL, elements=elements, tendon_sites=tendon_sites)
    rod = RodModel.from_params(params)
    g = params.environment.gravity_m_s2
    twin_tip = np.full((len(rows), 3), np.nan)
    rod_tip = np.full((len(rows), 3), np.nan)
    settled = np.zeros(len(rows), dtype=bool)
    converged = np.zeros(len(rows), dtype=bool)
    start = time.perf_counter()
    for k, (_, kappa, phi, mass) in enumerate(rows):
        tensions = grid_tensions_n(params, kappa, phi)
        plant.set_tensions(tensions)
        plant.set_tip_mass_kg(mass)
        result = plant.settle(tol_m=settle_tol_m)
        settled[k] = result.settled
        twin_tip[k] = plant.tip_pose()[0]
        try:
            sol = solve(rod, tensions, tip_force_n=(0.0, 0.0, -mass * g), base_rotation=HORIZONTAL)
        except ConvergenceError:
            continue
        converged[k] = bool(sol.converged)
        if sol.converged:
            rod_tip[k] = sol.tip_position_m
    return CrosscheckResult(rows, twin_tip, rod_tip, settled, converged, params.backbone.length_m,
                            plant.layout.elements, time.perf_counter() - start)


def _subset_rows():
    return [(i, k, p, m) for i, (k, p, m) in enumerate(CAUSE_SUBSET)]


def cause_studies(params: Params, elements: int) -> list[tuple[str, CrosscheckResult]]:
    """The twin variants that isolate each cause, run over :data:`CAUSE_SUBSET`."""
    rows = _subset_rows()
    iso_g = params.replace({"backbone.shear_modulus_pa": params.backbone.youngs_modulus_pa / 2.8})
    studies = [(f"N = {n} elements, disc routing", dict(elements=n)) for n in (5, 10, 20, 30)]
    studies += [
        (f"N = {elements}, a tendon site at every element (near-continuous routing)",
         dict(elements=elements, tendon_sites="elements")),
        (f"N = {elements}, settled to 1e-7 m instead of 1e-6 m", dict(elements=elements, settle_tol_m=1e-7)),
    ]
    out = [(name, crosscheck(params, configs=rows, **kw)) for name, kw in studies]
    out.append((f"N = {elements}, disc routing, isotropic G = E/2.8 (both models)",
                crosscheck(iso_g, configs=rows, elements=elements)))
    out.append((f"N = {elements}, near-continuous routing, isotropic G = E/2.8 (both models)",
                crosscheck(iso_g, configs=rows, elements=elements, tendon_sites="elements")))
    return out


def write_report(result: CrosscheckResult, studies, out_dir: str | Path, params: Params) -> Path:
    """Write ``crosscheck.md`` (and ``crosscheck.csv``) into ``out_dir``; returns the Markdown path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    s = result.summary()
    d_mm = result.difference_m * 1e3
    pct = 100 * result.difference_m / result.length_m
    lines = [
        "# Twin vs predictor over the thesis validation grid",
        "",
        f"Endoscope horizontal, gravity on; tensions = pretension ({params.tendons.pretension_n} N) + "
        "EI·κ/r·max(0, cos(φ − α_i)); tip mass hung at the tip. Twin: "
        f"{result.elements} elements, ideal tension sources, settled to 1 µm per 20 ms window, "
        f"configurations in the thesis's order; predictor: `twin.rod.solve`. Wall time {result.wall_s:.1f} s.",
        "",
        "| | median | worst | goal |",
        "| --- | --- | --- | --- |",
        f"| tip difference (mm) | {s['median_mm']:.3f} | {s['worst_mm']:.3f} | |",
        f"| tip difference (% of L) | {s['median_pct']:.2f} | {s['worst_pct']:.2f} | ≤ 1 median, ≤ 3 worst |",
        "",
        f"Worst configuration: {s['worst_config']} (config, κ 1/m, φ deg, mass kg). "
        f"Compared {s['compared']} of {s['configurations']}; twin unsettled: {s['unsettled']}; "
        f"predictor failed: {s['rod_failed']}.",
        "",
        "## Causes, measured on a subset of the grid",
        "",
        "Each row re-runs the subset " + ", ".join(f"(κ {k}, φ {p:g}°, {m * 1e3:g} g)" for k, p, m in CAUSE_SUBSET)
        + " with one thing changed.",
        "",
        "| twin variant | median (mm) | worst (mm) | median (% L) |",
        "| --- | --- | --- | --- |",
    ]
    for name, r in studies:
        ss = r.summary()
        lines.append(f"| {name} | {ss['median_mm']:.3f} | {ss['worst_mm']:.3f} | {ss['median_pct']:.2f} |")
    lines += [
        "",
        "Reading the table: the predictor routes each tendon continuously at its offset, so equal",
        "tensions put no net moment on it at any curvature. The rig's line runs in straight chords",
        "between discs; on a bent rod every chord lies a sagitta κℓ²/8 towards the centre of",
        "curvature, so the pretension of all four tendons bends the rod further — the twin's",
        "difference falls when the twin gets a site at every element. With the thesis's G",
        "(GA ≈ 1.35 N, below the ~5.4 N the tendons press the backbone with) the backbone between",
        "two discs is shear-soft under that compression, which amplifies the bow; with an isotropic",
        "G the amplification goes and the disc-routing difference is the chord sagitta alone.",
        "Settling to a tighter tolerance changes the tips by far less than the differences.",
        "",
        "## Per configuration",
        "",
        "| config | κ (1/m) | φ (deg) | mass (g) | twin tip (mm) | predictor tip (mm) | diff (mm) | diff (% L) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    csv = ["config,kappa_per_m,phi_deg,mass_kg,twin_x_m,twin_y_m,twin_z_m,rod_x_m,rod_y_m,rod_z_m,diff_m,settled"]
    for k, (config, kappa, phi, mass) in enumerate(result.rows):
        tw, rd = result.twin_tip_m[k] * 1e3, result.rod_tip_m[k] * 1e3
        flag = "" if result.settled[k] else " (unsettled)"
        lines.append(
            f"| {config} | {kappa:g} | {phi:g} | {mass * 1e3:g} | {tw[0]:.2f}, {tw[1]:.2f}, {tw[2]:.2f} | "
            f"{rd[0]:.2f}, {rd[1]:.2f}, {rd[2]:.2f} | {d_mm[k]:.3f}{flag} | {pct[k]:.2f} |")
        csv.append(",".join(str(v) for v in (config, kappa, phi, mass, *result.twin_tip_m[k], *result.rod_tip_m[k],
                                             result.difference_m[k], bool(result.settled[k]))))
    path = out / "crosscheck.md"
    path.write_text("\n".join(lines) + "\n")
    (out / "crosscheck.csv").write_text("\n".join(csv) + "\n")
    return path


def run_crosscheck(params: Params | None = None, out_dir: str | Path = "reports/crosscheck",
                   *, elements: int | None = None, with_causes: bool = True) -> tuple[Path, dict]:
    """The full cross-check: grid, cause studies and report. Returns (report path, summary)."""
    params = params if params is not None else load_params()
    result = crosscheck(params, elements=elements)
    studies = cause_studies(params, result.elements) if with_causes else []
    return write_report(result, studies, out_dir, params), result.summary()
