"""``twin discrepancy`` command-line contract: JSON keys, verdicts and exit codes, parameter file,
report, bad paths and bad datasets (one line each)."""

import json
import shutil

import numpy as np

import pytest

from twin import load_params
from twin.cli import main
from twin.discrepancy import candidate_library, synthetic_validation_dataset
from twin.discrepancy.commands import EXIT_CODES
from twin.discrepancy.verdict import Verdict
from twin.pcc import validation_grid

NOMINAL = load_params()
GRID = [g for g in validation_grid() if g[1] in (0.0, 13.0, 26.2) and g[2] % 60 == 0 and g[3] in (0.0, 0.01)]


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
    assert data["verdict"] == "effect" and data["candidates"] == []
    assert data["remaining_rms_m"] == data["rms_after_m"] < 1.3 * data["noise_rms_m"]
    value = data["parameters"]["effects.tip_load_error_fraction"]
    assert value["value"] == pytest.approx(-0.12, abs=0.02) and 0 < value["std_error"] < 0.02
    # The honest interval holds the statistical one and every term it is built of.
    u = value["uncertainty"]
    assert u == pytest.approx(np.sqrt(value["std_error"]**2 + value["split_scatter"]**2 + value["model_form"]**2
                                      + value["model_form_shift"]**2))
    assert value["ci95"] == pytest.approx([value["value"] - 1.96 * u, value["value"] + 1.96 * u])
    assert value["ci95"][0] < value["ci95_statistical"][0] < value["ci95_statistical"][1] < value["ci95"][1]
    assert value["ci95"][0] < -0.12 < value["ci95"][1] and value["model_form"] > 0
    assert data["rms_after_m"] < 0.5 * data["rms_before_m"]
    assert sorted(r["effect"] for r in data["ranking"]) == sorted(candidate_library(NOMINAL))
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


def test_an_unexplained_verdict_exits_3_and_says_where(tmp_path, capsys):
    truth = NOMINAL.replace({"tendons.angles_deg": [0.0, 90.0, 195.0, 270.0]})
    synthetic_validation_dataset(tmp_path / "data", NOMINAL, truth, grid=GRID, seed=5)
    code, out, err = run(capsys, "discrepancy", tmp_path / "data", "--json")
    assert code == 3, err
    data = json.loads(out)
    assert data["verdict"] == "unexplained" and data["remaining_rms_m"] > 3 * data["noise_rms_m"]
    assert data["remaining"]["beyond_noise"] and len(data["remaining"]["worst"]) == 5
    code, out, err = run(capsys, "discrepancy", tmp_path / "data")
    assert code == 3 and "verdict: unexplained" in out


def test_clean_data_exits_0_with_verdict_none(tmp_path, capsys):
    synthetic_validation_dataset(tmp_path / "data", NOMINAL, NOMINAL, grid=GRID, seed=4)
    code, out, err = run(capsys, "discrepancy", tmp_path / "data", "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["verdict"] == "none" and data["effects"] == [] and data["parameters"] == {}


def test_help_documents_the_exit_codes(capsys):
    with pytest.raises(SystemExit):
        main(["discrepancy", "--help"])
    text = capsys.readouterr().out
    for verdict in Verdict:
        assert any(line.split()[:2] == [verdict, str(EXIT_CODES[verdict])] for line in text.splitlines()), verdict


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    folder = tmp_path_factory.mktemp("clean") / "data"
    synthetic_validation_dataset(folder, NOMINAL, NOMINAL, grid=GRID, seed=3)
    return folder


def _edit_metadata(folder, change):
    meta = json.loads((folder / "metadata.json").read_text())
    (folder / "metadata.json").write_text(json.dumps(change(meta)))


def _edit_csv(folder, change):
    path = folder / "measurements.csv"
    lines = path.read_text().splitlines()
    path.write_text("\r\n".join(change(lines)) + "\r\n")


def _tension_1(lines, value):
    header = lines[0].split(",")
    cells = lines[1].split(",")
    cells[header.index("tension_1_n")] = value
    return [lines[0], ",".join(cells)] + lines[2:]


@pytest.mark.parametrize("damage, words", [
    (lambda f: _edit_metadata(f, lambda m: [m]), ["metadata.json", "list"]),
    (lambda f: _edit_metadata(f, lambda m: {**m, "base_rotation": "horizontal"}), ["metadata.json", "base_rotation"]),
    (lambda f: _edit_metadata(f, lambda m: {**m, "params": "endoscope.toml"}), ["metadata.json", "params"]),
    (lambda f: _edit_csv(f, lambda lines: lines[:4]), ["3 row(s)", "too few"]),
    (lambda f: _edit_csv(f, lambda lines: _tension_1(lines, "-5.0")), ["measurements.csv", "row 2", "tension_1_n",
                                                                      "-5.0"]),
    (lambda f: _edit_csv(f, lambda lines: [lines[0] + ",tip_x_m"] + [line + ",0.0" for line in lines[1:]]),
     ["measurements.csv", "row 1", "tip_x_m", "twice"]),
])
def test_a_bad_dataset_is_one_line_naming_file_row_and_column(clean, tmp_path, capsys, damage, words):
    folder = tmp_path / "data"
    shutil.copytree(clean, folder)
    damage(folder)
    code, out, err = run(capsys, "discrepancy", folder)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in err, (word, err)


def test_a_missing_parameter_file_is_one_line(clean, tmp_path, capsys):
    code, out, err = run(capsys, "discrepancy", clean, "--params", tmp_path / "nowhere.toml")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert "nowhere.toml" in err and "no such file" in err


def test_a_parameter_file_of_another_tendon_count_is_refused_naming_it(tmp_path, capsys):
    from twin.robots import robot_path

    data = synthetic_validation_dataset(tmp_path / "data", load_params(), load_params(),
                                        grid=[g for g in validation_grid()][:12])
    code, out, err = run(capsys, "discrepancy", data.path, "--params", robot_path("three-tendon"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "has 4 tendons; robot 'three-tendon' has 3" in err
