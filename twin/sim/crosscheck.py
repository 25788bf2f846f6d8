"""Cross-check of the twin against the predictor over the thesis validation grid (thesis §8.3).

Both are settled in statics under the same tendon tensions: for each grid configuration
(κ, φ, tip mass) the tensions that realise the PCC arc on top of the pretension
(:func:`twin.rod.grid.pcc_tensions_n`), the endoscope horizontal, gravity on, the mass hung at
the tip. The twin is driven by ideal tension sources and settled configuration after
configuration in the thesis's order (each from its neighbour's state); the predictor
(:mod:`twin.rod`) solves the same loads. The report gives the tip difference at the default
settings per configuration in mm and in % of L, the median and the worst, whether that meets
:data:`GOAL_MEDIAN_PCT` and :data:`GOAL_WORST_PCT`, and the causes of what differs, each
measured over the whole grid by changing one thing: the element count, the tendon routing (the
rig's straight chords between discs against the predictor's continuous routing, and the
continuous routing without the tendons' second-order length), the axial and shear joints and
where they sit, where the twist hinges sit, the torsion, the thesis's shear modulus, the time
step and the settling tolerance.

The twin has to stay faithful across robots, not only the endoscope: :data:`ROBOTS` names the
zoo's robots it is held to (``twin crosscheck --robot NAME``), and
:func:`crosscheck_status` gives any parameter set's verdict on :data:`QUICK_GRID`, for the reports
built on a twin to carry.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from twin.params import Params, load_params
from twin.robots import description, load_robot, robot_names
from twin.pcc import GRID_KAPPA_PER_M, GRID_TIP_MASS_KG, validation_grid
from twin.pose import pose_name
from twin.rod.grid import pcc_realisable, pcc_tensions_n
from twin.scaleout import map_ordered
from twin.sim.plant import Plant

__all__ = ["CAUSES", "GOAL_MEDIAN_PCT", "GOAL_WORST_PCT", "QUICK_GRID", "ROBOTS", "CrosscheckResult",
           "CrosscheckStatus", "cause_studies", "crosscheck", "crosscheck_status", "robot_params",
           "plot_crosscheck", "run_crosscheck", "run_zoo", "write_report"]

# The thesis's fitted shear modulus (Pa), §9.1; it needs shear slides at every station.
THESIS_SHEAR_MODULUS_PA = 4.7586e4
# What the twin must meet against the predictor, in % of the backbone length: the median and the
# worst tip difference over the grid, every configuration settled and solved.
GOAL_MEDIAN_PCT = 1.0
GOAL_WORST_PCT = 3.0
# Simulated time a configuration may take to come to rest (s): twice the slowest frictionless
# configuration's (long, κ 26.2 m⁻¹ with 10 g, 2.0 s). At μ 0.6 a plane change turns tendons'
# sliding over and releases a larger swing of the tip mass, which rings down in 3.2 s on long;
# rows that settle sooner cost nothing more.
SETTLE_TIMEOUT_S = 6.0
# The robots the twin is held to: the zoo (models/<name>/), the default first.
ROBOTS = robot_names()
# A reduced grid for quick verdicts and the tests, in the thesis's order: the straight rod with
# 0, 5 and 10 g, the curvature raised step by step in the plane φ = 0 with the 10 g, then every
# plane at the largest curvature with it, where every robot's worst configurations lie. The
# loads come on in steps, as in the full grid: hung at once from the straight 100 mm robot, 10 g
# swing at about 2 Hz with a damping ratio of about 0.2 and take over the settling's 3 s.
QUICK_GRID = [row for row in validation_grid() if row[0] < 2 or row[3] == max(GRID_TIP_MASS_KG) and (
    row[2] == 0.0 or row[1] == max(GRID_KAPPA_PER_M))]
# One thing changed against the defaults per study: (name, parameter overrides — "tendon_sites"
# is the plant's routing override —, whether the predictor sees the change too, settling
# tolerance m, why it matters).
CAUSES: tuple[tuple[str, dict[str, Any], bool, float, str], ...] = (
    ("N = 20 elements", {"sim.elements": 20}, False, 1e-6,
     "element count: the ends of the chain are straight half-elements and a tip load is lumped by "
     "the midpoint rule, both errors falling as 1/N²; N = 20 runs at a quarter of the speed."),
    ("N = 20, slides at every station: the predictor's strains, finely", {"sim.elements": 20, "sim.slide_stride": 1},
     False, 1e-6,
     "with the tendons' length to second order (their stiffening of twist and shear) what is left "
     "is the discretisation, falling as 1/N²: at N = 20 the worst tip is within 0.05 mm."),
    ("torsion G·J instead of E(Ixx+Iyy) (both models)", {"backbone.torsion": "GJ"}, True, 1e-6,
     "with the softer torsion (2GI) the tendons' stiffening of twist, ΣT·r² per unit twist, is "
     "nearly half the torsional stiffness; the twin has it as the predictor does."),
    ("continuous routing to first order: no tension stiffening", {"tendon_sites": "linear"}, False, 1e-6,
     "the fixed tendon alone, without the plant loop's second order (twin.sim.model.TendonLength): "
     "no stiffening of twist by ΣT·r² (15% of E(Ixx+Iyy) at 8 N) nor of shear by ΣT, so the tip "
     "mass twists the rod bent out of the vertical plane further, up to 0.34 mm at κ = 26.2 1/m; "
     "the median moves 0.01 mm and the discretisation happens to offset part of it."),
    ("continuous routing to first order, torsion G·J (both models)",
     {"tendon_sites": "linear", "backbone.torsion": "GJ"}, True, 1e-6,
     "the same with G·J, where ΣT·r² is nearly half the torsional stiffness: 2.3 mm worst."),
    ("continuous routing to first order, thesis G, slides at every station (both models)",
     {"tendon_sites": "linear", "backbone.shear_modulus_pa": THESIS_SHEAR_MODULUS_PA, "sim.slide_stride": 1},
     True, 1e-6,
     "the same with GA = 1.35 N, where the tendons' 5–9 N carry most of the shear stiffness: the "
     "goal is missed (4.6% of L at the median); compare the row with the second order below."),
    ("disc routing: straight chords between discs (the rig)", {"sim.tendon_routing": "discs"}, False, 1e-6,
     "the real rig's line runs in straight chords between discs; a chord across a bent joint lies "
     "off the offset towards the centre of curvature, so the pretension of all four tendons bends "
     "the rod further, by ΣT·ℓ²/(8EI) of the curvature for chords of length ℓ. The predictor routes "
     "the tendon continuously and has no such effect; the twin's continuous routing matches it."),
    ("chords one element long: N = 20, a site at every element's middle",
     {"sim.elements": 20, "tendon_sites": "elements"}, False, 1e-6,
     "the chord effect falls with the square of the chord: 3 mm chords instead of the discs' 6 mm."),
    ("no axial joints", {"sim.axial_joints": False}, False, 1e-6,
     "the tendons compress the backbone by ΣT·L/EA (0.15–0.25 mm at 5–9 N, EA = 2200 N), a "
     "shortening along the tip axis that would pass for a tracker offset."),
    ("no shear joints", {"sim.shear_joints": False}, False, 1e-6,
     "shear with the isotropic G (GA = 78 N): F·L/GA = 0.08 mm under the 10 g tip load, plus the "
     "weight's share. Small, but systematic: on twin data with every effect off (216 rows, seed 7) "
     "the discrepancy workflow fits a tip-load error of −0.9% (p = 2e-4) without the shear joints, "
     "−0.1% (p = 0.6) with them."),
    ("slides at every station instead of every fifth", {"sim.slide_stride": 1}, False, 1e-6,
     "lumping the small shear and axial compliance of five elements at their middle station."),
    ("twist hinges at the middle of every third station instead of every station", {"sim.twist_stride": 3},
     False, 1e-6,
     "lumping the torsional compliance of three elements at their middle station: a tip mass "
     "hanging from a rod bent out of the vertical plane twists it about tangents that turn along "
     "the rod, and one hinge per block turns the distal part about a single one of them."),
    ("time step 1 ms instead of the default sim.timestep_s", {"sim.timestep_s": 1e-3}, False, 1e-6,
     "the discrete integrator's statics do not depend on the step."),
    ("settled to 1e-7 m instead of 1e-6 m", {}, False, 1e-7,
     "settling: what is left to move after two quiet 20 ms windows."),
    ("thesis G, slides at every station (both models)",
     {"backbone.shear_modulus_pa": THESIS_SHEAR_MODULUS_PA, "sim.slide_stride": 1}, True, 1e-6,
     "with GA = 1.35 N, shear dominates, and the tendons' tension adds to GA (second order in the "
     "tendon length) in both models."),
    ("thesis G, slides at every station, disc routing (both models)",
     {"backbone.shear_modulus_pa": THESIS_SHEAR_MODULUS_PA, "sim.slide_stride": 1,
      "sim.tendon_routing": "discs"}, True, 1e-6,
     "the configuration of the first cross-check: below the 5–9 N the tendons press it with, "
     "GA = 1.35 N lets the backbone bow between discs (Engesser, P_cr ~ GA)."),
)


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
        wall_s: wall time of the run (s).
        left_out: configurations of the grid the robot's tendon layout cannot bend
            (:func:`twin.rod.grid.pcc_realisable`), not run.
    """

    rows: list
    twin_tip_m: np.ndarray
    rod_tip_m: np.ndarray
    settled: np.ndarray
    rod_converged: np.ndarray
    length_m: float
    elements: int
    wall_s: float
    left_out: tuple = ()

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
            "left_out": len(self.left_out),
            "meets_goal": self.meets_goal,
        }

    @property
    def meets_goal(self) -> bool:
        """True when every configuration was compared and the median and worst difference are
        within :data:`GOAL_MEDIAN_PCT` and :data:`GOAL_WORST_PCT` of L."""
        d = self.difference_m
        ok = np.isfinite(d) & self.settled
        if not ok.all():
            return False
        pct = 100.0 * d / self.length_m
        return bool(np.median(pct) <= GOAL_MEDIAN_PCT and np.max(pct) <= GOAL_WORST_PCT)

    def verdict(self) -> str:
        """One line: whether the goal is met, and by what."""
        s = self.summary()
        figures = (f"median {s['median_pct']:.2f}%, worst {s['worst_pct']:.2f}% of L over {s['compared']} of "
                   f"{s['configurations']} configurations (goal: median ≤ {GOAL_MEDIAN_PCT:g}%, worst ≤ "
                   f"{GOAL_WORST_PCT:g}%, all compared)")
        if self.left_out:
            figures += f"; {len(self.left_out)} configurations left out: the tendon layout cannot bend their planes"
        return f"goal met: {figures}" if self.meets_goal else f"GOAL MISSED: {figures}"


def crosscheck(params: Params | None = None, *, configs=None, elements: int | None = None,
               tendon_sites: str | None = None, settle_tol_m: float = 1e-6) -> CrosscheckResult:
    """Settle twin and predictor over ``configs`` (default the 216 of the validation grid), both
    with the clamp in the parameter set's ``rig.base_quat``.

    Args:
        params: parameter set (default ``models/endoscope/endoscope.toml``).
        configs: iterable of (config, κ, φ, mass) as :func:`twin.pcc.validation_grid` yields.
        elements, tendon_sites: overrides of the twin's discretisation (see :class:`twin.sim.plant.Plant`).
        settle_tol_m: the twin's settling tolerance (:meth:`twin.sim.plant.Plant.settle`).
    """
    from twin.rod import ConvergenceError, RodModel, solve

    params = params if params is not None else load_params()
    every = list(validation_grid() if configs is None else configs)
    # The straight rows (κ = 0) need no pull, whatever their plane.
    bendable = [row[1] == 0 or pcc_realisable(row[2], params) for row in every]
    rows = [row for row, ok in zip(every, bendable) if ok]
    left_out = tuple(row for row, ok in zip(every, bendable) if not ok)
    plant = Plant(params, elements=elements, tendon_sites=tendon_sites)
    rod = RodModel.from_params(params)
    g = params.environment.gravity_m_s2
    twin_tip = np.full((len(rows), 3), np.nan)
    rod_tip = np.full((len(rows), 3), np.nan)
    settled = np.zeros(len(rows), dtype=bool)
    converged = np.zeros(len(rows), dtype=bool)
    start = time.perf_counter()
    for k, (_, kappa, phi, mass) in enumerate(rows):
        tensions = pcc_tensions_n(kappa, phi, params)
        plant.set_tensions(tensions)
        plant.set_tip_mass_kg(mass)
        result = plant.settle(tol_m=settle_tol_m, timeout_s=SETTLE_TIMEOUT_S)
        settled[k] = result.settled
        twin_tip[k] = plant.tip_pose()[0]
        try:
            # With friction, the twin's state remembers how it got here; the predictor is given it.
            sol = solve(rod, tensions, tip_force_n=(0.0, 0.0, -mass * g), base_rotation=plant.base_rotation,
                        friction_direction=plant.sliding_state)
        except ConvergenceError:
            continue
        converged[k] = bool(sol.converged)
        if sol.converged:
            rod_tip[k] = sol.tip_position_m
    return CrosscheckResult(rows, twin_tip, rod_tip, settled, converged, params.backbone.length_m,
                            plant.layout.elements, time.perf_counter() - start, left_out)


def robot_params(name: str, overrides: dict | None = None) -> Params:
    """Robot ``name``'s parameter set (:func:`twin.robots.load_robot`), ``overrides`` on top.

    Raises:
        ValueError: ``name`` is not a robot of the zoo.
    """
    return load_robot(name, overrides or {})


@dataclasses.dataclass(frozen=True)
class CrosscheckStatus:
    """A parameter set's cross-check verdict on :data:`QUICK_GRID`.

    Attributes:
        meets_goal: :attr:`CrosscheckResult.meets_goal` there.
        median_pct, worst_pct: the tip difference in % of L.
        verdict: :meth:`CrosscheckResult.verdict`.
    """

    meets_goal: bool
    median_pct: float
    worst_pct: float
    verdict: str

    @property
    def warning(self) -> str | None:
        """The line a report built on this twin must carry, or None when the goal is met."""
        if self.meets_goal:
            return None
        return (f"Warning: this twin is out of bounds against the predictor ({self.verdict}); "
                "its numbers stand for the robot only that far (`twin crosscheck`).")


def crosscheck_status(params: Params | None = None) -> CrosscheckStatus:
    """The verdict of a quick cross-check (:data:`QUICK_GRID`, about a second) of ``params``
    (default ``models/endoscope/endoscope.toml``), computed once per parameter set and process."""
    return _status(params if params is not None else load_params())


@functools.lru_cache(maxsize=32)
def _status(params: Params) -> CrosscheckStatus:
    # Parameter sets hash and compare by value (their sources aside).
    result = crosscheck(params, configs=QUICK_GRID)
    s = result.summary()
    return CrosscheckStatus(result.meets_goal, s["median_pct"], s["worst_pct"], result.verdict())


def cause_studies(params: Params) -> list[tuple[str, bool, CrosscheckResult]]:
    """The twin (and, where marked, the predictor) with one thing changed, over the whole grid:
    ``(name, predictor changed too, result)`` per :data:`CAUSES`."""
    studies = []
    for name, values, both, tol, _ in CAUSES:
        overrides = {k: v for k, v in values.items() if k != "tendon_sites"}
        result = crosscheck(params.replace(overrides), tendon_sites=values.get("tendon_sites"), settle_tol_m=tol)
        studies.append((name, both, result))
    return studies


def plot_crosscheck(result: CrosscheckResult, path: str | Path) -> Path:
    """The report's opening figure: twin-to-predictor tip difference (% of L) over the bending
    plane, one line per curvature, one panel per tip mass, against the goal's median line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = np.array([r[1:] for r in result.rows], dtype=float).reshape(-1, 3)
    pct = 100.0 * result.difference_m / result.length_m
    masses = np.unique(rows[:, 2])
    fig, axes = plt.subplots(1, len(masses), figsize=(min(4.2 * len(masses), 15.0), 3.8), sharey=True,
                             squeeze=False)
    for ax, mass in zip(axes[0], masses):
        for kappa in np.unique(rows[:, 0]):
            sel = (rows[:, 2] == mass) & (rows[:, 0] == kappa)
            order = np.argsort(rows[sel, 1])
            ax.plot(rows[sel, 1][order], pct[sel][order], "o-", ms=3, lw=1, label=f"κ={kappa:g}")
        ax.axhline(GOAL_MEDIAN_PCT, color="k", ls="--", lw=0.8, label=f"goal: median ≤ {GOAL_MEDIAN_PCT:g}%")
        ax.set(title=f"tip mass {mass * 1e3:g} g", xlabel="bending plane φ (deg)")
        ax.grid(alpha=0.3)
    # A single bending plane (or a narrow set) would autoscale to ±0.05°: pad to a readable span.
    phi_low, phi_high = np.min(rows[:, 1]), np.max(rows[:, 1])
    pad = max(10.0, 0.05 * (phi_high - phi_low))
    for ax in axes[0]:
        ax.set_xlim(phi_low - pad, phi_high + pad)
    top = np.nanmax(pct) if np.isfinite(pct).any() else GOAL_MEDIAN_PCT
    axes[0][0].set_ylim(0.0, 1.1 * max(top, GOAL_MEDIAN_PCT))
    # A distance, never signed: |tip_twin − tip_predictor|.
    axes[0][0].set_ylabel("twin-to-predictor tip distance\n|p_twin − p_pred| (% of L)")
    axes[0][-1].legend(fontsize=7, title=f"curvature (1/m); worst-case goal {GOAL_WORST_PCT:g}%", title_fontsize=7)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_report(result: CrosscheckResult, studies, out_dir: str | Path, params: Params, *,
                 robot: str | None = None) -> Path:
    """Write ``crosscheck.md``, ``crosscheck.csv`` and ``crosscheck.png`` (:func:`plot_crosscheck`,
    which opens the report) into ``out_dir``; returns the Markdown path.

    Args:
        robot: the :data:`ROBOTS` name ``params`` stand for, if any (named in the title).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    s = result.summary()
    sim = params.sim
    d_mm = result.difference_m * 1e3
    pct = 100 * result.difference_m / result.length_m
    named = f" ({robot}: models/{robot}/)" if robot else ""
    lines = [
        f"# Twin vs predictor over the thesis validation grid{named}",
        "",
        "Written by `twin crosscheck` (`twin.sim.crosscheck`); per-configuration tips in `crosscheck.csv`.",
        "",
        f"**{'Goal met' if result.meets_goal else 'GOAL MISSED'}**: {result.verdict().split(': ', 1)[1]}.",
        "",
        f"![twin vs predictor tip difference per configuration]({plot_crosscheck(result, out / 'crosscheck.png').name})",
        "",
        f"L = {params.backbone.length_m * 1e3:g} mm, {params.tendons.count} tendons routed "
        f"{params.tendons.routing}, torsion {params.backbone.torsion}, G = {params.backbone.shear_modulus_pa:.4g} Pa. "
        f"Base clamped {pose_name(params.rig.base_rotation)}, gravity on; tensions `pcc_tensions_n(κ, φ)` = pretension "
        f"({params.tendons.pretension_n} N) + EI·κ/r·max(0, cos(φ − α_i)); tip mass hung at the tip. Twin: "
        f"N = {sim.elements} elements, {sim.timestep_s * 1e3:g} ms steps, "
        f"{'axial' if sim.axial_joints else 'no axial'} and {'shear' if sim.shear_joints else 'no shear'} "
        f"joints ({_stations('slides', sim.slide_stride)}), {_stations('twist hinges', sim.twist_stride)}, "
        f"{sim.tendon_routing} tendon "
        "routing, ideal tension sources, settled to 1 µm over two 20 ms windows "
        f"(at most {SETTLE_TIMEOUT_S:g} s of simulated time), configurations in the "
        "thesis's order. Predictor: `twin.rod.solve`. "
        f"Wall time {result.wall_s:.1f} s for the {len(result.rows)}.",
        "",
        "| tip difference | median | worst | goal |",
        "| --- | --- | --- | --- |",
        f"| mm | {s['median_mm']:.3f} | {s['worst_mm']:.3f} | ~0.1–0.2 (tracker noise) |",
        f"| % of L | {s['median_pct']:.2f} | {s['worst_pct']:.2f} | ≤ 1 median, ≤ 3 worst |",
        "",
        f"Worst configuration: {_config(s['worst_config'])}. Compared {s['compared']} of "
        f"{s['configurations']}; twin unsettled: {s['unsettled']}; predictor failed: {s['rod_failed']}.",
        "",
        "## Causes, each measured over the whole grid",
        "",
        "Each row changes one thing against the defaults. *vs predictor*: the tip difference as above "
        "(the predictor changed too where marked). *moves the twin*: how far the change moves the "
        "twin's own tips from the defaults' — the size of the cause itself.",
        "",
        "| change | vs predictor: median / worst (mm) | median (% L) | moves the twin: median / worst (mm) "
        "| wall (s) |",
        "| --- | --- | --- | --- | --- |",
        f"| none (defaults) | {s['median_mm']:.3f} / {s['worst_mm']:.3f} | {s['median_pct']:.2f} | — "
        f"| {result.wall_s:.1f} |",
    ]
    for name, both, r in studies:
        ss = r.summary()
        if both:
            moved = "— (both changed)"
        else:
            shift = np.linalg.norm(r.twin_tip_m - result.twin_tip_m, axis=1) * 1e3
            moved = f"{np.nanmedian(shift):.3f} / {np.nanmax(shift):.3f}"
        flag = f" ({ss['unsettled']} unsettled)" if ss["unsettled"] else ""
        lines.append(f"| {name}{flag} | {ss['median_mm']:.3f} / {ss['worst_mm']:.3f} | {ss['median_pct']:.2f} | "
                     f"{moved} | {r.wall_s:.1f} |")
    why = {name: text for name, _, _, _, text in CAUSES}
    lines += ["", "Why each matters:", ""]
    lines += [f"- *{name}*: {why[name]}" for name, _, _ in studies if name in why]
    lines += ["", "## The largest differences at the defaults", "",
              "| config | κ (1/m) | φ (deg) | mass (g) | twin tip (mm) | predictor tip (mm) | diff (mm) | diff (% L) |",
              "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for k in np.argsort(-np.nan_to_num(d_mm))[:10]:
        config, kappa, phi, mass = result.rows[k]
        tw, rd = result.twin_tip_m[k] * 1e3, result.rod_tip_m[k] * 1e3
        lines.append(f"| {config} | {kappa:g} | {phi:g} | {mass * 1e3:g} | {tw[0]:.2f}, {tw[1]:.2f}, {tw[2]:.2f} | "
                     f"{rd[0]:.2f}, {rd[1]:.2f}, {rd[2]:.2f} | {d_mm[k]:.3f} | {pct[k]:.2f} |")
    path = out / "crosscheck.md"
    path.write_text("\n".join(lines) + "\n")
    csv = ["config,kappa_per_m,phi_deg,mass_kg,twin_x_m,twin_y_m,twin_z_m,rod_x_m,rod_y_m,rod_z_m,diff_m,settled"]
    for k, (config, kappa, phi, mass) in enumerate(result.rows):
        csv.append(",".join(f"{v:.9g}" if isinstance(v, float) else str(v) for v in (
            config, kappa, phi, mass, *result.twin_tip_m[k], *result.rod_tip_m[k], result.difference_m[k],
            bool(result.settled[k]))))
    (out / "crosscheck.csv").write_text("\n".join(csv) + "\n")
    return path


def _stations(joints: str, stride: int) -> str:
    return f"{joints} at every station" if stride == 1 else f"{joints} at the middle of every {stride} stations"


def _config(row) -> str:
    if row is None:
        return "none compared"
    config, kappa, phi, mass = row
    return f"#{config} (κ {kappa:g} 1/m, φ {phi:g}°, {mass * 1e3:g} g)"


def run_crosscheck(params: Params | None = None, out_dir: str | Path = "reports/crosscheck",
                   *, with_causes: bool = True, configs=None, robot: str | None = None) -> tuple[Path, dict]:
    """The full cross-check: grid (``configs``, default all 216), cause studies and report.
    Returns (report path, summary); ``summary["meets_goal"]`` is the verdict."""
    params = params if params is not None else load_params()
    result = crosscheck(params, configs=configs)
    studies = cause_studies(params) if with_causes else []
    return write_report(result, studies, out_dir, params, robot=robot), result.summary()


def _robot_crosscheck(job) -> tuple[CrosscheckResult, list]:
    """One robot's grid and, if asked, cause studies: a job of :func:`run_zoo`."""
    params, configs, with_causes = job
    return crosscheck(params, configs=configs), cause_studies(params) if with_causes else []


def run_zoo(out_dir: str | Path = "reports/crosscheck", *, configs=None, overrides: dict | None = None,
            robots: Sequence[str] | None = None, workers: int = 1, cluster: str | None = None,
            with_causes: bool = True) -> tuple[Path, dict[str, dict]]:
    """Every robot of ``robots`` (default :data:`ROBOTS`) over the grid: each one's report in
    ``out_dir/<robot>/`` (the default robot's in ``out_dir`` itself, with the cause studies) and a
    table of all in ``out_dir/zoo.md``. The cause studies (``with_causes``) cover the whole grid, so
    they run only when ``configs`` is the whole grid (None). One job per robot, run by :func:`twin.scaleout.map_ordered`
    (``workers`` local processes, or the Ray ``cluster``); the reports are written here.
    Returns (table path, {robot: summary})."""
    out = Path(out_dir)
    names = list(ROBOTS if robots is None else robots)
    default = next(iter(ROBOTS))
    params = {name: robot_params(name, overrides) for name in names}
    causes = with_causes and configs is None
    outcomes = map_ordered(_robot_crosscheck, [(params[name], configs, causes and name == default) for name in names],
                           workers=workers, cluster=cluster)
    summaries = {}
    for name, (result, studies) in zip(names, outcomes):
        write_report(result, studies, out if name == default else out / name, params[name], robot=name)
        summaries[name] = result.summary()
    lines = ["# Twin vs predictor across the robots", "",
             "Written by `twin crosscheck --robot all`; each robot's report beside it "
             f"(goal: median ≤ {GOAL_MEDIAN_PCT:g}%, worst ≤ {GOAL_WORST_PCT:g}% of L, every configuration compared).",
             "", "| robot | what it is | median (% L) | worst (% L) | worst (mm) | worst configuration | verdict |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for name, s in summaries.items():
        lines.append(f"| {name} | {description(name)} | {s['median_pct']:.2f} | {s['worst_pct']:.2f} | "
                     f"{s['worst_mm']:.3f} | {_config(s['worst_config'])} | "
                     f"{'met' if s['meets_goal'] else 'MISSED'} |")
    table = out / "zoo.md"
    out.mkdir(parents=True, exist_ok=True)
    table.write_text("\n".join(lines) + "\n")
    return table, summaries
