"""Validation analysis and report on synthetic data with a known error."""

import json

import numpy as np
import pytest

from twin import load_params
from twin.experiments.analysis import analyse_validation
from twin.experiments.report import write_validation_report
from twin.pcc import tendon_length_changes_m
from twin.rod.grid import pcc_tensions_n

from conftest import synthetic_rows

PARAMS = load_params()


def grid_cases(kappas=(0.0, 13.0, 26.2), phis=(0.0, 90.0, 180.0, 270.0), masses=(0.0, 0.01)):
    cases, config = [], 0
    for k in kappas:
        for phi in phis:
            for m in masses:
                cases.append((config, k, phi, m, pcc_tensions_n(k, phi, PARAMS), tendon_length_changes_m(k, phi, PARAMS)))
                config += 1
    return cases


def test_perfect_data_gives_zero_error(make_dataset):
    data = make_dataset(synthetic_rows(PARAMS, grid_cases()))
    s = analyse_validation(data).summary()
    assert s["failed_predictions"] == 0 and s["worst_error_mm"] < 1e-6


def test_a_heavier_endoscope_shows_as_positive_z_error(make_dataset):
    heavier = load_params(overrides={"backbone.mass_kg": 0.012})
    data = make_dataset(synthetic_rows(heavier, grid_cases()))
    result = analyse_validation(data, PARAMS)
    s = result.summary()
    # The model (6 g) predicts less sag than measured (12 g): predicted − measured z > 0.
    assert s["mean_z_mm"] > 0.3
    assert np.all(result.predictions.errors_m[:, 2] > 0)
    by_mass = result.by_group("tip_mass_kg")
    assert [g["rows"] for g in by_mass] == [12, 12]


def test_report_has_tables_and_figures(make_dataset, tmp_path):
    data = make_dataset(synthetic_rows(load_params(overrides={"backbone.mass_kg": 0.009}), grid_cases(), noise_m=1e-4))
    path = write_validation_report(analyse_validation(data, PARAMS), tmp_path, facts={"wall_time_s": 1.0})
    text = path.read_text()
    for heading in ("## Summary", "## By tip mass", "## Worst configurations", "error_magnitude.png", "front_view.png"):
        assert heading in text
    for png in ("error_magnitude", "error_x", "error_y", "error_z", "front_view"):
        assert (tmp_path / "figures" / f"{png}.png").stat().st_size > 5000
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["rows"] == 24 and summary["wall_time_s"] == 1.0
    assert summary["rms_error_mm"] == pytest.approx(analyse_validation(data, PARAMS).summary()["rms_error_mm"])


def test_a_report_on_a_twin_out_of_bounds_carries_the_warning(make_dataset, tmp_path):
    from argparse import Namespace

    from twin.experiments.commands import _twin_warnings

    def args(*twin_set):
        return Namespace(device="sim://", twin_overrides=list(twin_set))

    # The rig's straight chords between discs put the twin 2.7 mm (median) off the predictor.
    warnings = _twin_warnings(args('sim.tendon_routing="discs"'), PARAMS)
    assert len(warnings) == 1 and "out of bounds" in warnings[0]
    assert _twin_warnings(args(), PARAMS) == []
    assert _twin_warnings(Namespace(device="serial:///dev/ttyACM0", twin_overrides=[]), PARAMS) == []
    data = make_dataset(synthetic_rows(PARAMS, grid_cases()))
    path = write_validation_report(analyse_validation(data, PARAMS), tmp_path, warnings=warnings)
    assert path.read_text().splitlines()[2] == f"**{warnings[0]}**"
    assert json.loads((tmp_path / "summary.json").read_text())["warnings"] == warnings
