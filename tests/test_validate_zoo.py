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


@pytest.mark.parametrize("robot, tendons", [("three-tendon", 3), ("two-segment", 6)])
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
    bent = d.tip_positions_m[d["kappa_cmd_per_m"] == 26.2]
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
