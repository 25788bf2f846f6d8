"""A dataset as a rosbag2 MCAP file, for Foxglove or rviz, without ROS installed.

The twin keeps no telemetry recording of its own: a dataset's rows are the time series (one
static measurement each, at its ``time_s``). Each row becomes one message on each topic:

``/twin/tendons`` (``sensor_msgs/msg/JointState``)
    ``name`` ``tendon_1`` … ``tendon_N`` (the dataset's N tendons); ``position`` the relative
    tendon lengths (m, + = paid out), ``effort`` the calibrated tensions (N), ``velocity`` empty.
``/twin/tip_pose`` (``geometry_msgs/msg/PoseStamped``)
    the measured tip in frame ``world`` (REP 105's fixed frame; here its origin is the robot's
    base centre, its axes the twin's world axes, z up), position in m; orientation the measured
    quaternion, the identity where the row has none (the MCAP metadata record ``twin_dataset``
    counts those rows).
``/twin/predicted_tip_pose`` (``geometry_msgs/msg/PoseStamped``)
    beside it, the Cosserat prediction of the same tracked point from the row's measured tensions
    and known tip mass (the dataset's own parameter set), frame ``world``; rows whose prediction
    failed have none.
``/twin/backbone`` (``nav_msgs/msg/Path``)
    the predicted backbone, base to tip, as poses in frame ``world`` (rviz's Path display).
``/twin/tip_wrench`` (``geometry_msgs/msg/WrenchStamped``)
    the tip force estimated from the row's tensions and tracked tip pose (``twin force DATASET``,
    :mod:`twin.force`), frame ``world``, N: the load applied at the tip, its observable part (0
    along a direction the pose cannot see; the MCAP metadata record ``twin_tip_wrench`` gives each
    row's standard deviations and unobservable axes). The torque is 0: the estimate is of a
    point contact. Rows whose estimate did not converge have none.
``/tf_static`` (``tf2_msgs/msg/TFMessage``)
    once, at the first stamp: ``world`` → ``base_link`` (REP 105's frame rigidly attached to the
    robot's base; its axes the robot's body axes, z along the unbent backbone), rotated by the base
    clamp's rotation (body → world).

Stamps are the dataset's ``created`` time plus the row's ``time_s`` (rows without one follow
the last stamped row at 1 s intervals). The file is written by ``mcap-ros2-support`` with the
``ros2`` profile and CDR-encoded messages, which is what ``ros2 bag record`` writes with its
MCAP storage; Foxglove opens it as it is, and ``ros2 bag play OUT.mcap`` replays it (older ROS 2
releases may need ``-s mcap``).

Example:
    >>> export_bag("runs/validate-20261201-120000", "sweep.mcap")
    ExportSummary(path=PosixPath('sweep.mcap'), rows=24, topics=('/twin/tendons', '/twin/tip_pose', ...))
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import math
from pathlib import Path

import numpy as np

from twin.data.dataset import read_dataset

__all__ = ["BACKBONE_TOPIC", "JOINT_STATE", "PATH", "POSE_STAMPED", "PREDICTED_TIP_TOPIC", "TENDONS_TOPIC",
           "TF_MESSAGE", "TF_STATIC_TOPIC", "TIP_TOPIC", "WRENCH_STAMPED", "WRENCH_TOPIC", "ExportSummary",
           "export_bag", "register"]

TENDONS_TOPIC = "/twin/tendons"
TIP_TOPIC = "/twin/tip_pose"
PREDICTED_TIP_TOPIC = "/twin/predicted_tip_pose"
BACKBONE_TOPIC = "/twin/backbone"
WRENCH_TOPIC = "/twin/tip_wrench"
TF_STATIC_TOPIC = "/tf_static"
# REP 105 frame names: the fixed frame, and the robot's body frame at its base.
WORLD_FRAME = "world"
BASE_FRAME = "base_link"
JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
PATH = "nav_msgs/msg/Path"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"

# Message definitions as rosbag2 stores them: the type's own fields, then each type it uses.
_SEPARATOR = "=" * 80 + "\n"
_HEADER = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
_TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
_JOINT_STATE_DEF = ("std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
                    "float64[] effort\n" + _SEPARATOR + _HEADER + _SEPARATOR + _TIME)
_POSE_STAMPED_DEF = ("std_msgs/Header header\ngeometry_msgs/Pose pose\n" + _SEPARATOR + _HEADER + _SEPARATOR + _TIME
                     + _SEPARATOR + "MSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation\n"
                     + _SEPARATOR + "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n"
                     + _SEPARATOR + "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\n"
                     "float64 w 1\n")
_POSE = ("MSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation\n"
         + _SEPARATOR + "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n"
         + _SEPARATOR + "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n")
_PATH_DEF = ("std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses\n" + _SEPARATOR + _HEADER + _SEPARATOR
             + _TIME + _SEPARATOR + "MSG: geometry_msgs/PoseStamped\nstd_msgs/Header header\nPose pose\n"
             + _SEPARATOR + _POSE)
_TF_MESSAGE_DEF = ("geometry_msgs/TransformStamped[] transforms\n" + _SEPARATOR
                   + "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n"
                   "Transform transform\n" + _SEPARATOR + _HEADER + _SEPARATOR + _TIME + _SEPARATOR
                   + "MSG: geometry_msgs/Transform\nVector3 translation\nQuaternion rotation\n" + _SEPARATOR
                   + "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n" + _SEPARATOR
                   + "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n")
_WRENCH_STAMPED_DEF = ("std_msgs/Header header\ngeometry_msgs/Wrench wrench\n" + _SEPARATOR + _HEADER + _SEPARATOR
                       + _TIME + _SEPARATOR + "MSG: geometry_msgs/Wrench\nVector3 force\nVector3 torque\n" + _SEPARATOR
                       + "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n")


@dataclasses.dataclass(frozen=True)
class ExportSummary:
    """What :func:`export_bag` wrote.

    Attributes:
        path: the MCAP file.
        rows: dataset rows exported (one message per topic each).
        topics: the topics written.
    """

    path: Path
    rows: int
    topics: tuple[str, ...]


def _stamps_ns(created: str | None, times_s: np.ndarray) -> list[int]:
    """UNIX nanoseconds of each row: ``created`` (ISO 8601; the epoch if absent) + ``time_s``.

    Integer arithmetic: a float of UNIX nanoseconds is off by a few hundred ns.
    """
    origin_ns = 0
    if created:
        try:
            moment = datetime.datetime.fromisoformat(created)
        except ValueError:
            moment = None
        if moment is not None:
            if moment.tzinfo is None:
                moment = moment.replace(tzinfo=datetime.timezone.utc)
            epoch = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)
            origin_ns = (moment - epoch) // datetime.timedelta(microseconds=1) * 1000
    stamps, last_ns = [], None
    for t in times_s:
        t = float(t)
        offset_ns = round(t * 1e9) if math.isfinite(t) else (0 if last_ns is None else last_ns + 1_000_000_000)
        last_ns = offset_ns
        stamps.append(origin_ns + offset_ns)
    return stamps


def _header(stamp_ns: int, frame_id: str) -> dict:
    return {"stamp": {"sec": stamp_ns // 1_000_000_000, "nanosec": stamp_ns % 1_000_000_000}, "frame_id": frame_id}


def _pose(position, rotation) -> dict:
    from twin.pose import matrix_to_quat

    w, x, y, z = matrix_to_quat(rotation).tolist()
    px, py, pz = np.asarray(position, dtype=float).tolist()
    return {"position": {"x": px, "y": py, "z": pz}, "orientation": {"x": x, "y": y, "z": z, "w": w}}


def export_bag(source: str | Path, out: str | Path) -> ExportSummary:
    """Write the dataset at ``source`` (a dataset folder, its ``measurements.csv`` or a
    ``twin validate`` run folder) to the rosbag2 MCAP file ``out``.

    The file is written beside ``out`` and renamed onto it when complete, so a failed export
    leaves no half-written bag.

    Raises:
        DatasetError: ``source`` is not a readable dataset.
        OSError: ``out`` cannot be written.
    """
    from mcap_ros2.writer import Writer

    dataset = read_dataset(source)
    out = Path(out)
    times_s = dataset.columns.get("time_s", np.full(len(dataset), np.nan))
    stamps = _stamps_ns(dataset.metadata.get("created"), times_s)
    lengths, tensions = dataset.lengths_m, dataset.tensions_n
    tips, quats = dataset.tip_positions_m, dataset.tip_quaternions
    names = [f"tendon_{i}" for i in range(1, dataset.tendons + 1)]
    unmeasured = 0
    # The prediction of each row, kept with its backbone (the solutions land in ``solutions``).
    from twin.data.prediction import predict_dataset

    from twin.force.rows import dataset_estimates

    solutions: list = [None] * len(dataset)
    predicted = predict_dataset(dataset, guesses=solutions)
    wrenches = list(dataset_estimates(dataset, dataset.params))
    tmp = out.with_name(f".{out.name}.tmp")
    try:
        with open(tmp, "wb") as stream:
            writer = Writer(stream)
            joint_schema = writer.register_msgdef(JOINT_STATE, _JOINT_STATE_DEF)
            pose_schema = writer.register_msgdef(POSE_STAMPED, _POSE_STAMPED_DEF)
            path_schema = writer.register_msgdef(PATH, _PATH_DEF)
            tf_schema = writer.register_msgdef(TF_MESSAGE, _TF_MESSAGE_DEF)
            wrench_schema = writer.register_msgdef(WRENCH_STAMPED, _WRENCH_STAMPED_DEF)
            first = stamps[0] if stamps else 0
            writer.write_message(TF_STATIC_TOPIC, tf_schema, {"transforms": [{
                "header": _header(first, WORLD_FRAME), "child_frame_id": BASE_FRAME,
                "transform": {"translation": {"x": 0.0, "y": 0.0, "z": 0.0},
                              "rotation": _pose([0, 0, 0], dataset.base_rotation)["orientation"]}}]},
                log_time=first, publish_time=first, sequence=0)
            predicted_rows = 0
            for row, stamp in enumerate(stamps):
                writer.write_message(TENDONS_TOPIC, joint_schema, {
                    "header": _header(stamp, ""), "name": names, "position": lengths[row].tolist(),
                    "velocity": [], "effort": tensions[row].tolist(),
                }, log_time=stamp, publish_time=stamp, sequence=row)
                w, x, y, z = quats[row].tolist()
                if not all(math.isfinite(v) for v in (w, x, y, z)):
                    w, x, y, z = 1.0, 0.0, 0.0, 0.0
                    unmeasured += 1
                px, py, pz = tips[row].tolist()
                writer.write_message(TIP_TOPIC, pose_schema, {
                    "header": _header(stamp, WORLD_FRAME),
                    "pose": {"position": {"x": px, "y": py, "z": pz},
                             "orientation": {"x": x, "y": y, "z": z, "w": w}},
                }, log_time=stamp, publish_time=stamp, sequence=row)
                estimate = wrenches[row]
                if estimate.converged:
                    fx, fy, fz = (float(v) for v in estimate.force_observable_n)
                    writer.write_message(WRENCH_TOPIC, wrench_schema, {
                        "header": _header(stamp, WORLD_FRAME),
                        "wrench": {"force": {"x": fx, "y": fy, "z": fz}, "torque": {"x": 0.0, "y": 0.0, "z": 0.0}},
                    }, log_time=stamp, publish_time=stamp, sequence=row)
                solution = solutions[row]
                if not predicted.converged[row] or solution is None:
                    continue
                writer.write_message(PREDICTED_TIP_TOPIC, pose_schema, {
                    "header": _header(stamp, WORLD_FRAME), "pose": _pose(predicted.tip_m[row], solution.rotations[-1]),
                }, log_time=stamp, publish_time=stamp, sequence=row)
                writer.write_message(BACKBONE_TOPIC, path_schema, {
                    "header": _header(stamp, WORLD_FRAME),
                    "poses": [{"header": _header(stamp, WORLD_FRAME), "pose": _pose(p, r)}
                              for p, r in zip(solution.positions_m, solution.rotations)],
                }, log_time=stamp, publish_time=stamp, sequence=row)
                predicted_rows += 1
            meta = dataset.metadata
            writer.add_metadata("twin_dataset", {
                "source": str(dataset.path or source), "experiment": str(meta.get("experiment", "")),
                "device": str(meta.get("device", "")), "created": str(meta.get("created", "")),
                "robot": str(dataset.robot or ""), "tendons": str(dataset.tendons),
                "rows": str(len(dataset)), "orientation_unmeasured_rows": str(unmeasured),
                "tip_frame": f"{WORLD_FRAME}: origin at the base centre, the twin's world axes (z up)",
                "predicted_rows": str(predicted_rows),
            })
            writer.add_metadata("twin_tip_wrench", {
                "frame": WORLD_FRAME, "unit": "N", "torque": "0: a point contact is estimated",
                "rows": str(sum(e.converged for e in wrenches)),
                # Per row: standard deviations (N) per world axis of the observable part, and which
                # axes are unobservable (their force is 0 in the message, not measured as 0).
                "force_std_n": ";".join(" ".join(f"{v:.4g}" for v in np.sqrt(np.clip(
                    np.diag(e.force_observable_cov_n2), 0.0, None))) for e in wrenches),
                "unobservable_axes": ";".join("".join(a for a, ok in zip("xyz", e.force_observable) if not ok)
                                              for e in wrenches),
            })
            writer.finish()
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)
    return ExportSummary(out, len(dataset), (TENDONS_TOPIC, TIP_TOPIC, PREDICTED_TIP_TOPIC, BACKBONE_TOPIC,
                                             WRENCH_TOPIC, TF_STATIC_TOPIC))


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export-bag",
        help="write a dataset (or a run folder's) as a rosbag2 MCAP file for Foxglove or rviz",
        description="Exports each dataset row as sensor_msgs/msg/JointState on /twin/tendons (lengths in m, "
        "tensions in N), geometry_msgs/msg/PoseStamped on /twin/tip_pose (frame world, m), the predicted tip "
        "and backbone, and the estimated tip force as geometry_msgs/msg/WrenchStamped on /twin/tip_wrench (N).",
    )
    p.add_argument("source", metavar="DATASET_OR_RUN", help="a dataset folder or a twin validate run folder")
    p.add_argument("out", metavar="OUT.mcap", help="the MCAP file to write (replaced if it exists)")
    p.set_defaults(func=run_export_bag)


def run_export_bag(args: argparse.Namespace) -> int:
    """``twin export-bag``: export, then say what was written."""
    summary = export_bag(args.source, args.out)
    print(f"{summary.path}: {summary.rows} rows on {', '.join(summary.topics)}")
    return 0
