"""Dataset format version 2: N tendons, the base pose, the robot; version 1 keeps reading."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from twin import load_params
from twin.data import dataset as dataset_module
from twin.data.dataset import (COLUMNS, TENDON_GROUPS, DatasetError, DatasetWriter, TendonGroup, columns, read_dataset,
                               write_dataset)
from twin.data.prediction import predict_dataset
from twin.pose import HORIZONTAL, UP, matrix_to_quat, rot_x
from twin.robots import load_robot

# A dataset written by the version-1 writer (four tendons, no robot nor tendons entry).
V1_FIXTURE = Path(__file__).parent / "golden" / "dataset_v1"


def row(config, tendons, **extra):
    r = {"config": config, "kappa_cmd_per_m": 4.5, "phi_cmd_deg": 30.0, "tip_mass_kg": 0.005,
         "tip_x_m": 0.05, "tip_y_m": 0.001, "tip_z_m": -0.01}
    for i in range(1, tendons + 1):
        r[f"tension_{i}_n"] = 1.2 + 0.1 * i + 0.01 * config
        r[f"length_{i}_m"] = -1e-4 * i
    r.update(extra)
    return r


def write(folder, params, rows, robot=None, base_rotation=HORIZONTAL):
    return write_dataset(folder, rows, experiment="validation", device="sim://", params=params,
                         base_rotation=base_rotation, robot=robot)


def test_a_version_1_dataset_reads_as_it_always_did():
    d = read_dataset(V1_FIXTURE)
    assert d.metadata["version"] == 1 and "tendons" not in d.metadata and "robot" not in d.metadata
    assert d.tendons == 4 and d.robot is None
    assert len(d) == 3 and list(d["config"]) == [0, 1, 2]
    assert d.tensions_n.shape == (3, 4) and d.lengths_m.shape == (3, 4)
    assert d.tensions_n[2].tolist() == pytest.approx([1.32, 1.42, 1.52, 1.62])
    assert d.lengths_m[1, 3] == pytest.approx(-4e-4)
    assert np.allclose(d.base_rotation, HORIZONTAL)
    assert d.params.tendons.count == 4 and d.params.backbone.length_m == pytest.approx(0.06)
    # Version 1's columns are version 2's for four tendons, without the optional groups added since.
    optional = {c for g in TENDON_GROUPS if g.name not in ("tensions", "lengths") for c in g.columns(4)}
    optional |= {"tip_frames", "tip_sem_x_m", "tip_sem_y_m", "tip_sem_z_m"}
    assert (V1_FIXTURE / "measurements.csv").read_text().splitlines()[0].split(",") == [
        c for c in COLUMNS if c not in optional]
    assert np.isnan(d.tip_quaternions).all() and d["time_s"].tolist() == [1.0, 2.0, 3.0]


@pytest.mark.parametrize("robot, tendons", [("three-tendon", 3), ("two-segment", 6), ("endoscope", 4)])
def test_a_dataset_has_one_column_per_tendon_of_its_robot_and_records_the_robot(tmp_path, robot, tendons):
    params = load_robot(robot)
    d = write(tmp_path, params, [row(0, tendons), row(1, tendons)], robot=robot)
    header = (tmp_path / "measurements.csv").read_text().splitlines()[0].split(",")
    assert header == list(columns(tendons)) == d.metadata["columns"]
    assert [c for c in header if c.startswith("tension_")] == [f"tension_{i}_n" for i in range(1, tendons + 1)]
    assert d.metadata["version"] == 2 and d.metadata["tendons"] == tendons and d.tendons == tendons
    assert d.robot == robot
    assert d.tensions_n.shape == (2, tendons) and d.lengths_m.shape == (2, tendons)
    assert d.tensions_n[1, tendons - 1] == pytest.approx(1.2 + 0.1 * tendons + 0.01)
    # The recorded parameter set rebuilds the robot the data were taken with.
    assert d.params == params and d.params.tendons.end_discs == params.tendons.end_discs


def test_a_row_of_another_tendon_count_is_refused(tmp_path):
    three = load_robot("three-tendon")
    with DatasetWriter(tmp_path, experiment="validation", device="sim://", params=three,
                       base_rotation=HORIZONTAL) as w:
        with pytest.raises(DatasetError, match=r"unknown column\(s\) \['length_4_m', 'tension_4_n'\] .*3 tendons"):
            w.write(row(0, 4))
        with pytest.raises(DatasetError, match="tension_3_n"):
            w.write({k: v for k, v in row(0, 3).items() if k != "tension_3_n"})
        w.write(row(0, 3))
    assert len(read_dataset(tmp_path)) == 1


def test_resuming_with_a_robot_of_another_tendon_count_is_refused(tmp_path):
    write(tmp_path, load_robot("three-tendon"), [row(0, 3)])
    with pytest.raises(DatasetError, match="holds a dataset of 3 tendons; cannot resume it with a robot of 4"):
        DatasetWriter(tmp_path, experiment="validation", device="sim://", params=load_params(),
                      base_rotation=HORIZONTAL)


def _edit_metadata(folder, change):
    path = folder / "metadata.json"
    path.write_text(json.dumps(change(json.loads(path.read_text()))))
    return path


@pytest.mark.parametrize("change, message", [
    (lambda m: {**m, "tendons": 4}, r"tendons 4 but the recorded robot \(params tendons.angles_deg\) has 3"),
    (lambda m: {**m, "tendons": "3"}, "tendons '3' is not a whole number"),
    (lambda m: {**m, "tendons": True}, "tendons True is not a whole number"),
    (lambda m: {k: v for k, v in m.items() if k != "tendons"}, "missing 'tendons'"),
    (lambda m: {**m, "robot": "three-tendon"}, "robot 'three-tendon' is not an object with a name"),
    (lambda m: {k: v for k, v in m.items() if k != "robot"}, "missing 'robot'"),
])
def test_robot_entries_that_do_not_fit_are_refused_naming_file_and_entry(tmp_path, change, message):
    write(tmp_path, load_robot("three-tendon"), [row(0, 3)], robot="three-tendon")
    path = _edit_metadata(tmp_path, change)
    with pytest.raises(DatasetError, match=message) as info:
        read_dataset(tmp_path)
    assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value)


def test_a_header_with_a_tendon_beyond_the_metadatas_count_is_refused(tmp_path):
    write(tmp_path, load_robot("three-tendon"), [row(0, 3)])
    path = tmp_path / "measurements.csv"
    lines = path.read_text().splitlines()
    path.write_text("\r\n".join([lines[0] + ",tension_4_n", lines[1] + ",1.0"]) + "\r\n")
    with pytest.raises(DatasetError, match=r"column 'tension_4_n' is beyond the dataset's 3 tendons"):
        read_dataset(tmp_path)


def test_the_base_pose_reads_as_a_rotation_or_a_quaternion(tmp_path):
    tilted = rot_x(0.3) @ HORIZONTAL
    d = write(tmp_path, load_params(), [row(0, 4)], base_rotation=tilted)
    assert np.allclose(d.base_rotation, tilted)
    _edit_metadata(tmp_path, lambda m: {**m, "base_rotation": matrix_to_quat(tilted).tolist()})
    assert np.allclose(read_dataset(tmp_path).base_rotation, tilted, atol=1e-12)
    # The writer takes a quaternion too, and records what it was given.
    q = write(tmp_path / "q", load_params(), [row(0, 4)], base_rotation=[1.0, 0.0, 0.0, 0.0])
    assert q.metadata["base_rotation"] == [1.0, 0.0, 0.0, 0.0] and np.array_equal(q.base_rotation, UP)


@pytest.mark.parametrize("pose, why", [
    ("identity", "not an array of numbers"),
    ([["1", "0", "0"], ["0", "1", "0"], ["0", "0", "1"]], "not an array of numbers"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, -1]], "not orthonormal with determinant \\+1"),
    ([[2, 0, 0], [0, 2, 0], [0, 0, 2]], "not orthonormal"),
    ([0.5, 0.0, 0.0, 0.0], "a quaternion of norm 0.5, not 1"),
    ([1.0, 0.0, 0.0], "neither 3x3 nor 4"),
])
def test_a_base_pose_that_is_not_a_rotation_is_refused_on_reading_and_on_writing(tmp_path, pose, why):
    write(tmp_path / "r", load_params(), [row(0, 4)])
    path = _edit_metadata(tmp_path / "r", lambda m: {**m, "base_rotation": pose})
    with pytest.raises(DatasetError, match=f"base_rotation .* is not a 3x3 rotation or a unit quaternion .*{why}") \
            as info:
        read_dataset(tmp_path / "r")
    assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value)
    with pytest.raises(DatasetError, match="base_rotation .* nothing written"):
        write(tmp_path / "w", load_params(), [row(0, 4)], base_rotation=pose)
    assert not (tmp_path / "w" / "metadata.json").exists()


def test_data_of_another_tendon_count_are_refused_by_the_analysis_in_one_line(tmp_path):
    d = write(tmp_path, load_robot("three-tendon"), [row(0, 3)], robot="three-tendon")
    with pytest.raises(DatasetError) as info:
        d.check_robot(load_params(), "endoscope")
    assert str(info.value) == f"dataset {tmp_path} has 3 tendons; robot 'endoscope' has 4"
    with pytest.raises(DatasetError, match="has 3 tendons; the parameter set it is analysed with has 4"):
        predict_dataset(d, load_params())
    d.check_robot(load_robot("three-tendon"), "three-tendon")


def test_a_three_tendon_dataset_is_predicted_with_its_own_robot(tmp_path):
    from twin.rod.grid import pcc_tensions_n

    params = load_robot("three-tendon")
    rows = [{**row(c, 3), "kappa_cmd_per_m": 13.0, "phi_cmd_deg": phi,
             **{f"tension_{i + 1}_n": t for i, t in enumerate(pcc_tensions_n(13.0, phi, params))}}
            for c, phi in enumerate((0.0, 60.0, 120.0))]
    predictions = predict_dataset(write(tmp_path, params, rows))
    assert predictions.converged.all()
    # Bent towards each plane in turn: three different tips.
    assert np.min(np.linalg.norm(np.diff(predictions.tip_m, axis=0), axis=1)) > 1e-3


def test_a_new_optional_per_tendon_group_is_one_entry_of_the_table(tmp_path, monkeypatch):
    # Written before the group existed: it reads, the group's cells NaN.
    write(tmp_path / "old", load_params(), [row(0, 4)])
    stretch = TendonGroup("stretches", "stretch_{i}_m", "tendon stretch from a second encoder at the anchor (m)",
                          required=False)
    monkeypatch.setattr(dataset_module, "TENDON_GROUPS", dataset_module.TENDON_GROUPS + (stretch,))
    old = read_dataset(tmp_path / "old")
    assert old.per_tendon("stretches").shape == (1, 4) and np.isnan(old.per_tendon("stretches")).all()
    three = load_robot("three-tendon")
    d = write(tmp_path / "new", three, [row(0, 3, stretch_1_m=1e-5, stretch_2_m=0.0, stretch_3_m=2e-5), row(1, 3)])
    header = d.metadata["columns"]
    assert header.index("length_3_m") < header.index("stretch_1_m") < header.index("stretch_3_m") < \
        header.index("tip_x_m")
    assert d.per_tendon("stretches")[0].tolist() == [1e-5, 0.0, 2e-5] and np.isnan(d.per_tendon("stretches")[1]).all()
    with pytest.raises(KeyError, match="per-tendon group 'slip'"):
        d.per_tendon("slip")
    # Resumed, the old file keeps its header: the new group's values stay out of its rows.
    with DatasetWriter(tmp_path / "old", experiment="validation", device="sim://", params=load_params(),
                       base_rotation=HORIZONTAL) as w:
        w.write(row(1, 4, stretch_1_m=1e-5))
    resumed = read_dataset(tmp_path / "old")
    assert list(resumed["config"]) == [0, 1] and np.isnan(resumed.per_tendon("stretches")).all()
    assert "stretch_1_m" not in (tmp_path / "old" / "measurements.csv").read_text()


def test_the_v1_fixture_stays_readable_after_a_copy_is_resumed_by_todays_writer(tmp_path):
    shutil.copytree(V1_FIXTURE, tmp_path / "d")
    with DatasetWriter(tmp_path / "d", experiment="validation", device="sim://", params=load_params(),
                       base_rotation=HORIZONTAL) as w:
        assert w.completed() == {0, 1, 2}
        w.write(row(3, 4))
    d = read_dataset(tmp_path / "d")
    assert list(d["config"]) == [0, 1, 2, 3] and d.tensions_n.shape == (4, 4)


def test_appending_another_experiment_to_a_file_without_sliding_states_adds_their_columns(tmp_path):
    shutil.copytree(V1_FIXTURE, tmp_path / "d")
    before = read_dataset(tmp_path / "d")
    with pytest.raises(DatasetError, match="cannot resume it as 'decide-reapproach'"):
        DatasetWriter(tmp_path / "d", experiment="decide-reapproach", device="sim://", params=load_params(),
                      base_rotation=HORIZONTAL)
    with DatasetWriter(tmp_path / "d", experiment="decide-reapproach", device="sim://", params=load_params(),
                       base_rotation=HORIZONTAL, append=True) as w:
        w.write(row(3, 4, slide_1=1.0, slide_2=-1.0, slide_3=0.5, slide_4=0.0))
    assert (tmp_path / "d" / "measurements.csv").read_text().splitlines()[0].split(",") == list(COLUMNS)
    d = read_dataset(tmp_path / "d")
    assert list(d["experiment"]) == ["validation"] * 3 + ["decide-reapproach"]
    assert np.isnan(d.sliding_state[:3]).all() and d.sliding_state[3].tolist() == [1.0, -1.0, 0.5, 0.0]
    for name in ("tension_1_n", "length_4_m", "tip_z_m", "time_s"):
        assert d[name][:3].tolist() == before[name].tolist()


def test_a_new_dataset_records_the_sliding_state_and_reads_it_back(tmp_path):
    with DatasetWriter(tmp_path / "d", experiment="validation", device="sim://", params=load_params(),
                       base_rotation=HORIZONTAL) as w:
        w.write(row(0, 4, slide_1=1.0, slide_2=-1.0, slide_3=0.25))
    d = read_dataset(tmp_path / "d")
    assert d.sliding_state[0, :3].tolist() == [1.0, -1.0, 0.25] and np.isnan(d.sliding_state[0, 3])


def test_rows_of_another_base_pose_are_refused(tmp_path):
    shutil.copytree(V1_FIXTURE, tmp_path / "d")
    for append in (False, True):
        with pytest.raises(DatasetError, match="recorded in another base pose"):
            DatasetWriter(tmp_path / "d", experiment="validation" if not append else "decide-planes", device="sim://",
                          params=load_params(), base_rotation=UP, append=append)
    assert len(read_dataset(tmp_path / "d")) == 3
