"""Every figure the commands write reads at a glance: page-sized, axes labelled with units, a
legend wherever several series share axes, a scale where sizes or pictures encode lengths.

Each plot function runs as its command runs it; the Figures are inspected as they are saved.
"""

from __future__ import annotations

import argparse
import json
import struct
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from twin import load_params
from twin.experiments.analysis import analyse_validation, plot_validation
from twin.pcc import tendon_length_changes_m
from twin.rod.grid import pcc_tensions_n

from conftest import synthetic_rows

PARAMS = load_params()
REPO = Path(__file__).resolve().parents[1]
# A report page: wider than this at the dpi a figure is saved with, it is shrunk past reading.
MAX_WIDTH_PX = 1600


@pytest.fixture
def saved(monkeypatch):
    """(figure, path) of every Figure saved while the test runs."""
    figures: list[tuple[Figure, Path]] = []
    original = Figure.savefig

    def record(self, fname, *args, **kwargs):
        figures.append((self, Path(fname)))
        return original(self, fname, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", record)
    return figures


def _png_size(path: Path) -> tuple[int, int]:
    """(width, height) px from a PNG's header."""
    with open(path, "rb") as f:
        header = f.read(24)
    assert header[:8] == b"\x89PNG\r\n\x1a\n", path
    return struct.unpack(">II", header[16:24])


def _data_artists(ax) -> int:
    return len(ax.lines) + len(ax.collections) + len(ax.containers)


def _labelled(ax, which: str) -> bool:
    """The axis has a label, or one of the axes it shares that axis with has."""
    siblings = (ax.get_shared_x_axes() if which == "x" else ax.get_shared_y_axes()).get_siblings(ax)
    return any((a.get_xlabel() if which == "x" else a.get_ylabel()).strip() for a in siblings)


def check_readable(fig: Figure, path: Path) -> None:
    """The house rules of a figure, as asserts naming the file."""
    width, height = _png_size(path)
    assert width <= MAX_WIDTH_PX and height <= MAX_WIDTH_PX, f"{path.name}: {width} x {height} px"
    plots = [ax for ax in fig.axes if ax.axison and _data_artists(ax)]
    assert plots, f"{path.name}: no plotted data"
    for ax in plots:
        if ax.get_label() == "<colorbar>":  # one axis: its label is the colour's quantity
            label = ax.get_ylabel() or ax.get_xlabel()
            assert "(" in label and ")" in label, f"{path.name}: colour bar {label!r} without a unit"
            continue
        assert _labelled(ax, "x") and _labelled(ax, "y"), f"{path.name}: an axes without its labels ({ax.get_title()})"
        for label in (ax.get_xlabel(), ax.get_ylabel()):
            # A quantity says its unit; a category (a configuration, an effect) has none.
            if label and not any(w in label for w in ("configuration", "effect", "score")):
                assert "(" in label and ")" in label, f"{path.name}: {label!r} has no unit"
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None] + list(fig.legends)
    if any(_data_artists(ax) > 1 for ax in plots):
        assert legends, f"{path.name}: several series and no legend"
    for legend in legends:
        assert all(t.get_text().strip() for t in legend.get_texts()), f"{path.name}: an empty legend entry"


def _grid_cases():
    cases, config = [], 0
    for kappa in (0.0, 13.0, 26.2):
        for phi in (0.0, 90.0, 180.0, 270.0):
            for mass in (0.0, 0.005, 0.01):
                cases.append((config, kappa, phi, mass, pcc_tensions_n(kappa, phi, PARAMS),
                              tendon_length_changes_m(kappa, phi, PARAMS)))
                config += 1
    return cases


def test_validation_figures_are_readable_and_the_front_view_has_its_scale(make_dataset, tmp_path, saved):
    data = make_dataset(synthetic_rows(load_params(overrides={"backbone.mass_kg": 0.009}), _grid_cases(),
                                       noise_m=1e-4))
    result = analyse_validation(data, PARAMS)
    paths = plot_validation(result, tmp_path)
    assert list(paths)[0] == "error_magnitude"  # the figure a report opens with
    assert {p for _, p in saved} == set(paths.values())
    for fig, path in saved:
        check_readable(fig, path)
    # Every signed error states its sign on its axis: predicted minus measured (e = p̂ − p*).
    for axis in "xyz":
        (fig,) = [fig for fig, path in saved if path == paths[f"error_{axis}"]]
        assert f"e_{axis} = {axis}̂ − {axis}*" in fig.axes[0].get_ylabel()
        assert "predicted − measured" in fig.axes[0].get_ylabel()
    front = next(fig for fig, path in saved if path == paths["front_view"])
    # The error circles: a reference circle of a stated error in every panel, and the magnification said.
    texts = [t.get_text() for ax in front.axes for t in ax.texts]
    assert sum("mm error" in t for t in texts) == 3, texts
    legend = " ".join(t.get_text() for t in front.legends[0].get_texts())
    gain = float(legend.split("×")[1].split(")")[0])
    worst_mm = np.nanmax(result.error_mm)
    radii = [p.get_radius() for ax in front.axes for p in ax.patches]
    assert max(radii) == pytest.approx(gain * worst_mm, rel=5e-3)  # the stated magnification is the drawn one


def test_the_demo_plot_is_readable_with_a_legend_of_each_shape(tmp_path, saved):
    from twin.demo import run_demo

    args = argparse.Namespace(out=str(tmp_path), params=None, robot=None, overrides=[])
    assert run_demo(args) == 0
    ((fig, path),) = saved
    check_readable(fig, path)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert sum(label.startswith("κ") for label in labels) == 9 and "tip mass 10 g" in labels


def test_the_compensation_figure_fits_a_page_for_the_whole_grid(tmp_path, saved):
    from twin.control.compensation_trial import CompensationTrial

    stored = json.loads((REPO / "reports" / "compensation" / "summary.json").read_text())
    trial = CompensationTrial(rows=stored["rows"], device="sim://", floor_n=stored["floor_n"],
                              limit_n=stored["limit_n"], corrections=stored["corrections"],
                              timing_s=stored["timing_s"])
    assert len(trial.rows) > 100
    report = trial.write_report(tmp_path, runtime_s=stored["runtime_s"])
    ((fig, path),) = saved
    check_readable(fig, path)
    # The legend above the axes, not over the bars (before: over them, and clipped at the sides).
    fig.draw_without_rendering()
    legend, axes = fig.legends[0].get_window_extent(), fig.axes[0].get_window_extent()
    assert legend.y0 >= axes.y1 - 1
    # The report opens with it: the first thing after the title.
    first = [line for line in report.read_text().splitlines()[1:] if line.strip()][0]
    assert first.startswith("![") and path.name in first
    # A few rows keep their names under the bars.
    saved.clear()
    small = CompensationTrial(rows=trial.rows[:12], device="sim://", floor_n=trial.floor_n, limit_n=trial.limit_n,
                              corrections=trial.corrections, timing_s=trial.timing_s)
    small.plot(tmp_path / "small.png")
    ((fig, path),) = saved
    check_readable(fig, path)
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()][0].startswith("κ")


def test_the_stiffness_surface_is_readable(tmp_path, saved):
    from types import SimpleNamespace

    from twin.experiments.stiffness import StiffnessResult, plot_error_surface

    e_grid, g_grid = np.geomspace(4e6, 2e7, 6), np.geomspace(1e6, 8e6, 5)
    e, g = np.meshgrid(e_grid, g_grid)
    result = StiffnessResult(fit=SimpleNamespace(values=np.array([8e6, 3e6])), youngs_grid_pa=e_grid,
                             shear_grid_pa=g_grid, summed_error_m=np.log(e / 8e6) ** 2 + np.log(g / 3e6) ** 2 + 0.01)
    plot_error_surface(result, tmp_path / "error_surface.png")
    ((fig, path),) = saved
    check_readable(fig, path)


def test_the_report_picture_has_a_scale_bar_and_axes(tmp_path, saved):
    from twin.sim import Plant
    from twin.sim.render import RenderError, render_png

    plant = Plant(load_params(overrides=["sim.elements=10"]))
    plant.set_tensions([2.5, 1.35, 1.35, 1.35])
    plant.settle()
    try:
        path = render_png(plant, tmp_path / "bent.png", labelled=True, title="bent", width=320, height=240)
    except RenderError as exc:
        pytest.skip(f"no headless OpenGL here: {exc}")
    ((fig, _),) = saved
    width, height = _png_size(path)
    assert width == 320 and height > 240  # the picture at its size, a title above
    (ax,) = fig.axes
    bars = [a for a in ax.artists if "SizeBar" in type(a).__name__]
    assert len(bars) == 1
    texts = [t.get_text() for t in ax.texts]
    assert any(t.endswith(("x", "y", "z")) and t[0] in "+-" for t in texts), texts


def test_discrepancy_figures_are_readable_and_the_report_opens_with_before_and_after(tmp_path, saved):
    from twin.discrepancy import run_discrepancy, synthetic_validation_dataset, write_report
    from twin.pcc import validation_grid

    grid = [g for g in validation_grid() if g[1] in (0.0, 13.0, 26.2) and g[2] % 60 == 0 and g[3] in (0.0, 0.01)]
    truth = PARAMS.replace({"effects.tracker_offset_m": [0.0, 0.0, 0.002]})
    result = run_discrepancy(synthetic_validation_dataset(tmp_path / "data", PARAMS, truth, grid=grid, seed=7))
    report = write_report(result, tmp_path / "report")
    names = {path.name for _, path in saved}
    assert {"before_after.png", "signature.png", "ranking.png", "front_view.png"} <= names
    for fig, path in saved:
        # The Find step's validation figures are renamed residuals_* once saved.
        check_readable(fig, path if path.exists() else path.with_name(f"residuals_{path.name}"))
    lines = [line for line in report.read_text().splitlines() if line.strip()]
    assert lines[2].startswith("![") and "before_after.png" in lines[2]  # after the title and the verdict line


def test_the_crosscheck_report_opens_with_its_figure(tmp_path, saved):
    from twin.sim.crosscheck import CrosscheckResult, write_report

    rows = [(i, kappa, phi, mass) for i, (kappa, phi, mass) in enumerate(
        (k, p, m) for k in (0.0, 13.0, 26.2) for p in (0.0, 90.0, 180.0, 270.0) for m in (0.0, 0.01))]
    rng = np.random.default_rng(0)
    twin_tip = rng.normal(0.0, 0.03, (len(rows), 3))
    result = CrosscheckResult(rows=rows, twin_tip_m=twin_tip, rod_tip_m=twin_tip + rng.normal(0.0, 1e-4, twin_tip.shape),
                              settled=np.ones(len(rows), bool), rod_converged=np.ones(len(rows), bool),
                              length_m=PARAMS.backbone.length_m, elements=10, wall_s=1.0)
    report = write_report(result, [], tmp_path, PARAMS)
    ((fig, path),) = saved
    check_readable(fig, path)
    lines = [line for line in report.read_text().splitlines() if line.strip()]
    assert lines[2].startswith("**Goal met") and lines[3] == f"![twin vs predictor tip difference per configuration]({path.name})"


def test_the_crosscheck_figure_of_one_configuration_has_readable_axes_and_an_unsigned_label(tmp_path, saved):
    from twin.sim.crosscheck import CrosscheckResult, plot_crosscheck

    result = CrosscheckResult(rows=[(0, 10.0, 90.0, 0.0)], twin_tip_m=np.array([[0.001, 0.0, 0.1]]),
                              rod_tip_m=np.array([[0.0, 0.0, 0.1]]), settled=np.array([True]),
                              rod_converged=np.array([True]), length_m=0.1, elements=20, wall_s=1.0)
    plot_crosscheck(result, tmp_path / "crosscheck.png")
    ((fig, path),) = saved
    check_readable(fig, path)
    (ax,) = fig.axes
    low, high = ax.get_xlim()
    assert low <= 80.0 and high >= 100.0  # not matplotlib's ±0.05° around one point
    assert ax.get_ylim()[0] == 0.0 and ax.get_ylim()[1] >= 1.0  # the 1 % distance is on the plot, from zero
    assert "distance" in ax.get_ylabel() and "twin − predictor tip" not in ax.get_ylabel()
