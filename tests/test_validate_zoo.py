"""``twin validate --robot`` on the twin for robots of three, six and two tendons: the grid is
realised for the robot's layout, and what the layout cannot realise is said, not run."""

import json

import numpy as np
import pytest

from twin.cli import main
from twin.data.dataset import read_dataset

# Two antagonistic tendons (the endoscope's 1 and 3): they bend in the plane 0°-180° only.
TWO_TENDONS = ["--set", "tendons.angles_deg=[0.0, 180.0]", "--set", "sensors.loadcell_offset_counts=[0.0, 0.0]",
               "--set", "effects.tension_gain_error=[0.0, 0.0]", "--set", "effects.tension_offset_error_n=[0.0, 0.0]"]


def _validate(out, *options):
    code = main(["validate", "--quick", "--seed", "2", "--out", str(out), *options])
    (run,) = out.iterdir()
    return code, run


@pytest.mark.parametrize("robot, tendons", [("three-tendon", 3), ("two-segment", 6), ("stiff-long", 3)])
def test_twin_validate_realises_the_grid_for_the_robots_layout(tmp_path, capsys, robot, tendons):
    code, run = _validate(tmp_path, "--robot", robot)
    err = capsys.readouterr().err
    assert code == 0, err
    d = read_dataset(run)
    assert d.robot == robot and d.tendons == tendons and d.tensions_n.shape == (24, tendons)
    assert d.metadata["left_out"] == [] and "left out" not in err
    summary = json.loads((run / "summary.json").read_text())
    assert summary["failed_predictions"] == 0 and summary["left_out"] == 0
    assert summary["median_error_mm"] < 1.0 and summary["worst_error_mm"] < 3.0
    # Bent in every plane of the quick grid: the tips of the most bent configurations spread around.
    bent = d.tip_positions_m[d["kappa_cmd_per_m"] == d["kappa_cmd_per_m"].max()]
    assert np.ptp(bent, axis=0).max() > 0.02


def test_twin_validate_names_the_configurations_a_layout_cannot_realise(tmp_path, capsys):
    code, run = _validate(tmp_path, *TWO_TENDONS)
    err = capsys.readouterr().err
    assert code == 0, err
    d = read_dataset(run)
    left_out = d.metadata["left_out"]
    # The quick grid bends in planes 0, 90, 180 and 270°: the two tendons cannot pull towards 90 and 270°.
    assert {e["phi_cmd_deg"] for e in left_out} == {90.0, 270.0} and all(e["kappa_cmd_per_m"] > 0 for e in left_out)
    assert len(d) + len(left_out) == 24 and not set(d["config"]) & {e["config"] for e in left_out}
    assert f"{len(left_out)} of the grid's 24 configurations left out" in err
    assert "## Configurations left out" in (run / "report.md").read_text()


def test_the_grid_scales_with_the_robot_and_the_endoscopes_is_the_thesis_grid():
    from twin.pcc import GRID_KAPPA_PER_M, THESIS_LENGTH_M, quick_grid, validation_grid
    from twin.robots import load_robot

    thesis = validation_grid()
    assert validation_grid(load_robot("endoscope")) == thesis
    assert sorted({row[1] for row in thesis}) == list(GRID_KAPPA_PER_M)
    # The quick look at the thesis grid: κ 0/13/26.2 1/m, the four planes, 0 and 10 g.
    assert quick_grid(thesis) == [g for g in thesis if g[1] in (0.0, 13.0, 26.2) and g[2] in (0.0, 90.0, 180.0, 270.0)
                                  and g[3] != 0.005]
    # A 150 mm robot bends by the thesis's angles: 90° at most.
    stiff = load_robot("stiff-long")
    grid = validation_grid(stiff)
    assert [row[0] for row in grid] == [row[0] for row in thesis] and len(grid) == 216
    bends = sorted({row[1] * stiff.backbone.length_m for row in grid})
    np.testing.assert_allclose(bends, np.array(GRID_KAPPA_PER_M) * THESIS_LENGTH_M, rtol=1e-6)


def test_configurations_the_tension_limit_cannot_hold_are_left_out_with_the_reason():
    from twin.experiments.protocols import unrealisable
    from twin.pcc import validation_grid
    from twin.robots import load_robot, robot_names

    # Every robot of the zoo holds its own grid, the endoscope the thesis's whole.
    for name in robot_names():
        params = load_robot(name)
        assert unrealisable(validation_grid(params), params) == [], name
    # The thesis's curvatures on the stiff 150 mm robot need up to ~50 N: over its 30 N limit.
    stiff = load_robot("stiff-long")
    left_out = unrealisable(validation_grid(), stiff)
    assert {e["kappa_cmd_per_m"] for e in left_out} >= {26.2} and 0.0 not in {e["kappa_cmd_per_m"] for e in left_out}
    assert all("over 0.9 of the 30 N tension limit" in e["reason"] for e in left_out)
    # A lower limit holds less.
    weaker = unrealisable(validation_grid(), stiff.replace({"rig.tension_limit_n": 15.0}))
    assert len(weaker) > len(left_out)


def test_validate_runs_the_grid_given_as_a_spec_or_a_file(tmp_path, capsys):
    grid = tmp_path / "grid.csv"
    grid.write_text("bend_deg,phi_deg,tip_mass_kg\n0,0,0\n45,90,0.005\n")
    code, run = _validate(tmp_path / "file", "--robot", "stiff-long", "--grid", str(grid))
    assert code == 0, capsys.readouterr().err
    d = read_dataset(run)
    # --quick keeps the file's two configurations (their smallest and largest curvature, ...).
    assert list(d["config"]) == [0, 1]
    np.testing.assert_allclose(d["kappa_cmd_per_m"], [0.0, np.radians(45.0) / 0.15])
    code, run = _validate(tmp_path / "spec", "--grid", "kappa_per_m=0,20;phi_deg=0,180;tip_mass_kg=0")
    assert code == 0
    assert sorted(set(read_dataset(run)["kappa_cmd_per_m"])) == [0.0, 20.0] and len(read_dataset(run)) == 4


@pytest.mark.parametrize("grid, message", [
    ("kappa=0,1", "--grid kappa=0,1: unknown axis 'kappa'; the axes are kappa_per_m, bend_deg, phi_deg, tip_mass_kg"),
    ("kappa_per_m=0,x", "--grid kappa_per_m=0,x: kappa_per_m value 'x' is not a number"),
    ("tip_mass_kg=-1", "--grid tip_mass_kg=-1: tip_mass_kg = -1.0: must be finite and >= 0"),
    ("nonsense", "--grid nonsense: neither a file nor a SPEC"),
    ("kappa_per_m=1;bend_deg=3", "not both"),
])
def test_a_bad_grid_is_refused_in_one_line_before_a_run_folder_exists(tmp_path, capsys, grid, message):
    code = main(["validate", "--quick", "--out", str(tmp_path), "--grid", grid])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not any(tmp_path.iterdir())


def test_a_configuration_that_trips_the_limit_is_left_out_and_a_resume_does_not_run_it_again(tmp_path, capsys):
    # The twin's rod is stiffer than the model's (hidden): holding the bend tips the 30 N limit.
    options = ["--robot", "stiff-long", "--twin-set", "backbone.youngs_modulus_pa=1e11",
               "--grid", "bend_deg=0,90;phi_deg=180;tip_mass_kg=0,0.01"]
    code, run = _validate(tmp_path, *options)
    err = capsys.readouterr().err
    assert code == 0, err
    left_out = read_dataset(run).metadata["left_out"]
    assert [e["config"] for e in left_out] == [2, 3] and "tripped the tension limit when run" in left_out[0]["reason"]
    assert "configuration 2 (κ 10.472 1/m, φ 180°, 0 g) tripped the tension limit" in err
    assert sorted(read_dataset(run)["config"]) == [0, 1]
    assert "tripped the tension limit when run" in (run / "report.md").read_text()
    # Resumed, it is left out before running, not tripped again.
    code = main(["validate", "--quick", "--seed", "2", "--resume", str(run), *options])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "2 of the grid's 4 configurations left out" in err and "going on" not in err


def test_a_grid_the_limit_cannot_hold_at_all_is_said_and_exits_non_zero(tmp_path, capsys):
    code = main(["validate", "--robot", "stiff-long", "--grid", "kappa_per_m=26.2;phi_deg=0;tip_mass_kg=0",
                 "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 4
    assert "1 of the grid's 1 configurations left out" in err and "no configuration was measured" in err
