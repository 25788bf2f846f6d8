"""The dataset format: round trip, incremental writing, resume, and refusal of bad files."""

import json

import numpy as np
import pytest

from twin import load_params
from twin.data.dataset import COLUMNS, DatasetError, DatasetWriter, read_dataset
from twin.pose import HORIZONTAL


def row(config, **extra):
    r = {"config": config, "kappa_cmd_per_m": 4.5, "phi_cmd_deg": 30.0, "tip_mass_kg": 0.005,
         "tip_x_m": 0.05, "tip_y_m": 0.001, "tip_z_m": -0.01}
    for i in range(1, 5):
        r[f"tension_{i}_n"] = 1.2 + 0.1 * i
        r[f"length_{i}_m"] = -1e-4 * i
    r.update(extra)
    return r


def writer(folder, experiment="validation"):
    return DatasetWriter(folder, experiment=experiment, device="sim://", params=load_params(),
                         base_rotation=HORIZONTAL, calibration={"gain": [1, 2, 3, 4]})


def test_round_trip_keeps_values_and_metadata(tmp_path):
    with writer(tmp_path) as w:
        w.write(row(0, tip_qw=1.0, tip_qx=0.0, tip_qy=0.0, tip_qz=0.0, time_s=1.5))
        w.write(row(1))
    d = read_dataset(tmp_path)
    assert len(d) == 2 and list(d["config"]) == [0, 1]
    assert d.tensions_n.shape == (2, 4) and d.tensions_n[0, 3] == pytest.approx(1.6)
    assert np.isnan(d.tip_quaternions[1]).all() and d.tip_quaternions[0, 0] == 1.0
    assert np.allclose(d.base_rotation, HORIZONTAL)
    assert d.params == load_params()
    assert d.metadata["calibration"] == {"gain": [1, 2, 3, 4]}
    assert d.metadata["experiment"] == "validation"


def test_every_row_is_on_disk_as_soon_as_it_is_written(tmp_path):
    w = writer(tmp_path)
    w.write(row(0))
    w.write(row(1))
    # Not closed: an interrupted run still leaves both rows readable.
    assert len(read_dataset(tmp_path)) == 2
    w.close()


def test_resume_skips_completed_configurations(tmp_path):
    with writer(tmp_path) as w:
        w.write(row(0))
        w.write(row(5))
    with writer(tmp_path) as w:
        assert w.completed() == {0, 5}
        w.write(row(6))
    assert list(read_dataset(tmp_path)["config"]) == [0, 5, 6]


def test_resuming_a_different_experiment_is_refused(tmp_path):
    with writer(tmp_path) as w:
        w.write(row(0))
    with pytest.raises(DatasetError, match="stiffness"):
        writer(tmp_path, experiment="stiffness")


def test_rows_missing_columns_are_refused(tmp_path):
    with writer(tmp_path) as w:
        bad = row(0)
        del bad["tension_3_n"]
        with pytest.raises(DatasetError, match="tension_3_n"):
            w.write(bad)


@pytest.mark.parametrize("mutate, message", [
    (lambda lines: [lines[0].replace("tip_z_m", "tip_w_m")] + lines[1:], "tip_z_m"),
    (lambda lines: lines[:1] + [lines[1].replace("0.05", "abc", 1)], "'abc' is not a number"),
    (lambda lines: lines[:1] + [lines[1].rsplit(",", 3)[0]], "fields"),
    (lambda lines: lines[:1] + [lines[1].replace("0.05", "nan", 1)], "not finite"),
])
def test_malformed_measurements_are_refused_naming_row_and_column(tmp_path, mutate, message):
    with writer(tmp_path) as w:
        w.write(row(0))
    path = tmp_path / "measurements.csv"
    path.write_text("\n".join(mutate(path.read_text().splitlines())) + "\n")
    with pytest.raises(DatasetError, match=message):
        read_dataset(tmp_path)


def test_wrong_format_or_version_is_refused(tmp_path):
    with writer(tmp_path) as w:
        w.write(row(0))
    meta_path = tmp_path / "metadata.json"
    meta = json.loads(meta_path.read_text())
    meta["version"] = 99
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match="version"):
        read_dataset(tmp_path)
    with pytest.raises(DatasetError, match="missing"):
        read_dataset(tmp_path / "nowhere")


def test_a_validate_run_folder_reads_as_its_dataset(tmp_path):
    with writer(tmp_path / "run" / "dataset") as w:
        w.write(row(0))
    assert read_dataset(tmp_path / "run").columns["config"].tolist() == [0]
    with pytest.raises(DatasetError, match="missing"):
        read_dataset(tmp_path)


def test_header_lists_the_documented_columns(tmp_path):
    with writer(tmp_path) as w:
        w.write(row(0))
    assert (tmp_path / "measurements.csv").read_text().splitlines()[0].split(",") == list(COLUMNS)


def test_a_tension_below_the_floor_is_refused_on_writing_and_reading_and_noise_around_zero_is_kept(tmp_path):
    with writer(tmp_path / "w") as w:
        with pytest.raises(DatasetError, match=r"tension_2_n.*-5.0.*a tendon only pulls"):
            w.write(row(0, tension_2_n=-5.0))
        w.write(row(1, tension_2_n=-0.002))
    assert read_dataset(tmp_path / "w").tensions_n[0, 1] == pytest.approx(-0.002)
    path = tmp_path / "w" / "measurements.csv"
    path.write_text(path.read_text().replace("-0.002", "-5.0"))
    with pytest.raises(DatasetError, match=r"row 2, column 'tension_2_n': '-5.0' is below -0.5 N"):
        read_dataset(tmp_path / "w")


@pytest.mark.parametrize("change, message", [
    (lambda meta: [meta], "format 'list'"),
    (lambda meta: {**meta, "base_rotation": "[[1, 0, 0], [0, 1, 0], [0, 0, 1]]"}, "base_rotation .* is not a 3x3"),
    (lambda meta: {**meta, "params": ["backbone"]}, "params is a JSON array, expected an object of sections"),
    (lambda meta: {**meta, "params": {"backbone": 3}}, "params section 'backbone' is a JSON number"),
])
def test_malformed_metadata_is_refused_naming_file_and_entry(tmp_path, change, message):
    with writer(tmp_path) as w:
        w.write(row(0))
    meta_path = tmp_path / "metadata.json"
    meta_path.write_text(json.dumps(change(json.loads(meta_path.read_text()))))
    with pytest.raises(DatasetError, match=message) as info:
        read_dataset(tmp_path)
    assert str(meta_path) in str(info.value)


def test_a_duplicated_column_is_refused_naming_it_and_both_fields(tmp_path):
    with writer(tmp_path) as w:
        w.write(row(0))
    path = tmp_path / "measurements.csv"
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    path.write_text("\r\n".join([lines[0] + ",tension_3_n", lines[1] + ",9.0"]) + "\r\n")
    with pytest.raises(DatasetError, match=rf"row 1, column 'tension_3_n' appears twice \(fields "
                                           rf"{header.index('tension_3_n') + 1} and {len(header) + 1}\)"):
        read_dataset(tmp_path)
