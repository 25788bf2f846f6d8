"""``twin discrepancy`` command-line contract: JSON keys, parameter file, report, bad paths."""

import json

import pytest

from twin import load_params
from twin.cli import main
from twin.discrepancy import synthetic_validation_dataset
from twin.effects import EFFECTS
from twin.pcc import validation_grid

NOMINAL = load_params()


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_json_names_the_hidden_tip_load_and_writes_params_and_report(tmp_path, capsys):
    grid = [g for g in validation_grid() if g[1] in (0.0, 13.0, 26.2) and g[2] % 60 == 0 and g[3] in (0.0, 0.01)]
    truth = NOMINAL.replace({"effects.tip_load_error_fraction": -0.12})
    synthetic_validation_dataset(tmp_path / "data", NOMINAL, truth, grid=grid, seed=11)
    code, out, err = run(capsys, "discrepancy", tmp_path / "data", "--json", "--out-params", tmp_path / "fitted.toml",
                         "--report", tmp_path / "report", "--max-effects", "1")
    assert code == 0, err
    data = json.loads(out)
    assert data["effect"] == "tip_load"
    value = data["parameters"]["effects.tip_load_error_fraction"]
    assert value["value"] == pytest.approx(-0.12, abs=0.02) and 0 < value["std_error"] < 0.02
    assert data["rms_after_m"] < 0.5 * data["rms_before_m"]
    assert {r["effect"] for r in data["ranking"]} <= set(EFFECTS) and len(data["ranking"]) == 8
    assert all("score" in r for r in data["ranking"])
    fitted = load_params(tmp_path / "fitted.toml")
    assert fitted.effects.tip_load_error_fraction == pytest.approx(value["value"])
    assert fitted.source("effects.tip_load_error_fraction").startswith("fitted: discrepancy data")
    assert (tmp_path / "report" / "report.md").exists()


def test_a_bad_dataset_path_is_named(tmp_path, capsys):
    code, out, err = run(capsys, "discrepancy", tmp_path / "nowhere")
    assert code == 2 and out == ""
    assert "nowhere" in err and "missing" in err


def test_bad_options_are_refused_by_name(tmp_path, capsys):
    synthetic_validation_dataset(tmp_path / "data", NOMINAL, NOMINAL, grid=validation_grid()[:6], seed=0)
    code, out, err = run(capsys, "discrepancy", tmp_path / "data", "--max-effects", "0")
    assert code == 2 and "max_effects = 0" in err
    code, out, err = run(capsys, "discrepancy", tmp_path / "data", "--holdout", "1.5")
    assert code == 2 and "holdout_fraction = 1.5" in err
