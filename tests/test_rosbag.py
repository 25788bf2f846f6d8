"""twin export-bag: a dataset as a rosbag2 MCAP file, read back with the MCAP library."""

import calendar
import datetime

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from twin.cli import main
from twin.data.dataset import DatasetError, DatasetWriter, read_dataset
from twin.rosbag import (BACKBONE_TOPIC, JOINT_STATE, PATH, POSE_STAMPED, PREDICTED_TIP_TOPIC, TENDONS_TOPIC,
                              TF_MESSAGE, TF_STATIC_TOPIC, TIP_TOPIC, WRENCH_STAMPED, WRENCH_TOPIC, export_bag)
from twin.params import load_params
from twin.pose import HORIZONTAL


def _row(config, rng, *, time_s, quat=True):
    row = {"config": config, "kappa_cmd_per_m": 13.0, "phi_cmd_deg": 90.0 * config, "tip_mass_kg": 0.01,
           "tip_x_m": rng.uniform(0.04, 0.06), "tip_y_m": rng.uniform(-0.01, 0.01), "tip_z_m": rng.uniform(-0.02, 0),
           "time_s": time_s}
    for i in range(1, 5):
        row[f"tension_{i}_n"] = rng.uniform(0.5, 3.0)
        row[f"length_{i}_m"] = rng.uniform(-1e-3, 1e-3)
    if quat:
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        row.update(tip_qw=q[0], tip_qx=q[1], tip_qy=q[2], tip_qz=q[3])
    return row


@pytest.fixture
def dataset(tmp_path):
    rng = np.random.default_rng(7)
    rows = [_row(0, rng, time_s=1.25), _row(1, rng, time_s=2.5, quat=False), _row(2, rng, time_s=float("nan"))]
    folder = tmp_path / "run" / "dataset"
    with DatasetWriter(folder, experiment="validation", device="sim://", params=load_params(),
                       base_rotation=HORIZONTAL, sync=False) as writer:
        for row in rows:
            writer.write(row)
    return read_dataset(folder)


def _decoded(path):
    """(channel, message, decoded ROS 2 message) of every message in the file, in log order."""
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [(channel, message, decoded) for _, channel, message, decoded in reader.iter_decoded_messages()]


def _messages(path):
    by_topic = {}
    for channel, message, decoded in _decoded(path):
        by_topic.setdefault(channel.topic, []).append((message, decoded))
    return by_topic


def test_bag_holds_every_row_with_its_values_and_stamps(dataset, tmp_path):
    out = tmp_path / "out.mcap"
    summary = export_bag(dataset.path, out)
    assert summary.rows == len(dataset) == 3
    messages = _messages(out)
    # The tip wrench only where the estimate converged (these rows are random, not a robot's shape).
    assert set(messages) - {WRENCH_TOPIC} == {TENDONS_TOPIC, TIP_TOPIC, PREDICTED_TIP_TOPIC, BACKBONE_TOPIC,
                                              TF_STATIC_TOPIC}
    assert len(messages.get(WRENCH_TOPIC, [])) <= len(dataset)
    created = datetime.datetime.fromisoformat(dataset.metadata["created"])
    origin_ns = calendar.timegm(created.utctimetuple()) * 10**9 + created.microsecond * 1000
    # The row without a time follows the last stamped one by 1 s.
    expected_ns = [origin_ns + 1_250_000_000, origin_ns + 2_500_000_000, origin_ns + 3_500_000_000]

    joints = messages[TENDONS_TOPIC]
    assert [type(msg).__name__ for _, msg in joints] == [JOINT_STATE.rsplit("/")[-1]] * 3
    assert [m.log_time for m, _ in joints] == expected_ns
    for row, (_, msg) in enumerate(joints):
        assert list(msg.name) == ["tendon_1", "tendon_2", "tendon_3", "tendon_4"]
        np.testing.assert_array_equal(msg.position, dataset.lengths_m[row])
        np.testing.assert_array_equal(msg.effort, dataset.tensions_n[row])
        assert list(msg.velocity) == []
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == expected_ns[row]

    poses = messages[TIP_TOPIC]
    assert [type(msg).__name__ for _, msg in poses] == [POSE_STAMPED.rsplit("/")[-1]] * 3
    assert [m.log_time for m, _ in poses] == expected_ns
    for row, (_, msg) in enumerate(poses):
        pose = msg.pose
        assert msg.header.frame_id == "world"  # REP 105's fixed frame
        np.testing.assert_array_equal([pose.position.x, pose.position.y, pose.position.z], dataset.tip_positions_m[row])
        q = [pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z]
        measured = dataset.tip_quaternions[row]
        if np.all(np.isfinite(measured)):
            np.testing.assert_array_equal(q, measured)
        else:
            assert q == [1.0, 0.0, 0.0, 0.0]


def test_bag_is_a_ros2_profile_file_with_its_metadata(dataset, tmp_path):
    out = tmp_path / "out.mcap"
    export_bag(dataset.path.parent, out)  # the run folder, as twin validate leaves it
    with open(out, "rb") as stream:
        reader = make_reader(stream)
        header = reader.get_header()
        summary = reader.get_summary()
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert header.profile == "ros2"
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    assert {summary.schemas[c.schema_id].name for c in summary.channels.values()} == {JOINT_STATE, POSE_STAMPED, PATH,
                                                                                     TF_MESSAGE, WRENCH_STAMPED}
    assert {summary.schemas[c.schema_id].encoding for c in summary.channels.values()} == {"ros2msg"}
    # 3 rows × (tendons, measured tip, predicted tip, backbone) + one /tf_static + the converged wrenches.
    assert summary.statistics.message_count == 13 + int(metadata["twin_tip_wrench"]["rows"])
    assert metadata["twin_dataset"]["rows"] == "3"
    assert metadata["twin_dataset"]["orientation_unmeasured_rows"] == "1"
    assert metadata["twin_dataset"]["experiment"] == "validation"


def test_cli_exports_and_refuses_what_is_not_a_dataset(dataset, tmp_path, capsys):
    out = tmp_path / "cli.mcap"
    assert main(["export-bag", str(dataset.path), str(out)]) == 0
    assert "3 rows" in capsys.readouterr().out
    assert len([m for c, m, _ in _decoded(out) if c.topic != WRENCH_TOPIC]) == 13
    (tmp_path / "empty").mkdir()
    assert main(["export-bag", str(tmp_path / "empty"), str(tmp_path / "no.mcap")]) == 2
    assert "dataset error" in capsys.readouterr().err
    assert not (tmp_path / "no.mcap").exists()
    with pytest.raises(DatasetError):
        export_bag(tmp_path / "empty", tmp_path / "no.mcap")


def test_a_failed_write_leaves_no_file(dataset, tmp_path, monkeypatch):
    import mcap_ros2.writer

    def fail(self, *args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(mcap_ros2.writer.Writer, "finish", fail)
    out = tmp_path / "torn.mcap"
    with pytest.raises(RuntimeError, match="disk full"):
        export_bag(dataset.path, out)
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir() if "torn" in p.name] == []


def test_bag_carries_tf_static_the_predicted_tip_and_the_backbone_in_rep_105_frames(dataset, tmp_path):
    from twin.data.prediction import predict_dataset
    from twin.pose import matrix_to_quat

    out = tmp_path / "out.mcap"
    export_bag(dataset.path, out)
    messages = _messages(out)
    ((_, tf),) = messages[TF_STATIC_TOPIC]
    (transform,) = tf.transforms
    assert (transform.header.frame_id, transform.child_frame_id) == ("world", "base_link")
    r = transform.transform.rotation
    np.testing.assert_allclose([r.w, r.x, r.y, r.z], matrix_to_quat(dataset.base_rotation), atol=1e-12)
    predicted = predict_dataset(dataset)
    assert predicted.converged.all()
    tips = messages[PREDICTED_TIP_TOPIC]
    paths = messages[BACKBONE_TOPIC]
    assert len(tips) == len(paths) == len(dataset)
    for row, ((_, tip), (_, path)) in enumerate(zip(tips, paths)):
        assert tip.header.frame_id == path.header.frame_id == "world"
        p = tip.pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], predicted.tip_m[row], atol=1e-12)
        points = np.array([[q.pose.position.x, q.pose.position.y, q.pose.position.z] for q in path.poses])
        assert len(points) > 5
        np.testing.assert_allclose(points[0], 0.0, atol=1e-9)  # the backbone starts at the base, world's origin
        # Its arc length is the backbone's, and its end is near the predicted (tracked) tip.
        assert np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)) == pytest.approx(
            dataset.params.backbone.length_m, rel=0.02)
        assert np.linalg.norm(points[-1] - predicted.tip_m[row]) < 0.02
