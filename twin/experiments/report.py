"""Markdown reports for runs: tables and figures a lab would rather look at than read."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping, Sequence

from twin.experiments.analysis import ValidationResult, plot_validation
from twin.pose import pose_name

__all__ = ["markdown_table", "write_validation_report"]


def markdown_table(rows: Sequence[Mapping], columns: Sequence[str] | None = None, *, digits: int = 3) -> str:
    """A Markdown table of dict rows (floats rounded to ``digits`` significant figures)."""
    if not rows:
        return "_(no rows)_\n"
    columns = list(columns or rows[0].keys())

    def fmt(v):
        if isinstance(v, float):
            return f"{v:.{digits}g}"
        return str(v)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c, "")) for c in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def write_validation_report(result: ValidationResult, folder: str | Path, *, title: str = "Validation sweep",
                            picture: Path | None = None, facts: Mapping[str, object] | None = None,
                            warnings: Sequence[str] = ()) -> Path:
    """Write ``report.md``, ``summary.json``, ``errors.csv``-like table and the figures into ``folder``;
    ``warnings`` (e.g. a twin whose cross-check is out of bounds) open the report."""
    folder = Path(folder)
    figures = plot_validation(result, folder / "figures")
    summary = result.summary()
    summary.update(facts or {})
    summary["warnings"] = list(warnings)
    meta = result.dataset.metadata
    # The grid's configurations the robot cannot realise (recorded by the run, not measured).
    left_out = list(meta.get("left_out", []))
    summary["left_out"] = len(left_out)
    (folder / "summary.json").write_text(json.dumps(summary, indent=1))
    lines = [f"# {title}", ""]
    lines += [f"**{w}**" for w in warnings] + ([""] if warnings else [])
    # The figure that answers the question (how far off is the prediction) opens the report.
    answer = figures["error_magnitude"]
    lines += [f"![prediction error per configuration]({answer.relative_to(folder)})", "",
              f"**Prediction error |p̂ − p*|: median {summary['median_error_mm']:.3g} mm, RMS "
              f"{summary['rms_error_mm']:.3g} mm, worst {summary['worst_error_mm']:.3g} mm** over "
              f"{summary['rows']} configurations ({summary['failed_predictions']} failed predictions).", ""]
    robot = (meta.get("robot") or {}).get("name")
    lines += [f"Device `{meta.get('device')}`, {summary['rows']} static measurements, experiment "
              f"`{meta.get('experiment')}`, recorded {meta.get('created')}"
              + (f", robot `{robot}` ({result.dataset.tendons} tendons)" if robot else "")
              + f", base clamped {pose_name(result.dataset.base_rotation)}.", ""]
    if left_out:
        lines += [f"**{len(left_out)} configurations of the grid left out**: the robot cannot realise or hold them "
                  "(listed with the reason under *Configurations left out*).", ""]
    if picture is not None and Path(picture).exists():
        lines += [f"![the endoscope]({Path(picture).relative_to(folder)})", ""]
    lines += ["## Summary", "", markdown_table([{k: v for k, v in summary.items()}]), ""]
    lines += ["Errors are |p̂ − p*| between the Cosserat prediction (from the measured tensions and the "
              "known loads) and the measured tip, base frame. The signed errors e_x, e_y, e_z are predicted "
              "minus measured (e = p̂ − p*): a positive e_z means the prediction lies above the measured tip. "
              "Failed predictions are counted, never plotted as answers.", ""]
    lines += ["## By tip mass", "", markdown_table(result.by_group("tip_mass_kg")), ""]
    lines += ["## By curvature", "", markdown_table(result.by_group("kappa_cmd_per_m")), ""]
    lines += ["## By bending plane", "", markdown_table(result.by_group("phi_cmd_deg")), ""]
    lines += ["## Figures", ""]
    for name, path in figures.items():
        if name != "error_magnitude":
            lines += [f"### {name.replace('_', ' ')}", "", f"![{name}]({path.relative_to(folder)})", ""]
    worst = sorted(result.rows_table(), key=lambda r: -r["error_mm"] if r["converged"] else float("-inf"))[:15]
    lines += ["## Worst configurations", "", markdown_table(worst), ""]
    lines += ["## All configurations", "", markdown_table(result.rows_table()), ""]
    if left_out:
        lines += ["## Configurations left out", "", "The grid's configurations the robot cannot realise (its tendon "
                  "layout) or hold (its tension limit), or that tripped the limit when run: not run, so neither "
                  "measured nor predicted.", "", markdown_table(left_out), ""]
    path = folder / "report.md"
    path.write_text("\n".join(lines))
    return path
