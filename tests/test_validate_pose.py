"""``twin validate --quick --pose``: the upright twin validates at the error level of the
horizontal one, and its dataset records the pose it ran in.

tests/test_pose.py checks the same through the protocol's API and device URLs; this is the
command a lab runs.
"""

import json

import numpy as np
import pytest

from twin.cli import main
from twin.data.dataset import read_dataset
from twin.pose import HORIZONTAL, UP


def _validate(out, *options):
    code = main(["validate", "--quick", "--seed", "2", "--out", str(out), *options])
    assert code == 0
    (run,) = out.iterdir()
    return run, json.loads((run / "summary.json").read_text()), read_dataset(run)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    return {pose: _validate(tmp_path_factory.mktemp(pose), "--pose", pose) for pose in ("up", "horizontal")}


def test_the_upright_twin_validates_at_the_error_level_of_the_horizontal_one(runs):
    (_, up, up_data), (_, flat, flat_data) = runs["up"], runs["horizontal"]
    assert np.allclose(up_data.base_rotation, UP) and np.allclose(flat_data.base_rotation, HORIZONTAL)
    # The same tips in both would mean the pose never reached the twin.
    assert np.max(np.abs(up_data.tip_positions_m - flat_data.tip_positions_m)) > 0.01
    assert up["rows"] == flat["rows"] == 24
    assert up["failed_predictions"] == flat["failed_predictions"] == 0
    assert flat["median_error_mm"] < 0.3
    for key in ("median_error_mm", "rms_error_mm", "worst_error_mm"):
        assert 0.5 * flat[key] < up[key] < 2.0 * flat[key], key


def test_resuming_the_upright_run_without_its_pose_is_refused_naming_the_pose(runs, capsys):
    run = runs["up"][0]
    assert main(["validate", "--quick", "--seed", "2", "--resume", str(run)]) == 2
    err = capsys.readouterr().err
    assert "rig.base_quat" in err and len(err.strip().splitlines()) == 1
    # With it, the run is complete: nothing is measured again.
    assert main(["validate", "--quick", "--seed", "2", "--resume", str(run), "--pose", "up"]) == 0
    assert len(read_dataset(run)) == 24


def test_the_report_names_the_pose_the_robot_was_clamped_in(runs):
    assert "base clamped upright." in (runs["up"][0] / "report.md").read_text()
    assert "base clamped horizontal (the thesis's clamp)." in (runs["horizontal"][0] / "report.md").read_text()


def test_a_pose_is_named_by_where_the_backbone_points():
    from twin.pose import pose_name, rot_y, rot_z

    # Clamped pointing down at 30°: the body z axis 30° below the world's horizontal plane.
    assert pose_name(rot_y(np.radians(120.0))) == "pointing 30° below the horizontal"
    assert pose_name(rot_z(0.3) @ rot_y(np.radians(60.0))) == "pointing 30° above the horizontal"
    assert pose_name(rot_y(np.pi)) == "pointing straight down"
    assert pose_name(rot_z(1.0) @ HORIZONTAL) == "pointing horizontally"
