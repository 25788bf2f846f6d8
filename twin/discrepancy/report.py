"""Show: the workflow's outcome as a Markdown report with figures and a JSON summary.

``report.md`` holds the workflow's verdict (:class:`twin.discrepancy.verdict.Verdict`: the tie's
candidates, or where the unexplained residual is), the verdict of the Find step and its
breakdowns (axis, plane, load, curvature), every round's ranking, the named effects with fitted
values and uncertainties, and the held-out error per configuration and in total before and
after; ``figures/`` holds

* ``before_after.png``: |e| per held-out configuration, before and after;
* ``signature.png``: e_y and e_z over the bending plane φ, before and after (thesis Figs. 19–20);
* ``ranking.png``: each round's candidate scores;
* ``residuals_*.png``: the Find step's thesis-style plots (:func:`twin.experiments.analysis.plot_validation`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from twin.discrepancy.verdict import Verdict
from twin.discrepancy.workflow import DiscrepancyResult
from twin.experiments.analysis import ValidationResult, plot_validation
from twin.experiments.report import markdown_table

__all__ = ["write_report", "plot_before_after", "plot_signature", "plot_ranking"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_before_after(result: DiscrepancyResult, path: Path) -> Path:
    """|e| (mm) of each held-out configuration before and after, sorted by the error before."""
    plt = _pyplot()
    table = sorted(result.heldout_table(), key=lambda r: -r["error_before_mm"])
    x = np.arange(len(table))
    fig, ax = plt.subplots(figsize=(min(15.0, max(6.0, 0.09 * len(table) + 3)), 3.6))
    ax.bar(x - 0.2, [r["error_before_mm"] for r in table], 0.4, label=f"before ({result.rms_before_m * 1e3:.2f} mm RMS)")
    ax.bar(x + 0.2, [r["error_after_mm"] for r in table], 0.4,
           label=f"after: {', '.join(result.named) or 'none'} ({result.rms_after_m * 1e3:.2f} mm RMS)")
    ax.axhline(result.residuals.noise.rms_3d_m * 1e3, color="k", lw=0.8, ls="--", label="noise (3-D RMS)")
    ax.set(xlabel="held-out configuration (sorted by error before)", ylabel="|p̂ − p*| (mm)",
           title="held-out tip error before and after")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_signature(result: DiscrepancyResult, path: Path) -> Path:
    """e_y and e_z (mm) over φ for the held-out rows, before and after, one colour per tip mass."""
    plt = _pyplot()
    d = result.dataset.subset(result.test)
    phi, mass = d.bends()[1], d["tip_mass_kg"]
    fig, axes = plt.subplots(2, 2, figsize=(9, 6), sharex=True, sharey="row")
    for col, (label, err) in enumerate((("before", result.errors_before_m), ("after", result.errors_after_m))):
        for row, (axis, name) in enumerate(((1, "e_y"), (2, "e_z"))):
            ax = axes[row][col]
            for m in np.unique(mass):
                sel = mass == m
                ax.scatter(phi[sel], err[sel, axis] * 1e3, s=10, label=f"{m * 1e3:g} g")
            ax.axhline(0, color="k", lw=0.6)
            ax.set(title=f"{name} {label}", ylabel=f"{name} (mm)")
            ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("bending plane φ (deg)")
    axes[0][1].legend(fontsize=7, title="tip mass", title_fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_ranking(result: DiscrepancyResult, path: Path) -> Path:
    """Each round's scores (lower is better; below 0 beats the current model before the F-test)."""
    plt = _pyplot()
    from matplotlib.patches import Patch

    # Rounds side by side, a page wide at most.
    fig, axes = plt.subplots(1, len(result.rounds), figsize=(min(4.2 * len(result.rounds), 15.0), 3.6 + 0.4),
                             squeeze=False)
    for i, (ax, rnd) in enumerate(zip(axes[0], result.rounds)):
        scores = [s for s in rnd.scores if np.isfinite(s.score)]
        colours = ["tab:green" if s.beats_noise else "tab:grey" for s in scores]
        ax.barh([s.effect for s in scores], [s.score for s in scores], color=colours)
        ax.axvline(0, color="k", lw=0.8)
        ax.invert_yaxis()
        ax.set(title=f"round {i + 1}: {rnd.winner.effect if rnd.winner else 'none'}", xlabel="score S (lower is better)",
               ylabel="candidate effect")
        ax.grid(alpha=0.3, axis="x")
    fig.legend([Patch(color="tab:green"), Patch(color="tab:grey")], ["beats noise", "does not beat noise"],
               loc="lower center", ncol=2, fontsize=8)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_report(result: DiscrepancyResult, folder: str | Path) -> Path:
    """Write ``report.md``, ``summary.json`` and ``figures/`` into ``folder``; returns the report's path."""
    folder = Path(folder)
    figures = folder / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    find = result.residuals
    paths = {"before_after": plot_before_after(result, figures / "before_after.png"),
             "signature": plot_signature(result, figures / "signature.png"),
             "ranking": plot_ranking(result, figures / "ranking.png")}
    for name, path in plot_validation(ValidationResult(find.dataset, find.predictions), figures).items():
        paths[f"residuals_{name}"] = path.rename(figures / f"residuals_{name}.png")
    summary = result.to_dict()
    (folder / "summary.json").write_text(json.dumps(summary, indent=1))
    named = ", ".join(f"`{e}`" for e in result.named) or "`none`"
    lines = [f"# Discrepancy: {result.dataset.path.name if result.dataset.path else 'dataset'}", "",
             f"**Verdict: {result.verdict}. Named effect(s): {named}.** Held-out RMS error "
             f"{result.rms_before_m * 1e3:.3g} mm before, "
             f"{result.rms_after_m * 1e3:.3g} mm after ({int(result.test.sum())} held-out rows, "
             f"{int(result.train.sum())} training rows, split seed {result.seed}).", "",
             f"![held-out tip error before and after]({paths['before_after'].relative_to(folder)})", "",
             "## Verdict", "", result.statement(), ""]
    if result.tied:
        lines += ["### Tied candidates", ""]
    if result.candidates():
        lines += ["### Candidates (none of them named)" if not result.tied else "", markdown_table([
            {"effect": c["effect"], "role": c["role"], "heldout_rms_mm": c["heldout_rms_m"] * 1e3, "score": c["score"],
             "worse_than_best_sigma": c["worse_z"],
             "fitted": "; ".join(f"{k} = {v['value']:.4g} ± {v['std_error']:.2g}" for k, v in c["parameters"].items()),
             "told_apart_by": ", ".join(c["deciding_experiments"])} for c in result.candidates()])]
    if result.separations():
        from twin.discrepancy.decide import DESIGNS, MANUAL_EXPERIMENTS

        lines += ["### What would tell them apart", "", markdown_table([
            {"between": " / ".join(s["between"]), "experiment": name,
             "what": DESIGNS[name].purpose if name in DESIGNS else MANUAL_EXPERIMENTS[name],
             "run_by_device": name in s["runnable"]} for s in result.separations() for name in s["experiments"]])]
    if result.verdict == Verdict.UNEXPLAINED:
        where = result.where()
        lines += ["### What remains (all rows, the fitted model)", "", markdown_table(where["by_axis"]),
                  markdown_table(where["by_plane"]), markdown_table(where["by_curvature"]),
                  markdown_table(where["by_load"]), "Worst configurations:", "", markdown_table(where["worst"])]
    lines += [
             "## Find", "", find.statement, "", f"Noise estimate: {find.noise.detail}.", "",
             "### By axis", "", markdown_table(find.by_axis()),
             "### By bending plane", "", markdown_table(find.by("phi_cmd_deg")),
             "### By tip load", "", markdown_table(find.by("tip_mass_kg")),
             "### By curvature", "", markdown_table(find.by("kappa_cmd_per_m")), ""]
    lines += ["## Name", "",
              "Each candidate is fitted on the training rows, jointly with the effects already named, within "
              "physical bounds and without the parameters the data leave undetermined, and scored on the "
              "held-out rows: S = N_h ln(MSE_h / MSE_h,0) + k ln(N_t) (held-out log-likelihood gain plus a BIC "
              "price per parameter; lower is better, the current model scores 0). The best score wins if it "
              "beats noise: S < 0, a training F-test against the current model at p < 0.001 / candidates, and "
              "a tenth off the held-out RMS. Candidates that also beat noise and whose held-out error is within "
              "two standard errors of the winner's tie with it. The winner is added and the rest ranked again.",
              ""]
    for i, rnd in enumerate(result.rounds):
        lines += [f"### Round {i + 1}: {rnd.winner.effect if rnd.winner else 'none'}", "",
                  f"Current model: training RMS {rnd.baseline_train_rms_m * 1e3:.3g} mm, held-out "
                  f"{rnd.baseline_heldout_rms_m * 1e3:.3g} mm.", "",
                  markdown_table([{"effect": s.effect, "k": s.parameters, "score": s.score,
                                   "train_rms_mm": s.train_rms_m * 1e3, "heldout_rms_mm": s.heldout_rms_m * 1e3,
                                   "F": s.f_statistic, "p": s.p_value, "beats_noise": s.beats_noise, "note": s.note}
                                  for s in rnd.scores])]
    lines += ["## Add", ""]
    if result.fit is not None:
        lines += ["Fitted on the training rows (standard errors from the fit's Jacobian):", "",
                  markdown_table(result.fit.table(), digits=4)]
        if result.uncertainty:
            lines += ["Honest uncertainty u = √(se² + s² + f² + b²) of each value: the standard error se, the "
                      "scatter s of the same fit over halves of the training configurations, the model-form "
                      "term f, the spread a model-form error of "
                      f"{result.uncertainty[0].model_form_level_m * 1e3:.3g} mm per configuration makes, and the "
                      "model-form shift b, what the twin's own difference from the predictor at the fitted "
                      "configurations moves the value by (twin.discrepancy.uncertainty); the 95 % interval is "
                      "value ± 1.96 u:", "",
                      markdown_table([{"parameter": u.parameter, "value": u.value, "std_error": u.std_error,
                                       "split_scatter": u.split_scatter, "model_form": u.model_form,
                                       "model_form_shift": u.model_form_shift,
                                       "uncertainty": u.total, "ci95_low": u.interval()[0],
                                       "ci95_high": u.interval()[1]} for u in result.uncertainty], digits=4)]
        lines += [
                  "Written into the parameter set with source "
                  f"`{result.params_after.source(result.fit.parameters[0].key)}`; use it with `--params FILE` "
                  "(`twin discrepancy ... --out-params FILE`).", ""]
    else:
        lines += ["Nothing beats noise: the model stays as it was.", ""]
    sig = result.signatures()
    lines += ["## Show", "", markdown_table([
        {"": "before", "heldout_rms_mm": result.rms_before_m * 1e3,
         "failed": int(np.count_nonzero(~result.converged_before)), "mean_e_z_mm": sig["before"]["mean_z_m"] * 1e3,
         "corr(e_y, -sin phi)": sig["before"]["corr_y_minus_sin_phi"],
         "e_y_sine_amplitude_mm": sig["before"]["y_sine_amplitude_m"] * 1e3},
        {"": "after", "heldout_rms_mm": result.rms_after_m * 1e3,
         "failed": int(np.count_nonzero(~result.converged_after)), "mean_e_z_mm": sig["after"]["mean_z_m"] * 1e3,
         "corr(e_y, -sin phi)": sig["after"]["corr_y_minus_sin_phi"],
         "e_y_sine_amplitude_mm": sig["after"]["y_sine_amplitude_m"] * 1e3}]), ""]
    for name, path in paths.items():
        if name != "before_after":  # it opens the report
            lines += [f"### {name.replace('_', ' ')}", "", f"![{name}]({path.relative_to(folder)})", ""]
    lines += ["### Held-out configurations", "", markdown_table(result.heldout_table()), ""]
    path = folder / "report.md"
    path.write_text("\n".join(lines))
    return path
