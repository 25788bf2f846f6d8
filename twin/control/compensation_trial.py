"""Load compensation on a device over the validation grid: PCC length setpoints against
model-compensated tensions, the tip error under 5 g and 10 g.

For each (κ, φ), in the device's pose: pretension straight, drive the PCC tendon lengths in length
mode and measure the unloaded tip — the target — and the tensions. Then, per tip mass:

1. **uncompensated** (the thesis's experiment): hang the mass with the PCC lengths held, measure;
2. **feed-forward**: switch the board to tension mode and ramp the tensions to those
   :func:`twin.control.compensation.hold_tensions` computes from the unloaded tensions and the
   known load; wait for the tip to come to rest, measure;
3. **corrected**: up to ``corrections`` times, re-aim the predictor by the model error the
   tracker's miss reveals (:func:`twin.control.compensation.correct_tensions`), ramp, rest,
   measure; stop early once that error is within ``correction_tolerance_m``. From the second
   correction on, each re-aims by the error over the share of its predicted move the last one
   made (:func:`twin.control.compensation.response_gain`, at most twice the error): under a
   tendon friction the model lacks, a full step falls short. Then keep the best command
   measured: one measured better than the last, the PCC lengths included, is commanded again
   and measured afresh. Under tendon friction the length mode can hold the loaded tip closer
   than the tension loop can put it (the endoscope at κ 26.2, φ 0, 10 g, μ = 0.1 hidden:
   0.10 mm uncompensated, 0.27 mm after four corrections; kept at the PCC lengths, 0.09 mm). A
   row is worse than uncompensated when its error is larger by more than the tracker can
   resolve (:func:`resolvably_larger`: two standard errors of the two means);
4. back to length mode at the PCC lengths, for the next mass.

Errors are tracker distances of the resting, loaded tip from the target (means over ``measure_s``).
A mass whose tensions trip the board's limit is recorded as faulted, not dropped, and so are the
masses of that configuration it left unrun.

Why this order and these waits (measured on the twin, ``sim://?seed=0``): under tension control
the endoscope is soft and its swing lightly damped — 10 g hung in tension mode sags the tip
~12 mm and sets off a ~1.7 Hz swing (damping ratio ~0.1) that takes ~7 s to fall under 0.1 mm;
hung in length mode it sags ~3 mm and is within 0.1 mm of rest in 0.5 s. So the mass goes on in
length mode and the compensation comes in by a smooth ramp. The switch itself still kicks the tip
by 2–7 mm (the board restarts the tension PID's integral at zero, so the motors let go for a few
control periods) and the tip is within ~0.15 mm of rest ~4 s after the ramp; it then keeps a
~0.1 mm jitter (load-cell noise through the soft tension-mode tip), which the measurement window
averages out. The ramp also takes slack tendons up gently: the step from slack to the old 1 N
floor spun a spool up to the duty clamp and its bite tripped the 6 N limit at κ = 17.5 and 26.2.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from twin.control.compensation import (GAIN_RESOLVE_SIGMAS, correct_tensions, hold_tensions, response_gain,
                                       unloaded_tips)
from twin.control.pretension import pretension_straight
from twin.control.gains import tension_gains_for
from twin.driver import CommandRejected
from twin.effects import SlidingState, friction_direction
from twin.experiments.protocols import Measurement, NotAtRestError, ProtocolError, measure, wait_for_rest
from twin.experiments.report import markdown_table
from twin.params import Params
from twin.pcc import GRID_KAPPA_PER_M, GRID_PHI_DEG, tendon_length_changes_m, validation_grid
from twin.rod import RodModel
from twin.rod.grid import GRAVITY_TIP_FORCE_N, pcc_realisable, pcc_tensions_n

__all__ = ["CompensationTrial", "run_compensation_trial", "tension_ceiling_n", "swing_limit_n", "compensation_grid",
           "within_reach",
           "resolvably_larger", "QUICK_CONFIGS", "GOAL_REDUCTION_PCT", "RESOLVE_SIGMAS"]

# A few (κ 1/m, φ deg) across curvature and bending direction (up, down, sideways), for --quick.
QUICK_CONFIGS = ((8.7, 0.0), (13.0, 90.0), (17.5, 180.0), (26.2, 270.0), (4.5, 30.0), (17.5, 240.0))

# The goal of model-based compensation: the tip error under load drops by at least 80 % against the PCC setpoints.
GOAL_REDUCTION_PCT = 80.0

# A mass whose best tensions within the bounds leave more than this share of the sag the load
# causes (by the predictor) is out of reach; the thesis endoscope's hardest rows leave 0.3 of it.
_REACH_SHARE = 0.5

# The three tip errors a row reports, and their labels in the summary and the plot.
_STAGES = (("uncompensated", "PCC lengths (uncompensated)"), ("feedforward", "feed-forward tensions"),
           ("corrected", "feed-forward + tracker correction"))


@dataclasses.dataclass(frozen=True)
class CompensationTrial:
    """Tip errors under load — uncompensated, feed-forward, corrected — one row per (κ, φ, mass).

    Row keys: ``kappa_per_m``, ``phi_deg``, ``mass_g``; ``uncompensated_mm``, ``feedforward_mm``,
    ``corrected_mm`` (tracker distances to the target, mm; NaN where the row faulted first);
    ``feedforward_reduction_pct``, ``corrected_reduction_pct`` (against uncompensated);
    ``model_residual_mm`` (the predictor's own miss of the target at the feed-forward tensions,
    within the bounds), ``reached`` (that miss is within tolerance), ``corrections`` (applied),
    ``feedforward_tensions_n``, ``tensions_n`` (those the row ended with), ``fault`` (empty, or what
    stopped the row); ``uncompensated_sem_mm``, ``corrected_sem_mm`` (standard errors of those two
    errors, mm, from the tracker frames' scatter) and ``kept`` (the command the row ended with:
    ``last``, or an earlier one measured better — ``feed-forward``, ``correction k``,
    ``PCC lengths`` — commanded again and measured afresh); ``peak_tension_n`` (the highest cell
    reading under the tension commands, N), ``swung`` (a command's cells read over
    :func:`swing_limit_n`) and ``unsettled`` (a command left the tip moving past the wait for
    rest): such commands are neither corrected nor kept.

    ``floor_n``, ``limit_n`` are the tension bounds (N), ``corrections`` the most corrections per
    mass, ``timing_s`` the ramp, rest and averaging durations (device s) the trial ran with,
    ``left_out`` the configurations of the grid left out before running, each
    ``{"kappa_per_m", "phi_deg", "reason"}`` (:func:`within_reach`).
    """

    rows: list[dict]
    device: str
    floor_n: float
    limit_n: float
    corrections: int
    timing_s: dict
    left_out: list = dataclasses.field(default_factory=list)

    def worse_rows(self) -> list[dict]:
        """Rows whose compensated (final) tip error is larger than the uncompensated one beyond
        what the tracker can measure (:func:`resolvably_larger` of the two errors' standard
        errors; a row without them, every excess): a compensation that made things worse, never
        to be read as an ordinary result."""
        return [r for r in self.rows if not r["fault"] and _worse(r)]

    def verdict(self) -> tuple[bool, list[str]]:
        """Whether the trial met its goal, and one line per way it did not: faulted rows, rows
        worse than uncompensated, a median reduction of the compensated error under
        :data:`GOAL_REDUCTION_PCT`, or nothing run at all."""
        s = self.summary()["all"]
        problems = []
        if s["faulted"]:
            faults = sorted({r["fault"] for r in self.rows if r["fault"] and not r["fault"].startswith("not run")})
            problems.append(f"{s['faulted']} of {len(self.rows)} rows faulted ({'; '.join(faults)})")
        for r in self.worse_rows():
            problems.append(f"κ {r['kappa_per_m']:g} φ {r['phi_deg']:g} {r['mass_g']:g} g: compensated "
                            f"{r['corrected_mm']:.2f} mm is WORSE than uncompensated {r['uncompensated_mm']:.2f} mm"
                            + _sem_text(r))
        if not s["configurations"]:
            problems.append("no row ran to the end")
        elif not s["corrected_median_reduction_pct"] >= GOAL_REDUCTION_PCT:
            problems.append(f"median reduction {s['corrected_median_reduction_pct']:.1f} % misses the "
                            f"{GOAL_REDUCTION_PCT:g} % goal")
        return not problems, problems

    def summary(self) -> dict:
        """Per tip mass and overall, over the rows that ran to the end (``faulted`` counts the
        others): median and worst error of each stage (mm), the median per-row reduction of the
        feed-forward and of the corrected tensions (%), and how many rows reach the 80 % goal."""
        out = {}
        for label, group in [("all", self.rows)] + [(f"{m:g} g", [r for r in self.rows if r["mass_g"] == m])
                                                    for m in sorted({r["mass_g"] for r in self.rows})]:
            rows = [r for r in group if not r["fault"]]
            entry: dict[str, float] = {"configurations": len(rows), "faulted": len(group) - len(rows)}
            for stage, _ in _STAGES:
                errors = np.array([r[f"{stage}_mm"] for r in rows])
                entry[f"{stage}_median_mm"] = float(np.median(errors)) if rows else math.nan
                entry[f"{stage}_worst_mm"] = float(errors.max()) if rows else math.nan
            for stage in ("feedforward", "corrected"):
                reductions = np.array([r[f"{stage}_reduction_pct"] for r in rows])
                entry[f"{stage}_median_reduction_pct"] = float(np.median(reductions)) if rows else math.nan
                entry[f"{stage}_rows_at_goal"] = int(np.sum(reductions >= GOAL_REDUCTION_PCT))
            out[label] = entry
        return out

    def _load_text(self) -> str:
        """How the load was known, for the report's method paragraph."""
        ran = [r for r in self.rows if "load" in r]
        if not ran:
            return ""
        side = max((float(np.linalg.norm(r["side_force_n"])) for r in ran), default=0.0)
        text = (" **Load not told:** the feed-forward and the corrections use the tip force estimated from the "
                "loaded, uncompensated measurement's tensions and tracked pose, not the mass."
                if ran[0]["load"] == "estimated" else " The compensation is told the mass.")
        if side > 0:
            text += f" A sideways force of {side * 1e3:.0f} mN pushes the tip with every mass; it is never told."
        return text

    def plot(self, path: str | Path) -> Path:
        """Bar chart of the errors per configuration: uncompensated, feed-forward, corrected."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        path = Path(path)
        # A page wide at most (13 in at 120 dpi): past ~40 rows the bars are thinner, and the
        # configurations are named in the report's table instead of under each bar.
        labels = [f"κ{r['kappa_per_m']:g} φ{r['phi_deg']:g} {r['mass_g']:g}g" for r in self.rows]
        x = np.arange(len(self.rows))  # faulted rows are NaN: an empty slot, not a bar
        # Constrained layout with the legend outside, above the axes: inside, it lay over the bars
        # and tight_layout clipped it.
        fig, ax = plt.subplots(figsize=(min(13.0, max(6.0, 0.3 * len(x))), 4.6), layout="constrained")
        for k, (stage, label) in enumerate(_STAGES):
            ax.bar(x + 0.27 * (k - 1), [r[f"{stage}_mm"] for r in self.rows], 0.27, label=label)
        if len(x) <= 40:
            ax.set_xticks(x, labels, rotation=90, fontsize=6)
            ax.set_xlabel("configuration (curvature κ 1/m, bending plane φ deg, tip mass)")
        else:
            ax.set_xlabel("configuration (row of the per-configuration table)")
        ax.set_xlim(-0.6, len(x) - 0.4)
        ax.set_ylabel("tip error under load (mm)")
        ax.set_title("tip error under load: uncompensated, feed-forward, corrected")
        ax.grid(alpha=0.3, axis="y")
        ax.set_ylim(bottom=0.0)
        fig.legend(loc="outside upper center", ncol=len(_STAGES), fontsize=8)
        fig.savefig(path, dpi=120, bbox_inches="tight")  # the canvas grows to hold the whole legend
        plt.close(fig)
        return path

    def write_report(self, folder: str | Path, *, runtime_s: float | None = None) -> Path:
        """``report.md`` (method, summary, per-configuration table), ``compensation.png``, ``summary.json``.

        Args:
            folder: the report folder (created).
            runtime_s: wall-clock time of the run (s), stated in the report if given.
        """
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        figure = self.plot(folder / "compensation.png")
        summary = self.summary()
        (folder / "summary.json").write_text(json.dumps(
            {"summary": summary, "floor_n": self.floor_n, "limit_n": self.limit_n, "corrections": self.corrections,
             "timing_s": self.timing_s, "goal_reduction_pct": GOAL_REDUCTION_PCT, "runtime_s": runtime_s,
             "left_out": self.left_out, "met_goal": self.verdict()[0], "problems": self.verdict()[1],
             "rows": self.rows}, indent=1))
        s = summary["all"]
        per_mass = "; ".join(f"{k}: feed-forward {v['feedforward_median_reduction_pct']:.1f} %, corrected "
                             f"{v['corrected_median_reduction_pct']:.1f} %" for k, v in summary.items() if k != "all")
        ran = f" The run took {runtime_s / 60:.1f} min (wall clock)." if runtime_s is not None else ""
        short = [r for r in self.rows if not r["fault"] and r["corrected_reduction_pct"] < GOAL_REDUCTION_PCT]
        out_of_reach = [r for r in short if not r["reached"]]
        shortfall = (f" Of the {len(short)} rows short of it with the correction, {len(out_of_reach)} have the "
                     "target out of reach within the bounds: the predictor itself misses it by "
                     f"{min(r['model_residual_mm'] for r in out_of_reach):.2f}–"
                     f"{max(r['model_residual_mm'] for r in out_of_reach):.2f} mm there."
                     if out_of_reach else "")
        t = self.timing_s
        lines = ["# Load compensation over the validation grid", "",
                 f"![tip error under load per configuration: uncompensated, feed-forward, corrected]({figure.name})",
                 "",
                 f"Device `{self.device}`. Target: the tip with 0 g under the PCC "
                 "tendon-length setpoints. **Uncompensated**: those lengths held in length mode while the "
                 "mass hangs. **Feed-forward**: the board switched to tension mode and ramped to the tensions "
                 "the Cosserat predictor and its Jacobian give for the known load (bounded least squares, "
                 f"floor {self.floor_n:.2f} N, ceiling {self.limit_n:.2f} N; target = the predictor's tip at the "
                 "measured unloaded tensions). **Corrected**: then up to "
                 f"{self.corrections} closed-loop corrections, each re-aiming the predictor by the model error "
                 "the tracker's miss reveals, by the error over the share of its predicted move the last "
                 "correction made (at most twice the error). The row ends on the best command measured: one "
                 "measured better than the last — an earlier correction, the feed-forward or the PCC lengths — is "
                 "commanded again and "
                 f"measured afresh ({sum(r.get('kept') not in ('', 'last', None) for r in self.rows)} rows; "
                 f"{sum(r.get('kept') == 'PCC lengths' for r in self.rows)} back at the PCC lengths). A command "
                 "under which a tendon's cell read more than half way from the ceiling to the board's tension "
                 "limit is one the tension loop swings under: no correction follows it and it is not kept "
                 f"({sum(bool(r.get('swung')) for r in self.rows)} rows), nor is one under which the tip did "
                 f"not come to rest ({sum(bool(r.get('unsettled')) for r in self.rows)} rows). A row "
                 f"counts as worse than uncompensated when its error is larger by more than {RESOLVE_SIGMAS:g} "
                 "standard errors of the difference of the two tracker means. Ramps are smooth, "
                 f"{t['ramp_s']:g} s; the tip rests {t['rest_s']:g} s after the feed-forward ramp and "
                 f"{t['correction_rest_s']:g} s after a correction's. Errors are tracker distances to the "
                 f"target, means over {t['measure_s']:g} s with the tip at rest ({t['target_measure_s']:g} s "
                 f"for the target).{ran}{self._load_text()}", "",
                 f"**Goal (≥ {GOAL_REDUCTION_PCT:g} % reduction of the tip error under load), median over the "
                 f"{s['configurations']} rows that ran ({s['faulted']} faulted):** feed-forward alone "
                 f"{s['feedforward_median_reduction_pct']:.1f} % "
                 f"({'meets' if s['feedforward_median_reduction_pct'] >= GOAL_REDUCTION_PCT else 'misses'} it), "
                 f"with the tracker correction {s['corrected_median_reduction_pct']:.1f} % "
                 f"({'meets' if s['corrected_median_reduction_pct'] >= GOAL_REDUCTION_PCT else 'misses'} it). "
                 f"Per mass — {per_mass}. Rows at the goal: feed-forward {s['feedforward_rows_at_goal']}, "
                 f"corrected {s['corrected_rows_at_goal']} of {s['configurations']}.{shortfall}", "",
                 *([f"**Not met:** {'; '.join(self.verdict()[1])}.", ""] if not self.verdict()[0] else []),
                 *([f"Left out before running ({len(self.left_out)}): " + "; ".join(
                     f"κ {c['kappa_per_m']:g} φ {c['phi_deg']:g} ({c['reason']})" for c in self.left_out) + ".", ""]
                   if self.left_out else []),
                 "## Summary", "",
                 markdown_table([{"tip mass": k, **v} for k, v in summary.items()]), "",
                 "## Per configuration", "",
                 markdown_table([{k: v for k, v in r.items() if not k.endswith("tensions_n")} | {
                     "feedforward_tensions_n": " ".join(f"{t:.2f}" for t in r["feedforward_tensions_n"]),
                     "tensions_n": " ".join(f"{t:.2f}" for t in r["tensions_n"])} for r in self.rows])]
        path = folder / "report.md"
        path.write_text("\n".join(lines))
        return path


def tension_ceiling_n(params: Params, gains: dict, *, margin_n: float = 0.5, headroom: float = 0.95) -> float:
    """Highest tension (N) a compensation may ask of the board's tension loop.

    The loop's duty is clamped at ``gains["output_limit"]``, so the most it can hold is that
    fraction of the stall force, ``rig.motor_stall_torque_nm / rig.spool_radius_m`` (153.8 N at
    full duty): 5.38 N for the tuned clamp of 0.035 (the twin holds 5.385 N; asked for 5.5 N it
    stays there, and the three tendons left 0.12 N short put the tip 1.3–1.9 mm off at κ 26.2,
    10 g). ``headroom`` keeps some duty for the integral to reject disturbances with, and
    ``margin_n`` keeps the ceiling that far under ``rig.tension_limit_n``.

    Args:
        params: the rig's parameter set.
        gains: the tension-mode gains (``output_limit``: duty clamp, 0–1).
        margin_n: distance kept from the board's tension limit (N).
        headroom: fraction of the clamped stall force that may be asked for.
    """
    stall_n = params.rig.motor_stall_force_n
    return min(params.rig.tension_limit_n - margin_n, headroom * gains["output_limit"] * stall_n)


def swing_limit_n(params: Params, limit_n: float) -> float:
    """Highest tension (N) a tendon's cell may read for the tension loop to count as holding its
    command: the ceiling ``limit_n`` plus half its distance to ``rig.tension_limit_n``. A loop that
    swings further leaves no margin for the next swing; the 0.44 N this leaves over the tuned
    5.12 N ceiling is about twice the swing above it (0.08–0.21 N, 0.16–0.41 N peak to peak)
    the loop kept at the ceiling under μ = 0.3 on long while it held (``sim://?seed=1``)."""
    return limit_n + 0.5 * max(params.rig.tension_limit_n - limit_n, 0.0)


def compensation_grid(params: Params, limit_n: float, masses_kg: Sequence[float] = (0.005, 0.010), *,
                      quick: bool = False) -> list[tuple[float, float]]:
    """The (κ 1/m, φ deg) configurations of the trial for the robot of ``params``.

    The validation grid without κ = 0 (:func:`twin.pcc.validation_grid`: the thesis's bend
    angles at the robot's length; 60 bends, :data:`QUICK_CONFIGS` for ``quick``) when the
    ceiling can bend the robot over all of it: the PCC pulls (:func:`twin.rod.grid.pcc_tensions_n`)
    grow by EI/r per 1/m in the hardest plane, so the ceiling above the pretension bends it up
    to (ceiling − pretension) r / EI — 32 1/m for the thesis endoscope at 5.1 N (its hardest
    rows then use the ceiling under 10 g, partly out of reach). A robot it cannot bend that far
    gets the grid's curvatures scaled so that the top one leaves the heaviest mass's pull,
    m g L / r, under the ceiling. A 150 mm, 1.2 mm nitinol rod (EI 5.9e-3 N·m², r 2.5 mm) at
    25.6 N keeps its validation grid, κ up to 10.5 1/m (90° of bend); its heaviest rows are
    checked mass by mass as the endoscope's are.

    Args:
        params: the robot's parameter set.
        limit_n: the compensation's tension ceiling (N).
        masses_kg: the tip masses of the trial (kg).
        quick: the six configurations of :data:`QUICK_CONFIGS` instead of the 60.
    """
    # The validation grid's curvatures for this robot's length (thesis bend angles κ·L), the
    # quick configurations mapped onto them by their place in the thesis's grid.
    kappas = dict(zip(GRID_KAPPA_PER_M, sorted({row[1] for row in validation_grid(params)})))
    configs = ([(kappas[k], p) for k, p in QUICK_CONFIGS] if quick
               else [(kappas[k], p) for k in GRID_KAPPA_PER_M if k > 0 for p in GRID_PHI_DEG])
    pulls = [np.max(pcc_tensions_n(1.0, phi, params, pretension_n=0.0))
             for phi in GRID_PHI_DEG if pcc_realisable(phi, params)]
    top = max(kappas.values())
    if not pulls or (limit_n - params.tendons.pretension_n) / max(pulls) >= top:
        return configs
    load_n = max(masses_kg) * params.environment.gravity_m_s2 * params.backbone.length_m / params.tendons.radius_m
    scale = (limit_n - params.tendons.pretension_n - load_n) / max(pulls) / top
    # A ceiling that cannot even hold the heaviest mass leaves the grid as it is, for
    # :func:`within_reach` to refuse with the tensions it needs.
    return [(round(float(k * scale), 2), p) for k, p in configs] if scale > 0 else configs


def within_reach(params: Params, configs, *, limit_n: float) -> tuple[list[tuple[float, float]], list[dict]]:
    """The configurations whose unloaded bend the compensation's tensions can hold, and those they
    cannot, each with the reason: the layout cannot bend towards φ, or the tensions that bend the
    unloaded robot there (:func:`twin.rod.grid.pcc_tensions_n`) are above ``limit_n``, so no
    tension-mode hold of the target exists. (Under a load, :func:`run_compensation_trial` checks
    each mass's plan against the sag with the predictor.)

    Returns:
        (kept configurations, left out as ``{"kappa_per_m", "phi_deg", "reason"}``).
    """
    kept, left_out = [], []
    for kappa, phi in configs:
        reason = ""
        if not pcc_realisable(phi, params):
            reason = "the tendon layout cannot bend towards this plane"
        elif (need := float(np.max(pcc_tensions_n(kappa, phi, params)))) > limit_n:
            reason = f"needs {need:.2f} N unloaded, above the {limit_n:.2f} N ceiling"
        if reason:
            left_out.append({"kappa_per_m": float(kappa), "phi_deg": float(phi), "reason": reason})
        else:
            kept.append((float(kappa), float(phi)))
    return kept, left_out


def run_compensation_trial(device, params: Params, *, configs: Sequence[tuple[float, float]] | None = None,
                           masses_kg: Sequence[float] = (0.005, 0.010), floor_n: float = 0.3,
                           limit_n: float | None = None, corrections: int = 4, correction_tolerance_m: float = 5e-5,
                           ramp_s: float = 1.0, rest_s: float = 4.0, correction_rest_s: float = 2.5,
                           measure_s: float = 1.5, target_measure_s: float = 3.0, settle_timeout_s: float = 10.0,
                           tension_gains: dict | None = None, unknown_load: bool = False, side_force_n: float = 0.0,
                           progress=None) -> CompensationTrial:
    """Run the trial on a connected device with a fixture and a tracker, in the device's pose.

    Configurations out of reach (:func:`within_reach`) are left out before running and listed
    in the trial's ``left_out``. A configuration whose target does not come to rest, or whose
    board faults, is recorded as faulted rows, and the trial goes on with the next.

    Args:
        device: the :class:`twin.driver.Device`.
        params: parameter set of the predictor and of the PCC setpoints.
        configs: (κ 1/m, φ deg) pairs; default :func:`compensation_grid` (the thesis grid
            without κ = 0, 60 bends, scaled to what the robot's ceiling can bend).
        masses_kg: tip masses (kg), hung in this order.
        floor_n: lowest compensating tension (N). 0.3 N keeps every tendon taut (none of them
            limit-cycled between slack and taut on the grid); the old 1 N left more targets out of
            reach, e.g. 0.26 instead of 0.19 mm at κ 13, φ 150, 5 g.
        limit_n: highest compensating tension (N); default :func:`tension_ceiling_n` of the
            tension gains (5.12 N for the endoscope's).
        corrections: most closed-loop corrections per mass (0 = feed-forward only). Without
            friction one or two reach the tolerance. Under a tendon friction the model does not
            know, a full step takes ~0.6 of the miss on the endoscope (μ = 0.3: 1.42, 1.01, 0.43,
            0.30, 0.20 mm) and 0.14-0.42 on the two-segment robot, hence the re-aim over the
            share the last correction made (:func:`twin.control.compensation.response_gain`);
            four do better than two (quick grid on ``sim://?seed=0``, median
            reduction at μ = 0.3: endoscope 92.9 against 78.4 %, three-tendon 90.8 against
            79.9 %; at μ = 0.1 96.6 against 94.8 %; with the fitted friction at μ = 0.3 95.3
            against 92.6 %).
        correction_tolerance_m: no further correction once the model error the tracker shows
            (measured miss minus the predictor's own, expected miss) is within this (m): about
            the standard error of a miss's length (the norm over the axes of both means' errors:
            0.045-0.047 mm on the twin, 0.2 mm of tracker noise a frame per axis, 40 frames a
            second, 1.5 s loaded and 3 s for the target); each row reports its own.
        ramp_s: duration of each smooth tension ramp (device s).
        rest_s, correction_rest_s: wait after the feed-forward ramp and after a correction's ramp
            before the at-rest check (device s); see the module docstring for the decay.
        measure_s: averaging window of each loaded measurement (device s; 40 tracker frames a
            second, ~0.1 mm of noise per frame and axis).
        target_measure_s: averaging window of the target (device s): longer, because its error
            is in every miss of the configuration, and every correction would chase it.
        settle_timeout_s: longest wait for the at-rest check (device s), the validation sweep's
            (:func:`twin.experiments.protocols.run_validation`): a tip that comes to rest sooner
            ends the wait. 6 s left one target of stiff-long's quick grid under a hidden μ = 0.3
            not at rest (κ 10.48 φ 270 after κ 7 φ 180, both its rows faulted); with 10 s it
            rests and the grid reaches 95.9 % with none faulted (``sim://``, seed 0).
        tension_gains: ``{"kp", "ki", "kd", "output_limit"}`` of the board's tension mode;
            default :func:`twin.control.gains.tension_gains_for` the robot.
        unknown_load: plan and correct with the tip force estimated from the loaded, uncompensated
            measurement (:func:`twin.force.estimate_tip_wrench`: its tensions and tracked pose)
            instead of the known mass's weight. Which rows run is still decided beforehand from
            the masses' weight, so that both modes run the same rows.
        side_force_n: a sideways force (N) pushed at the tip with every mass, across the clamp's
            axis and gravity, that the compensation is not told about: with a known mass it is
            left uncompensated, with ``unknown_load`` the estimate sees it.
        progress: called with a one-line status after each configuration, or None.

    Raises:
        ValueError: no configuration is within reach (the message names the closest one's reason).
    """
    model = RodModel.from_params(params)
    tension_gains = tension_gains or tension_gains_for(params)
    limit_n = tension_ceiling_n(params, tension_gains) if limit_n is None else float(limit_n)
    g = params.environment.gravity_m_s2
    bounds = dict(base_rotation=device.base_rotation, floor_n=floor_n, limit_n=limit_n)
    configs, left_out = within_reach(params, list(configs or compensation_grid(params, limit_n, masses_kg)),
                                     limit_n=limit_n)
    if not configs:
        first = left_out[0]
        raise ValueError(f"no configuration is within reach of the compensation (ceiling {limit_n:.2f} N): "
                         f"e.g. κ {first['kappa_per_m']:g} 1/m φ {first['phi_deg']:g}° {first['reason']}")
    steps = max(1, round(ramp_s * params.rig.telemetry_rate_hz))
    side = side_force_n * _side_direction(device.base_rotation)
    rows: list[dict[str, Any]] = []
    # Each tendon's friction sliding state, followed from the encoders over the whole trial: a
    # model with friction predicts every static shape in the state it was reached in.
    sliding = _Sliding(device, params)
    peaks = _TensionPeaks(device)
    swing_n = swing_limit_n(params, limit_n)
    for kappa, phi in configs:
        fault = ""
        try:
            device.disable()
            device.set_gains("tensions", **tension_gains)
            zero = pretension_straight(device, params, mode="lengths")
            pcc_lengths = zero + tendon_length_changes_m(kappa, phi, params)
            device.set_lengths(pcc_lengths)
            _wait_for_tip_rest(device, settle_timeout_s)
            unloaded = measure(device, duration_s=target_measure_s)
            unloaded_sigma = sliding.direction()
        except (ProtocolError, CommandRejected) as exc:
            # The target itself could not be set: every mass of the configuration is a faulted row.
            fault = f"no target: {str(exc).split(';')[0]}"
            unloaded = None
        first_row = len(rows)
        loads = [GRAVITY_TIP_FORCE_N(mass, g) for mass in masses_kg]
        if unloaded is not None:
            # The target and every mass's sag: independent solves, one batch.
            target_m, sags = unloaded_tips(model, unloaded.tensions_n, loads, base_rotation=bounds["base_rotation"],
                                           unloaded_friction_direction=unloaded_sigma)
        for mass, load, sag in zip(masses_kg, loads, sags if unloaded is not None else [0.0] * len(loads)):
            plan = sliding.plan(model, unloaded.tensions_n, unloaded_sigma, load, bounds, target_m) \
                if unloaded is not None else None
            if plan is not None and plan.residual_m > _REACH_SHARE * sag:
                # At best the row would end above half its uncompensated error: out of reach, not run.
                left_out.append({"kappa_per_m": kappa, "phi_deg": phi, "mass_g": round(mass * 1e3, 3),
                                 "reason": f"within {floor_n:.2f}–{limit_n:.2f} N the predictor misses the target by "
                                           f"{plan.residual_m * 1e3:.2f} mm against the load's {sag * 1e3:.2f} mm sag"})
                continue
            row = {"kappa_per_m": kappa, "phi_deg": phi, "mass_g": round(mass * 1e3, 3),
                   "side_force_n": side.round(6).tolist(), "load": "estimated" if unknown_load else "known",
                   "estimated_force_n": [],
                   "uncompensated_mm": math.nan, "feedforward_mm": math.nan, "corrected_mm": math.nan,
                   "uncompensated_sem_mm": math.nan, "corrected_sem_mm": math.nan, "kept": "",
                   "feedforward_reduction_pct": math.nan, "corrected_reduction_pct": math.nan,
                   "model_residual_mm": plan.residual_m * 1e3 if plan else math.nan,
                   "reached": bool(plan and plan.reached), "corrections": 0,
                   "peak_tension_n": math.nan, "swung": False, "unsettled": False,
                   "feedforward_tensions_n": plan.tensions_n.round(4).tolist() if plan else [],
                   "tensions_n": plan.tensions_n.round(4).tolist() if plan else [], "fault": fault}
            rows.append(row)
            if fault or unloaded is None:
                continue
            replan = None
            if unknown_load:
                def replan(loaded, unloaded=unloaded, unloaded_sigma=unloaded_sigma, target_m=target_m):
                    force = _estimated_load_n(params, model, loaded, device.base_rotation, sliding.direction())
                    return sliding.plan(model, unloaded.tensions_n, unloaded_sigma, force, bounds, target_m), force
            try:
                _run_mass(device, row, model, plan, unloaded, mass, load, pcc_lengths, bounds,
                          peaks=peaks, swing_n=swing_n, side_force_n=side, replan=replan,
                          steps=steps, corrections=corrections, correction_tolerance_m=correction_tolerance_m,
                          rest_s=rest_s, correction_rest_s=correction_rest_s, measure_s=measure_s,
                          settle_timeout_s=settle_timeout_s)
            except (ProtocolError, CommandRejected) as exc:
                # A tripped tension limit is a result, not a crash: record it, skip what is left.
                row["fault"] = str(exc).split(";")[0]
                fault = f"not run: the {row['mass_g']:g} g row faulted"
                for stage, _ in _STAGES[1:]:
                    row[f"{stage}_mm"] = row[f"{stage}_reduction_pct"] = math.nan
        device.fixture.hang_tip_mass(0.0)
        device.disable()
        if progress is not None:
            last = rows[first_row:]
            progress(f"κ {kappa:g} φ {phi:g}: " + ", ".join(
                f"{r['mass_g']:g} g {r['uncompensated_mm']:.2f} → {r['feedforward_mm']:.2f} → "
                f"{r['corrected_mm']:.2f} mm" + (f" ({r['fault']})" if r["fault"] else "")
                + (f" (kept: {r['kept']})" if r.get("kept") not in ("", "last") else "")
                + (f" (the tension loop swung to {r['peak_tension_n']:.2f} N)" if r.get("swung") else "")
                + (" (a tension command left the tip moving)" if r.get("unsettled") else "")
                + (" (WORSE than uncompensated)" if not r["fault"] and _worse(r) else "") for r in last))
    timing = {"ramp_s": ramp_s, "rest_s": rest_s, "correction_rest_s": correction_rest_s, "measure_s": measure_s,
              "target_measure_s": target_measure_s}
    return CompensationTrial(rows=rows, device=device.url, floor_n=floor_n, limit_n=limit_n, corrections=corrections,
                             timing_s=timing, left_out=left_out)


def _worse(row: dict) -> bool:
    """Whether a row's compensated error is resolvably larger than its uncompensated one."""
    return resolvably_larger(row["corrected_mm"], row.get("corrected_sem_mm", math.nan), row["uncompensated_mm"],
                             row.get("uncompensated_sem_mm", math.nan))


def _sem_text(row: dict) -> str:
    """`` (standard errors a / b mm)`` of a row's two errors, where it has them."""
    sems = (row.get("corrected_sem_mm", math.nan), row.get("uncompensated_sem_mm", math.nan))
    return f" (standard errors {sems[0]:.3f} / {sems[1]:.3f} mm)" if all(map(math.isfinite, sems)) else ""


def _side_direction(base_rotation) -> np.ndarray:
    """A unit vector across the clamp's axis and gravity (world −z): the sideways direction."""
    axis = np.asarray(base_rotation, dtype=float)[:, 2]
    side = np.cross(axis, [0.0, 0.0, -1.0])
    if np.linalg.norm(side) < 0.1:  # a vertical clamp: any direction across it is sideways
        side = np.asarray(base_rotation, dtype=float)[:, 1]
    return side / np.linalg.norm(side)


def _estimated_load_n(params: Params, model: RodModel, loaded, base_rotation, sigma) -> np.ndarray:
    """The tip force (N, world) estimated from a loaded measurement's mean tensions and tracked
    pose: its observable part (nothing is compensated along a direction the pose cannot see).

    Raises:
        ProtocolError: the estimate did not converge (the row is recorded as faulted).
    """
    from twin.force.estimator import estimate_tip_wrench
    from twin.pose import quat_to_matrix

    rotation = quat_to_matrix(loaded.tip_quaternion) if np.isfinite(loaded.tip_quaternion).all() else None
    est = estimate_tip_wrench(params, loaded.tensions_n, loaded.tip_position_m, rotation, base_rotation=base_rotation,
                              model=model, friction_direction=sigma)
    if not est.converged:
        raise ProtocolError("the tip force estimate of the loaded tip did not converge")
    return est.force_observable_n


class _TensionPeaks:
    """The highest tension (N) each tendon's cell read since :meth:`reset`, from every telemetry sample."""

    def __init__(self, device):
        self.peak_n: np.ndarray | None = None
        device.add_sample_listener(self._sample)

    def _sample(self, sample) -> None:
        tensions = np.asarray(sample.tensions_n, dtype=float)
        self.peak_n = tensions if self.peak_n is None else np.fmax(self.peak_n, tensions)

    def reset(self) -> None:
        self.peak_n = None

    def highest_n(self) -> float:
        """The highest reading of any tendon since :meth:`reset` (0 before a sample)."""
        return 0.0 if self.peak_n is None else float(np.max(self.peak_n))


class _Sliding:
    """The trial's record of each tendon's friction sliding state (:class:`twin.effects.SlidingState`),
    followed from the encoders. Without friction in the model σ changes no prediction: nothing is followed."""

    def __init__(self, device, params: Params):
        self.device, self.sense = device, params.effects.tendon_friction_coeff and params.effects.tendon_friction_direction
        self.state = SlidingState(device.info.tendon_m_per_count) if self.sense else None
        self.direction()

    def direction(self):
        """σ per tendon as the encoders left it (times the model's sliding sense), or None without friction."""
        if self.state is None:
            return None
        sigma = self.state.follow(self.device.drain())
        return None if sigma is None else friction_direction(np.zeros_like(sigma), self.sense, sigma)

    def plan(self, model: RodModel, unloaded_n, unloaded_sigma, load, bounds: dict, target_m=None):
        """:func:`hold_tensions` of the unloaded tensions, its target predicted in the state
        they were measured in (``unloaded_sigma``). The loaded tensions are planned, and
        corrected, with every tendon pulled (the predictor's default): planning them in the state
        the tension ramp would leave (σ = +1 where a tension rises, −1 where it falls) took the
        endoscope's feed-forward at μ = 0.3 from 44 % to 61 % median reduction but its corrected
        median from 87.8 % to 77.9 % (the corrections' own moves flip σ again over the 20 µm of
        presliding travel), and re-aiming each correction in the state measured at the miss
        gave 79.7 %. With the target alone in the measured state: 92.8 % (one run each on
        ``sim://?seed=0``, the quick grid)."""
        return hold_tensions(model, unloaded_n, load, unloaded_friction_direction=unloaded_sigma, target_m=target_m,
                             **bounds)


def _run_mass(device, row: dict, model: RodModel, plan, target: Measurement, mass: float, load, pcc_lengths, bounds: dict, *,
              peaks: "_TensionPeaks", swing_n: float, side_force_n=None, replan=None, steps: int, corrections: int, correction_tolerance_m: float, rest_s: float,
              correction_rest_s: float, measure_s: float, settle_timeout_s: float) -> None:
    """One tip mass of a configuration, from length mode at the PCC lengths back to it; fills ``row``.

    ``side_force_n``: a hidden force (N, world) pushed at the tip with the mass; ``replan``: with
    an unknown load, ``replan(loaded measurement) -> (plan, estimated force)`` replaces the plan
    and the load of the known mass."""
    device.fixture.hang_tip_mass(mass)
    if side_force_n is not None and np.any(side_force_n):
        device.fixture.apply_tip_load(side_force_n)
    try:
        _compensate_mass(device, row, model, plan, target, load, pcc_lengths, bounds, replan=replan, steps=steps,
                         peaks=peaks, swing_n=swing_n,
                         corrections=corrections, correction_tolerance_m=correction_tolerance_m, rest_s=rest_s,
                         correction_rest_s=correction_rest_s, measure_s=measure_s, settle_timeout_s=settle_timeout_s)
    finally:
        if side_force_n is not None and np.any(side_force_n):
            device.fixture.apply_tip_load((0.0, 0.0, 0.0))


def _compensate_mass(device, row: dict, model: RodModel, plan, target: Measurement, load, pcc_lengths, bounds: dict, *, replan,
                     peaks: "_TensionPeaks", swing_n: float,
                     steps: int, corrections: int, correction_tolerance_m: float, rest_s: float,
                     correction_rest_s: float, measure_s: float, settle_timeout_s: float) -> None:
    """``target`` is the unloaded measurement, every miss is measured from its tip.

    The loop keeps the best command it measured: after the corrections, a command measured
    better than the last one — the PCC lengths themselves, where friction held the loaded tip
    closer than the tension loop can put it — is commanded again and measured afresh, and that
    fresh measurement, not the one it was picked by (the smallest of several noisy means reads
    low), is the row's result.

    A command under which some tendon's cell read more than ``swing_n`` (N, from the ramp to the
    end of its measurement, ``peaks``) is one the tension loop does not hold: under a tendon
    friction the model lacks, the loop can swing stick-slip by ±0.9 N about a setpoint at the
    ceiling, and a swing that reaches the board's limit trips it (long, μ = 0.3 hidden,
    κ 15.72 φ 270 10 g: the fourth correction's rest read 6.01 N on ``sim://?seed=0``). No
    correction follows such a command and it is not kept: the row ends on the best calm one. A
    correction's rest is left as soon as the swing shows, without measuring the command.

    A tension command under which the tip does not come to rest within ``settle_timeout_s`` is
    one the loop does not hold either, though its cells stay under ``swing_n``: the row goes on
    as after a swing, and the command, measured where the tip went on moving, is never kept (long,
    μ = 0.3 hidden and μ̂ 0.3008 in the model, κ 15.72 φ 240 and φ 270 10 g, one tendon at the
    ceiling: the tip kept moving by over 0.3 mm per 0.1 s window for 10 s and both rows faulted,
    the full grid on ``sim://?seed=0``). Only the PCC lengths, which the length loop holds, fault
    the row when they do not rest."""
    _wait_for_tip_rest(device, settle_timeout_s)
    loaded = measure(device, duration_s=measure_s)
    uncompensated = _Miss.of(loaded, target)
    row["uncompensated_mm"], row["uncompensated_sem_mm"] = uncompensated.mm, uncompensated.sem_mm
    if replan is not None:
        plan, load = replan(loaded)
        row["estimated_force_n"] = np.round(load, 5).tolist()
        row["model_residual_mm"], row["reached"] = plan.residual_m * 1e3, bool(plan.reached)
        row["feedforward_tensions_n"] = plan.tensions_n.round(4).tolist()

    device.set_mode("tensions")
    # A slack tendon reads a few mN either side of zero; the board refuses negative setpoints.
    peaks.reset()
    _ramp_tensions(device, np.maximum(loaded.tensions_n, 0.0), plan.tensions_n, steps)
    miss, settled = _settled_miss(device, target, rest_s, measure_s, settle_timeout_s)
    row["feedforward_mm"] = miss.mm
    row["feedforward_reduction_pct"] = float(100.0 * (1.0 - miss.mm / uncompensated.mm))
    calm = _note_command(row, peaks, swing_n, settled)

    applied = plan
    # Each command measured, with its miss and whether the tension loop held it calm (its cells
    # under ``swing_n`` and the tip at rest): None stands for the PCC lengths in length mode,
    # which the length loop holds.
    tried: list[tuple[_Miss, Any, bool]] = [(uncompensated, None, True), (miss, plan, calm)]
    # The share of the predictor's tip moves the device makes, from the last correction: under a
    # tendon friction the model lacks, each full step falls short (see :func:`response_gain`).
    gain = 1.0
    for _ in range(corrections):
        # What the predictor expected to miss by (a target out of reach within the bounds) is
        # no model error: a correction would not change it, so it does not count.
        if np.linalg.norm(miss.vector_m - (applied.predicted_tip_m - applied.target_m)) <= correction_tolerance_m:
            break
        if not tried[-1][2]:
            break  # the loop swings towards the board's limit, or the tip moves: no further command is tried
        corrected = _correction(model, applied, plan.target_m, miss, load, bounds, gain)
        peaks.reset()
        _ramp_tensions(device, applied.tensions_n, corrected.tensions_n, steps)
        before, applied = (miss, applied), corrected
        rested = _rest(device, correction_rest_s, swinging=lambda: peaks.highest_n() > swing_n)
        row["corrections"] += 1
        if not rested:
            _note_command(row, peaks, swing_n, True)  # swung: left within its rest, unmeasured
            break
        miss, settled = _settled_miss(device, target, 0.0, measure_s, settle_timeout_s)
        tried.append((miss, applied, _note_command(row, peaks, swing_n, settled)))
        if not settled:
            break  # a miss measured on a moving tip says nothing of the next step
        made = response_gain(applied.predicted_tip_m - before[1].predicted_tip_m, miss.vector_m - before[0].vector_m,
                             math.hypot(miss.sem_mm, before[0].sem_mm) * 1e-3)
        gain = gain if made is None else made
    while True:
        k = min((i for i in range(len(tried)) if tried[i][2]), key=lambda i: tried[i][0].mm)
        command = tried[k][1]
        row["kept"] = "last"
        if command is applied:
            break
        if command is None:
            row["kept"] = "PCC lengths"
            device.set_mode("lengths")
            device.set_lengths(pcc_lengths)
            miss = _rest_and_measure(device, target, correction_rest_s, measure_s, settle_timeout_s)
            break
        row["kept"] = "feed-forward" if k == 1 else f"correction {k - 1}"
        _ramp_tensions(device, applied.tensions_n, command.tensions_n, steps)
        applied = command
        miss, settled = _settled_miss(device, target, correction_rest_s, measure_s, settle_timeout_s)
        if settled:
            break
        # Calm once, not this time: the next best command, the PCC lengths at worst.
        row["unsettled"] = True
        tried[k] = (tried[k][0], command, False)
    # Back at the PCC lengths, the tensions are the length mode's under the load.
    row["tensions_n"] = (loaded.tensions_n if row["kept"] == "PCC lengths" else applied.tensions_n).round(4).tolist()
    row["corrected_mm"], row["corrected_sem_mm"] = miss.mm, miss.sem_mm
    row["corrected_reduction_pct"] = float(100.0 * (1.0 - miss.mm / uncompensated.mm))

    device.set_mode("lengths")
    device.set_lengths(pcc_lengths)


def _correction(model: RodModel, applied, goal_m, miss: "_Miss", load, bounds: dict, gain: float):
    """The next correction of ``applied`` (:func:`twin.control.compensation.correct_tensions`)
    for the measured ``miss``, taken over ``gain``, the share of its predicted move the last
    correction made, except where that would not help:

    - a model error (the miss beyond what ``applied`` expected) within
      :data:`twin.control.compensation.GAIN_RESOLVE_SIGMAS` standard errors of the miss: the
      step would double the noise it chases;
    - a step that asks a tendon for the ceiling: there the tension loop has no duty to spare
      against the friction, and pulling the others harder left the tip swinging past the wait
      for rest (long, μ = 0.3 hidden, κ 15.72 φ 270 10 g, ``sim://?seed=0``).
    """
    error_m = float(np.linalg.norm(miss.vector_m - (applied.predicted_tip_m - applied.target_m)))
    share = gain if error_m > GAIN_RESOLVE_SIGMAS * miss.sem_mm * 1e-3 else 1.0
    corrected = correct_tensions(model, applied, goal_m, miss.vector_m, tip_force_n=load, response_gain=share, **bounds)
    high = 0.5 * (bounds["floor_n"] + bounds["limit_n"])
    if share < 1.0 and np.any(corrected.at_bounds & (corrected.tensions_n > high)):
        corrected = correct_tensions(model, applied, goal_m, miss.vector_m, tip_force_n=load, **bounds)
    return corrected


# How many standard errors apart two measured tip errors must be for the trial to call one
# larger: 2, a difference a still tip measured twice shows by chance under 5 % of the time (the
# standard error used, the norm of the per-axis ones, bounds that of a length from above).
RESOLVE_SIGMAS = 2.0


def resolvably_larger(a_mm: float, a_sem_mm: float, b_mm: float, b_sem_mm: float) -> bool:
    """Whether tip error ``a_mm`` is larger than ``b_mm`` beyond what the tracker can measure:
    by more than :data:`RESOLVE_SIGMAS` standard errors of their difference (``*_sem_mm``, the
    errors' own, :class:`_Miss`). An unknown standard error (NaN, a single frame) counts as 0:
    every excess then counts."""
    spread = math.hypot(*(s if math.isfinite(s) else 0.0 for s in (a_sem_mm, b_sem_mm)))
    return a_mm - b_mm > RESOLVE_SIGMAS * spread


@dataclasses.dataclass(frozen=True)
class _Miss:
    """A measured tip error: loaded tip mean minus the target's mean (``vector_m``, m), its length
    (``mm``) and that length's standard error (``sem_mm``): the norm over the axes of both means'
    standard errors (:attr:`twin.experiments.protocols.Measurement.tip_sem_m`, the frames' own
    scatter over √frames) added in quadrature."""

    vector_m: np.ndarray
    mm: float
    sem_mm: float

    @classmethod
    def of(cls, loaded, target) -> "_Miss":
        vector = loaded.tip_position_m - target.tip_position_m
        sem = float(np.linalg.norm(np.hypot(loaded.tip_sem_m, target.tip_sem_m)))
        return cls(vector, float(np.linalg.norm(vector)) * 1e3, sem * 1e3)


def _ramp_tensions(device, start_n, end_n, steps: int) -> None:
    """Move the tension setpoints from ``start_n`` to ``end_n`` (N) along a smoothstep, one
    setpoint per telemetry sample: no step for the lightly damped tension-mode swing to ring on."""
    start, end = np.asarray(start_n, dtype=float), np.asarray(end_n, dtype=float)
    for k in range(1, steps + 1):
        x = k / steps
        device.set_tensions(start + (end - start) * x * x * (3.0 - 2.0 * x))
        sample = device.wait_next(timeout_s=1.0)
        if sample.fault_flags:
            raise ProtocolError(f"the board reports fault {sample.fault_flags!r} (state {sample.state!r}) "
                                "during a tension ramp")


# How often a rest asks whether the tension loop swings (s): 10 telemetry samples at 40 Hz, a
# tenth of the 2.5 s rest after a correction and half the ~0.5 s beat of the stick-slip swing's
# peaks on long at μ = 0.3 (sim://?seed=0).
_SWING_CHECK_S = 0.25


def _rest(device, rest_s: float, *, swinging: Callable[[], bool]) -> bool:
    """Wait ``rest_s``, asking ``swinging()`` every :data:`_SWING_CHECK_S`: False as soon as it
    says the tension loop swings (the command is then left without waiting out the rest), else True."""
    waited = 0.0
    while waited < rest_s:
        step = min(_SWING_CHECK_S, rest_s - waited)
        device.wait(step)
        waited += step
        if swinging():
            return False
    return True


def _note_command(row: dict, peaks: _TensionPeaks, swing_n: float, settled: bool) -> bool:
    """Add a tension command to ``row``'s ``peak_tension_n``, ``swung`` and ``unsettled`` (its cells'
    highest reading since ``peaks`` was reset, N, against ``swing_n``; whether the tip came to
    rest under it); whether the loop held it calm (neither)."""
    peak = peaks.highest_n()
    row["peak_tension_n"] = float(np.fmax(row["peak_tension_n"], peak))
    row["swung"] = row["swung"] or peak > swing_n
    row["unsettled"] = row["unsettled"] or not settled
    return settled and peak <= swing_n


def _settled_miss(device, target, rest_s: float, measure_s: float, settle_timeout_s: float) -> tuple[_Miss, bool]:
    """:func:`_rest_and_measure`, and whether the tip came to rest: where it did not within
    ``settle_timeout_s``, the miss is measured on the moving tip (False). A board fault still raises."""
    try:
        return _rest_and_measure(device, target, rest_s, measure_s, settle_timeout_s), True
    except NotAtRestError:
        return _Miss.of(measure(device, duration_s=measure_s), target), False


def _rest_and_measure(device, target, rest_s: float, measure_s: float, settle_timeout_s: float) -> _Miss:
    """Wait ``rest_s``, check the tip is at rest, and return its miss of ``target`` (the unloaded measurement)."""
    device.wait(rest_s)
    _wait_for_tip_rest(device, settle_timeout_s)
    return _Miss.of(measure(device, duration_s=measure_s), target)


def _wait_for_tip_rest(device, timeout_s: float) -> None:
    """Wait until the tracked tip is at rest (:func:`twin.experiments.protocols.wait_for_rest`
    on the tip alone). The tensions are not judged: under tendon friction the tension loop can
    keep swinging by a newton or more while the friction holds the tip still (seen on the twin at
    μ = 0.1: 2.2 N peak to peak in tension mode, the tip within the tracker's noise), and the
    tip is what the trial measures."""
    wait_for_rest(device, tension_tolerance_n=math.inf, timeout_s=timeout_s)
