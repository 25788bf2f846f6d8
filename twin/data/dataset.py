"""The measurement dataset: one row per static measurement, plus a metadata file.

Format ``twin-dataset`` version 2, documented in ``docs/dataset.md`` (with the version history);
in short, a folder with

``measurements.csv``
    One row per static measurement, each written as one complete line (CRLF-terminated,
    one ``write``, then synced to disk), so a run that stops half-way keeps every sample taken
    (and can be resumed: :meth:`DatasetWriter.completed`). A row is complete only with its line
    end: a last line without one is a write that was cut off (a full disk, a crash) and is
    dropped on reading and on resuming, with a :class:`DatasetWarning` naming file and row.
    Columns (units in the names; empty cell = not measured), for a robot of N tendons:

    ==========================  ====================================================================
    config                      configuration number (int), unique per (κ, φ, tip mass, repeat)
    experiment                  ``validation`` / ``stiffness`` / ... (str)
    repeat                      repetition index (int)
    kappa_cmd_per_m             commanded PCC curvature (1/m); empty with φ for a free pose
    phi_cmd_deg                 commanded bending plane (deg); empty with κ for a free pose
    tip_mass_kg                 nominal mass hung at the tip (kg)
    tension_1_n … tension_N_n   calibrated tensions at the load cells (N)
    length_1_m … length_N_m     relative tendon lengths from the encoders (m, + = paid out), when measured
    tip_x_m, tip_y_m, tip_z_m   tip position, base frame: origin at the base centre, world axes (m)
    tip_qw … tip_qz             tip orientation quaternion (w, x, y, z), world axes, when measured
    time_s                      device time of the measurement (s)
    tip_frames                  tracker frames averaged into the row's tip position, when recorded
    tip_sem_x_m … tip_sem_z_m   standard error of the row's tip position per axis (m): the
                                frames' scatter over √frames, when recorded
    ==========================  ====================================================================

    The per-tendon columns are the groups of :data:`TENDON_GROUPS`, in its order.

``metadata.json``
    ``format``, ``version``, ``experiment``, ``created``, ``device`` (URL), ``robot`` (its name),
    ``tendons`` (N), ``base_rotation`` (the base pose, body → world: a 3×3 rotation or a unit
    quaternion w, x, y, z), ``gravity_m_s2``, ``params`` (the full parameter set with sources:
    the robot's parts, from which :func:`recorded_params` rebuilds the predictor),
    ``calibration`` (the load-cell calibration applied, or null), ``notes``, ``left_out`` (the
    configurations of the grid not run, each with its ``config`` and ``reason``), ``columns``.

Version 1 (four tendons, no ``robot`` nor ``tendons`` entry) reads as it always did.

Readers refuse files with missing, duplicated or malformed columns with a message naming the
file, the row and the column — a tension below :data:`TENSION_FLOOR_N` is malformed, a tendon
only pulls — and a ``metadata.json`` that is not an object of the documented entries; the
writer refuses values the reader would refuse (NaN or inf in a required column, such a
tension), so a file it wrote always reads back.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import functools
import io
import json
import math
import os
import re
import warnings
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from twin.inputs import DATASET_MAX_BYTES, METADATA_MAX_BYTES, InputFileError, read_input
from twin.params import Params, _from_dict, load_params
from twin.pose import rotation_of_quat

__all__ = [
    "FORMAT",
    "TENSION_FLOOR_N",
    "TENDON_GROUPS",
    "VERSION",
    "COLUMNS",
    "REQUIRED_COLUMNS",
    "DatasetError",
    "DatasetWarning",
    "Dataset",
    "DatasetWriter",
    "TendonGroup",
    "columns",
    "read_dataset",
    "read_metadata",
    "recorded_params",
    "recorded_rotation",
    "write_atomic",
    "write_dataset",
]

FORMAT = "twin-dataset"
VERSION = 2
# The versions this reader reads (docs/dataset.md has what each changed).
READABLE_VERSIONS = (1, 2)
# The thesis endoscope's tendon count, the only one version 1 knows.
TENDONS = 4
MEASUREMENTS = "measurements.csv"
METADATA = "metadata.json"
# Where a ``twin validate`` run folder keeps its dataset.
RUN_DATASET = "dataset"


@dataclasses.dataclass(frozen=True)
class TendonGroup:
    """A group of per-tendon columns: ``pattern.format(i=i)`` for tendon i = 1 … N.

    Attributes:
        name: what :meth:`Dataset.per_tendon` calls the group.
        pattern: the column name, with ``{i}`` for the tendon number and the unit at the end.
        meaning: what a cell holds (with its unit), for the documentation.
        required: every row has a finite number in every column; an optional group may be
            missing from a file (older datasets) and its cells may be empty (not measured).
    """

    name: str
    pattern: str
    meaning: str
    required: bool = True

    def columns(self, tendons: int) -> tuple[str, ...]:
        """The group's column names for ``tendons`` tendons, in order."""
        return tuple(self.pattern.format(i=i) for i in range(1, tendons + 1))


# The per-tendon columns, in file order: a new group is one more line (optional, so that the
# datasets written before it keep reading).
TENDON_GROUPS = (
    TendonGroup("tensions", "tension_{i}_n", "calibrated tension at the load cell (N)"),
    TendonGroup("lengths", "length_{i}_m", "relative tendon length from the encoder (m, + = paid out)",
                required=False),
    TendonGroup("sliding_state", "slide_{i}", "the tendon friction's sliding state σ followed from the encoder, "
                "averaged over the row's measurement window "
                "(+1 last pulled in … −1 last paid out, 1; twin.effects.SlidingState)", required=False),
)

_INT_COLUMNS = ("config", "repeat")
_STR_COLUMNS = ("experiment",)
_LEADING_COLUMNS = ("config", "experiment", "repeat", "kappa_cmd_per_m", "phi_cmd_deg", "tip_mass_kg")
_TRAILING_COLUMNS = ("tip_x_m", "tip_y_m", "tip_z_m", "tip_qw", "tip_qx", "tip_qy", "tip_qz", "time_s", "tip_frames",
                     "tip_sem_x_m", "tip_sem_y_m", "tip_sem_z_m")
# Columns that may be left out of a row (the writer fills in the experiment and repeat 0).
_DEFAULTED = ("experiment", "repeat")
# Columns that may be empty (not measured), besides the optional per-tendon groups. The command
# (κ, φ) is empty, both cells, for a free pose: one taken off any grid (an imported lab's data).
_NULLABLE = ("kappa_cmd_per_m", "phi_cmd_deg", "tip_qw", "tip_qx", "tip_qy", "tip_qz", "time_s",
             "tip_frames", "tip_sem_x_m", "tip_sem_y_m", "tip_sem_z_m")
_COMMAND = ("kappa_cmd_per_m", "phi_cmd_deg")
_HALF_COMMAND = "has a command κ or φ without the other (a free pose leaves both empty)"
# Lowest tension (N) a row may report: a slack tendon reads its load cell's noise around zero
# (millinewtons); a reading further below is a wiring, sign or calibration fault, which a
# prediction must not quietly read as a slack tendon.
TENSION_FLOOR_N = -0.5


@dataclasses.dataclass(frozen=True)
class _Layout:
    """The columns of a dataset of ``tendons`` tendons and what each may hold."""

    tendons: int
    columns: tuple[str, ...]
    required: tuple[str, ...]
    nullable: frozenset[str]
    tensions: frozenset[str]
    # Matches a column of any per-tendon group, for any tendon number.
    per_tendon: re.Pattern


def _layout(tendons: int) -> _Layout:
    return _layout_of(tendons, TENDON_GROUPS)


@functools.cache
def _layout_of(tendons: int, groups: tuple[TendonGroup, ...]) -> _Layout:
    grouped = tuple(c for g in groups for c in g.columns(tendons))
    optional = {c for g in groups if not g.required for c in g.columns(tendons)}
    every = _LEADING_COLUMNS + grouped + _TRAILING_COLUMNS
    nullable = frozenset(_NULLABLE) | optional
    tensions = next(g for g in groups if g.name == "tensions").columns(tendons)
    pattern = re.compile("|".join(re.escape(g.pattern).replace(re.escape("{i}"), "[0-9]+") for g in groups))
    return _Layout(tendons, every, tuple(c for c in every if c not in nullable and c not in _DEFAULTED),
                   nullable, frozenset(tensions), pattern)


def columns(tendons: int = TENDONS) -> tuple[str, ...]:
    """The columns of a dataset of ``tendons`` tendons, in file order."""
    return _layout(tendons).columns


# The columns of the thesis endoscope's datasets (four tendons).
COLUMNS = columns(TENDONS)
REQUIRED_COLUMNS = _layout(TENDONS).required


# What csv.writer ends a row with; a row is complete only when its line end is on disk.
_LINE_END = "\r\n"
_NEGATIVE_TENSION = f"is below {TENSION_FLOOR_N} N (a tendon only pulls: a sign, wiring or calibration fault)"


class DatasetError(ValueError):
    """A dataset file is missing, of another format, or has missing or malformed columns."""


class DatasetWarning(UserWarning):
    """A dataset was read by dropping a torn last row (a write cut off by a full disk or a crash)."""


@dataclasses.dataclass(frozen=True)
class Dataset:
    """A dataset in memory: column arrays and the metadata.

    Attributes:
        columns: name → array (float, int for config/repeat, str for experiment).
        metadata: the parsed ``metadata.json``.
        path: the folder it was read from (None if built in memory).
    """

    columns: Mapping[str, np.ndarray]
    metadata: Mapping[str, Any]
    path: Path | None = None

    def __len__(self) -> int:
        return len(self.columns["config"])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    @property
    def tendons(self) -> int:
        """N, the robot's tendon count (4 in a version-1 dataset)."""
        return int(self.metadata.get("tendons", TENDONS))

    @property
    def robot(self) -> str | None:
        """The name of the robot the data were taken with (None when not recorded: version 1)."""
        robot = self.metadata.get("robot")
        return robot.get("name") if isinstance(robot, Mapping) else None

    def per_tendon(self, group: str) -> np.ndarray:
        """(rows, N) the columns of per-tendon group ``group`` (a name in :data:`TENDON_GROUPS`);
        NaN where an optional group was not measured or is not in the file.

        Raises:
            KeyError: no such group.
        """
        found = [g for g in TENDON_GROUPS if g.name == group]
        if not found:
            raise KeyError(f"per-tendon group {group!r}: expected one of {', '.join(g.name for g in TENDON_GROUPS)}")
        nan = np.full(len(self), np.nan)
        return np.stack([self.columns.get(c, nan) for c in found[0].columns(self.tendons)], axis=1)

    @property
    def tensions_n(self) -> np.ndarray:
        """(rows, N) calibrated tensions (N)."""
        return self.per_tendon("tensions")

    @property
    def lengths_m(self) -> np.ndarray:
        """(rows, N) relative tendon lengths (m)."""
        return self.per_tendon("lengths")

    @property
    def sliding_state(self) -> np.ndarray:
        """(rows, N) the friction's sliding state recorded with each row (NaN where not recorded:
        the prediction then guesses it from the lengths, :func:`twin.effects.friction_direction`)."""
        return self.per_tendon("sliding_state")

    @property
    def free(self) -> np.ndarray:
        """(rows,) True for a free pose: a row with no commanded (κ, φ) (imported from a lab's data)."""
        return np.isnan(np.asarray(self.columns["kappa_cmd_per_m"], dtype=float))

    def bends(self) -> tuple[np.ndarray, np.ndarray]:
        """(κ (rows,) 1/m, φ (rows,) deg) of each row for analyses that group or fit over the bend:
        the commanded ones, and for a free pose the constant-curvature arc of the robot's length
        through its measured tip, in the base's body frame (z along the straight backbone):
        φ = atan2(y, x), κ = 2 atan2(√(x² + y²), z) / L."""
        kappa = np.asarray(self.columns["kappa_cmd_per_m"], dtype=float).copy()
        phi = np.asarray(self.columns["phi_cmd_deg"], dtype=float).copy()
        free = np.isnan(kappa)
        if free.any():
            body = self.tip_positions_m[free] @ self.base_rotation  # R^T p per row
            radial = np.hypot(body[:, 0], body[:, 1])
            kappa[free] = 2.0 * np.arctan2(radial, body[:, 2]) / self.params.backbone.length_m
            phi[free] = np.degrees(np.arctan2(body[:, 1], body[:, 0])) % 360.0
        return kappa, phi

    @property
    def tip_positions_m(self) -> np.ndarray:
        """(rows, 3) measured tip positions, base frame (m)."""
        return np.stack([self.columns[c] for c in ("tip_x_m", "tip_y_m", "tip_z_m")], axis=1)

    @property
    def tip_quaternions(self) -> np.ndarray:
        """(rows, 4) measured tip orientations (w, x, y, z); NaN rows where not measured."""
        return np.stack([self.columns[c] for c in ("tip_qw", "tip_qx", "tip_qy", "tip_qz")], axis=1)

    @property
    def base_rotation(self) -> np.ndarray:
        """The base pose the data were taken in, 3×3 (body → world), also when recorded as a quaternion."""
        return recorded_rotation(self.metadata["base_rotation"])

    @property
    def params(self) -> Params:
        """The parameter set recorded with the data (what the model believed at the time).

        Keys added to the parameter set after the data was recorded take today's defaults,
        marked as such in their source.
        """
        return recorded_params(self.metadata, origin=f"{self.path or 'dataset'} metadata params")

    def check_robot(self, params: Params, robot: str | None = None) -> None:
        """Refuse to analyse the data with a robot of another tendon count.

        Args:
            params: the parameter set the data are to be analysed with.
            robot: its robot's name, for the message (None: "the parameter set").

        Raises:
            DatasetError: one line, e.g. "dataset X has 3 tendons; robot 'endoscope' has 4".
        """
        if params.tendons.count != self.tendons:
            who = f"robot {robot!r}" if robot else "the parameter set it is analysed with"
            raise DatasetError(f"dataset {self.path or '(in memory)'} has {self.tendons} tendons; {who} has "
                               f"{params.tendons.count}")

    def subset(self, mask: np.ndarray) -> "Dataset":
        """The rows where ``mask`` is true (same metadata)."""
        mask = np.asarray(mask)
        return Dataset({k: v[mask] for k, v in self.columns.items()}, self.metadata, self.path)


def recorded_params(metadata: Mapping[str, Any], origin: str = "dataset metadata params") -> Params:
    """The parameter set recorded in a dataset's ``metadata.json`` (see :attr:`Dataset.params`).

    Raises:
        ParameterError: the recorded set does not load with today's parameter keys.
    """
    merged = load_params().to_dict()
    for section, entries in merged.items():
        for key, entry in entries.items():
            entry["source"] = f"default (not recorded with the data): {entry['source']}"
    for section, entries in metadata["params"].items():
        merged.setdefault(section, {}).update(entries)
    return _from_dict(merged, origin=origin)


def write_atomic(path: str | Path, text: str) -> Path:
    """Write a whole file so that it is either all there or not changed at all.

    The text goes to a temporary file beside ``path``, is synced to disk and renamed over
    ``path``; a full disk or a crash leaves the old file (or none) and no half-written one.

    Raises:
        OSError: the write failed (the temporary file is removed).
    """
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(temporary, "w", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(temporary, path)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        raise OSError(exc.errno, exc.strerror, str(path)) from exc
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    _sync_folder(path.parent)
    return path


def _sync_folder(folder: Path) -> None:
    """Sync a folder's entries (a rename or a new file) to disk, where the OS allows it."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some filesystems do not sync folders; the data itself is synced
    finally:
        os.close(fd)


def _add_columns(path: Path, header: tuple[str, ...], columns: tuple[str, ...], complete_bytes: int) -> None:
    """Rewrite ``measurements.csv`` under the header ``columns`` (a superset of ``header``):
    every complete row keeps its cells, a new column is empty. Atomic (:func:`write_atomic`)."""
    lines = path.read_bytes()[:complete_bytes].split(b"\n")
    index = {name: i for i, name in enumerate(header)}
    out = [_line(columns)]
    for r, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = _fields(line, path, r)
        out.append(_line([cells[index[c]] if c in index else "" for c in columns]))
    write_atomic(path, "".join(out))


def _line(cells: Iterable[str]) -> str:
    """One CSV row as a complete line, quoted as csv.writer quotes it."""
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator=_LINE_END).writerow(cells)
    return buffer.getvalue()


def recorded_rotation(value) -> np.ndarray:
    """The 3×3 rotation (body → world) of a recorded base pose: a 3×3 rotation matrix or a unit
    quaternion (w, x, y, z).

    Raises:
        ValueError: anything else (a string, a reflection, a matrix that is not orthonormal, a
            quaternion whose norm is not 1); the message says which.
    """
    raw = np.asarray(value) if isinstance(value, (list, tuple, np.ndarray)) else np.zeros(0, dtype=object)
    if raw.dtype.kind not in "iuf":
        raise ValueError("not an array of numbers")
    rot = raw.astype(float)
    if not np.all(np.isfinite(rot)):
        raise ValueError("not finite")
    if rot.shape == (4,):
        if abs(np.linalg.norm(rot) - 1.0) > 1e-6:
            raise ValueError(f"a quaternion of norm {np.linalg.norm(rot):.6g}, not 1")
        return rotation_of_quat(rot)
    if rot.shape != (3, 3):
        raise ValueError(f"of shape {rot.shape}, neither 3x3 nor 4")
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
        raise ValueError("not orthonormal with determinant +1")
    return rot


def _metadata(*, experiment: str, device: str, params: Params, base_rotation, calibration=None,
              notes: str = "", robot: str | None = None, left_out: Iterable[Mapping[str, Any]] = ()) -> dict:
    try:
        recorded_rotation(base_rotation)
        pose = np.asarray(base_rotation, dtype=float)
    except ValueError as exc:
        raise DatasetError(f"base_rotation {base_rotation!r} is not a 3x3 rotation or a unit quaternion "
                           f"(w, x, y, z): {exc}; nothing written") from None
    return {
        "format": FORMAT,
        "version": VERSION,
        "experiment": experiment,
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "device": device,
        "robot": {"name": robot},
        "tendons": params.tendons.count,
        "base_rotation": pose.tolist(),
        "gravity_m_s2": params.environment.gravity_m_s2,
        "params": params.to_dict(),
        "calibration": calibration,
        "notes": notes,
        "left_out": [dict(entry) for entry in left_out],
        "columns": list(columns(params.tendons.count)),
    }


class DatasetWriter:
    """Writes a dataset row by row, resuming a folder that already has rows.

    Every row goes to disk as one complete line in one ``write`` (and is synced when ``sync``):
    a row is either wholly in the file or not at all. A write that fails (a full disk, an I/O
    error) is cut back off the file before the ``OSError`` goes on, so the dataset stays
    readable and resumable. Values the reader would refuse are refused here, before anything
    is written. One writer at a time: a second one on the same folder is refused.

    Example:
        >>> with DatasetWriter(folder, experiment="validation", device="sim://", params=p,
        ...                    base_rotation=HORIZONTAL) as w:
        ...     if 7 not in w.completed():
        ...         w.write({"config": 7, ...})

    Args:
        params: the parameter set the data are taken with: its tendon count N sets the columns,
            and it is recorded whole (the robot's parts, for :func:`recorded_params`).
        base_rotation: the device's base pose, 3×3 (body → world) or a unit quaternion (w, x, y, z).
        robot: the robot's name (``--robot``), recorded in the metadata.
        left_out: the configurations of the experiment's grid it does not run, each a mapping
            with its ``config`` and the ``reason`` (recorded as ``left_out``).
        append: add rows of another ``experiment`` to an existing dataset (of the same robot);
            they carry their experiment in the ``experiment`` column. An optional per-tendon group
            the file was written without is added to it first (empty in its old rows), whereas a
            plain resume keeps the file's header and leaves such a group out.
        sync: sync every row to disk (the default: a row is seconds of rig time); with False,
            rows are synced once, on :meth:`close` (bulk writes of synthetic data).

    Raises:
        DatasetError: the folder holds another experiment, a dataset of another tendon count,
            a damaged dataset, or is being written by another writer; a base pose that is not
            a rotation.
        OSError: the folder or its files cannot be created or written.
    """

    def __init__(self, folder: str | Path, *, experiment: str, device: str, params: Params, base_rotation,
                 calibration: Mapping | None = None, notes: str = "", robot: str | None = None,
                 left_out: Iterable[Mapping[str, Any]] = (), sync: bool = True, append: bool = False):
        self.folder = Path(folder)
        self._layout = _layout(params.tendons.count)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.experiment = experiment
        self.path = self.folder / MEASUREMENTS
        self._sync = sync
        self._done: set[int] = set()
        self._left_out_columns: frozenset[str] = frozenset()
        if self.path.exists() and self.path.stat().st_size > 0:
            existing, complete_bytes, header = _read(self.folder)
            if existing.metadata.get("experiment") != experiment and not append:
                raise DatasetError(f"{self.folder}: holds a {existing.metadata.get('experiment')!r} dataset; "
                                   f"cannot resume it as {experiment!r}")
            if existing.tendons != params.tendons.count:
                raise DatasetError(f"{self.folder}: holds a dataset of {existing.tendons} tendons; cannot resume it "
                                   f"with a robot of {params.tendons.count}")
            # Its rows are predicted in the recorded pose: rows taken in another would be wrong.
            try:
                same_pose = np.allclose(existing.base_rotation, recorded_rotation(base_rotation), atol=1e-6)
            except ValueError as exc:
                raise DatasetError(f"base_rotation {base_rotation!r} is not a 3x3 rotation or a unit quaternion "
                                   f"(w, x, y, z): {exc}; nothing written") from None
            if not same_pose:
                raise DatasetError(f"{self.folder}: was recorded in another base pose ({existing.base_rotation.tolist()}) "
                                   f"than the device's ({recorded_rotation(base_rotation).tolist()}); cannot add rows")
            self._done = set(int(c) for c in existing["config"])
            # Rows go under the file's header: an optional group it was written without stays out.
            kept = tuple(c for c in self._layout.columns if c in header or c in self._layout.required)
            if append and kept != self._layout.columns:
                # A deciding experiment's rows carry what the file was written without (the
                # sliding state, which is what tells friction apart): the file gains those
                # columns, empty in its old rows, rewritten whole and atomically first.
                _add_columns(self.path, header, self._layout.columns, complete_bytes)
                kept, complete_bytes = self._layout.columns, self.path.stat().st_size
            self._left_out_columns = frozenset(self._layout.columns) - frozenset(kept)
            self._layout = dataclasses.replace(self._layout, columns=kept)
        else:
            meta = _metadata(experiment=experiment, device=device, params=params, base_rotation=base_rotation,
                             calibration=calibration, notes=notes, robot=robot, left_out=left_out)
            write_atomic(self.folder / METADATA, json.dumps(meta, indent=1))
            try:
                write_atomic(self.path, _line(self._layout.columns))
            except OSError:
                # No half-made dataset: without its header the folder is plainly not a dataset yet.
                (self.folder / METADATA).unlink(missing_ok=True)
                raise
            complete_bytes = None
        self._fd: int | None = os.open(self.path, os.O_RDWR | os.O_APPEND)
        try:
            _lock(self._fd, self.path)
            if complete_bytes is not None and os.fstat(self._fd).st_size > complete_bytes:
                # The torn last row _read warned about: cut it off, or the next row would extend it.
                os.ftruncate(self._fd, complete_bytes)
            if complete_bytes and os.pread(self._fd, 1, complete_bytes - 1) != b"\n":
                os.write(self._fd, _LINE_END.encode())  # a header that lost its line end
        except BaseException:
            os.close(self._fd)
            raise

    def completed(self) -> set[int]:
        """Configuration numbers already written (to skip on resume)."""
        return set(self._done)

    def write(self, row: Mapping[str, Any]) -> None:
        """Append one measurement as one complete line. Missing optional values are left empty.

        Raises:
            DatasetError: a required column is missing or not a finite number, a column is
                unknown, or a value is not of its column's type (nothing is written).
            OSError: the write failed (a full disk, an I/O error); the file is as before it,
                and the error names it.
        """
        config = row.get("config")
        layout = self._layout
        row = {k: v for k, v in row.items() if k not in self._left_out_columns}
        missing = [c for c in layout.required if c not in row]
        if missing:
            raise DatasetError(f"row for config {config!r} lacks column(s) {missing}")
        unknown = set(row) - set(layout.columns)
        if unknown:
            raise DatasetError(f"row for config {config!r} has unknown column(s) {sorted(unknown)} (a dataset of "
                               f"{layout.tendons} tendons)")
        values = dict(row)
        if _is_empty(values.get(_COMMAND[0])) != _is_empty(values.get(_COMMAND[1])):
            raise DatasetError(f"{self.path}: row for config {config!r} {_HALF_COMMAND}; not written")
        values.setdefault("experiment", self.experiment)
        values.setdefault("repeat", 0)
        cells = [self._cell(c, values.get(c), config) for c in layout.columns]
        data = _line(cells).encode("utf-8")
        fd = self._fd
        if fd is None:
            raise DatasetError(f"{self.path}: row for config {config!r} written after close(); not written")
        start = os.fstat(fd).st_size
        try:
            written = 0
            while written < len(data):
                written += os.write(fd, data[written:])
            if self._sync:
                os.fsync(fd)
        except OSError as exc:
            try:
                os.ftruncate(fd, start)
            except OSError:
                pass  # the reader drops a torn last row anyway
            raise OSError(exc.errno, f"{exc.strerror} (writing the row for config {config})",
                          str(self.path)) from exc
        self._done.add(int(values["config"]))

    def _cell(self, name: str, value: Any, config: Any) -> str:
        """The text of one cell, refusing what :func:`read_dataset` would refuse."""
        def refuse(problem: str) -> DatasetError:
            return DatasetError(f"{self.path}: row for config {config!r}: column {name!r} = {value!r} {problem}; "
                                "not written")

        if name in _STR_COLUMNS:
            text = str(value)
            if "\r" in text or "\n" in text:
                raise refuse("holds a line break")
            return text
        if value is None or (isinstance(value, (float, np.floating)) and math.isnan(value)):
            if name in self._layout.nullable:
                return ""
            raise refuse("is not a number (a required column must be measured)")
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise refuse("is not a number")
        if not math.isfinite(value):
            raise refuse("is not finite")
        if name in _INT_COLUMNS:
            if value != int(value):
                raise refuse("is not a whole number")
            return str(int(value))
        if name in self._layout.tensions and value < TENSION_FLOOR_N:
            raise refuse(_NEGATIVE_TENSION)
        return repr(float(value))

    def close(self) -> None:
        """Sync (when rows were not synced one by one) and close; closing twice is harmless."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            if not self._sync:
                os.fsync(fd)
        finally:
            os.close(fd)

    def __enter__(self) -> "DatasetWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _lock(fd: int, path: Path) -> None:
    """Hold an exclusive lock on the measurements file while writing (where the OS has flock)."""
    try:
        import fcntl
    except ImportError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise DatasetError(f"{path}: another run is writing this dataset") from None


def _dataset_folder(folder: str | Path) -> Path:
    """The dataset folder meant by a dataset folder, its ``measurements.csv`` or a run folder."""
    folder = Path(folder)
    if folder.is_file():
        folder = folder.parent
    if not (folder / METADATA).exists() and (folder / RUN_DATASET / METADATA).exists():
        folder = folder / RUN_DATASET
    return folder


def read_metadata(folder: str | Path) -> dict:
    """Read and check a dataset's ``metadata.json`` (the folder as for :func:`read_dataset`).

    Raises:
        DatasetError: missing file, not JSON, wrong format/version, missing or bad entries.
    """
    meta_path = _dataset_folder(folder) / METADATA
    if not meta_path.exists():
        raise DatasetError(f"{meta_path}: missing (a twin dataset folder holds {MEASUREMENTS} and {METADATA})")
    try:
        metadata = json.loads(read_input(meta_path, max_bytes=METADATA_MAX_BYTES).decode("utf-8"))
    except InputFileError as exc:
        raise DatasetError(str(exc)) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{meta_path}: not valid JSON: {exc}") from None
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT:
        found = metadata.get("format") if isinstance(metadata, dict) else type(metadata).__name__
        raise DatasetError(f"{meta_path}: format {found!r}, expected {FORMAT!r}")
    version = metadata.get("version")
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        raise DatasetError(f"{meta_path}: version {version!r}; this reader reads version "
                           f"{' and '.join(str(v) for v in READABLE_VERSIONS)}")
    for key in ("base_rotation", "params") + (("robot", "tendons") if version >= 2 else ()):
        if key not in metadata:
            raise DatasetError(f"{meta_path}: missing {key!r}")
    params = metadata["params"]
    if not isinstance(params, dict):
        raise DatasetError(f"{meta_path}: params is a JSON {_json_type(params)}, expected an object of sections")
    for section, entries in params.items():
        if not isinstance(entries, dict):
            raise DatasetError(f"{meta_path}: params section {section!r} is a JSON {_json_type(entries)}, "
                               "expected an object of entries")
    try:
        recorded_rotation(metadata["base_rotation"])
    except ValueError as exc:
        raise DatasetError(f"{meta_path}: base_rotation {metadata['base_rotation']!r} is not a 3x3 rotation or a "
                           f"unit quaternion (w, x, y, z): {exc}") from None
    if version >= 2:
        _check_robot_entries(metadata, meta_path)
    left_out = metadata.get("left_out", [])
    if not isinstance(left_out, list) or not all(isinstance(e, dict) and "config" in e for e in left_out):
        raise DatasetError(f"{meta_path}: left_out {left_out!r} is not a list of objects with a config")
    return metadata


def _check_robot_entries(metadata: Mapping[str, Any], meta_path: Path) -> None:
    """Version 2's ``robot`` and ``tendons``: a name (or null), and a count that is the recorded
    robot's (one tendon per entry of its ``tendons.angles_deg``).

    Raises:
        DatasetError: one line naming the file and the entry.
    """
    robot = metadata["robot"]
    if not isinstance(robot, dict) or not isinstance(robot.get("name", ""), (str, type(None))):
        raise DatasetError(f"{meta_path}: robot {robot!r} is not an object with a name (a string or null)")
    tendons = metadata["tendons"]
    if isinstance(tendons, bool) or not isinstance(tendons, int) or tendons < 1:
        raise DatasetError(f"{meta_path}: tendons {tendons!r} is not a whole number >= 1")
    angles = metadata["params"].get("tendons", {}).get("angles_deg")
    angles = angles.get("value") if isinstance(angles, dict) else angles
    if not isinstance(angles, list):
        raise DatasetError(f"{meta_path}: params tendons.angles_deg {angles!r} is not a list of angles: the "
                           "recorded robot has no tendon layout")
    if len(angles) != tendons:
        raise DatasetError(f"{meta_path}: tendons {tendons} but the recorded robot (params tendons.angles_deg) has "
                           f"{len(angles)}")


def _json_type(value: Any) -> str:
    """The JSON name of a parsed value's type (object, array, string, number, ...)."""
    names = {dict: "object", list: "array", str: "string", bool: "boolean", int: "number", float: "number"}
    return "null" if value is None else names.get(type(value), type(value).__name__)


def read_dataset(folder: str | Path) -> Dataset:
    """Read and check a dataset folder (or a path to its ``measurements.csv``, or the run
    folder of ``twin validate``, which keeps its dataset in ``dataset/``).

    A last row without its line end (a write cut off by a full disk or a crash) is dropped
    with a :class:`DatasetWarning` naming the file and the row.

    Raises:
        DatasetError: missing files, wrong format/version, missing or malformed columns
            (the message names the file, row and column).
    """
    return _read(folder)[0]


def _read(folder: str | Path) -> tuple[Dataset, int, tuple[str, ...]]:
    """The dataset, the length (bytes) of its ``measurements.csv`` up to the last complete row,
    and the file's header."""
    folder = _dataset_folder(folder)
    csv_path = folder / MEASUREMENTS
    metadata = read_metadata(folder)
    if not csv_path.exists():
        raise DatasetError(f"{csv_path}: missing (a twin dataset folder holds {MEASUREMENTS} and {METADATA})")
    try:
        data = read_input(csv_path, max_bytes=DATASET_MAX_BYTES)
    except InputFileError as exc:
        raise DatasetError(str(exc)) from None
    lines = data.split(b"\n")
    # After the last line end comes either nothing or a row whose write was cut off.
    torn = lines.pop()
    if not lines:
        if not torn.strip():
            raise DatasetError(f"{csv_path}: empty file (no header)")
        lines, torn = [torn], b""
    header = _fields(lines[0], csv_path, 1)
    seen: dict[str, int] = {}
    for i, name in enumerate(header, start=1):
        if name in seen:
            raise DatasetError(f"{csv_path}: row 1, column {name!r} appears twice (fields {seen[name]} and {i})")
        seen[name] = i
    layout = _layout(int(metadata.get("tendons", TENDONS)))
    missing = [c for c in layout.required if c not in header]
    if missing:
        raise DatasetError(f"{csv_path}: missing column(s) {missing}")
    beyond = [name for name in header if name not in layout.columns and layout.per_tendon.fullmatch(name)]
    if beyond:
        raise DatasetError(f"{csv_path}: row 1, column {beyond[0]!r} is beyond the dataset's {layout.tendons} "
                           f"tendons ({METADATA} tendons)")
    index = {name: i for i, name in enumerate(header)}
    columns: dict[str, list] = {name: [] for name in header if name in layout.columns}
    for r, line in enumerate(lines[1:], start=2):
        row = _fields(line, csv_path, r)
        if len(row) != len(header):
            raise DatasetError(f"{csv_path}: row {r} has {len(row)} fields, the header {len(header)}")
        for name in columns:
            columns[name].append(_parse(row[index[name]].strip(), name, csv_path, r, layout))
    if all(c in columns for c in _COMMAND):
        for r, (kappa, phi) in enumerate(zip(*(columns[c] for c in _COMMAND)), start=2):
            if math.isnan(kappa) != math.isnan(phi):
                raise DatasetError(f"{csv_path}: row {r} {_HALF_COMMAND}")
    complete_bytes = len(data) - len(torn)
    if torn:
        warnings.warn(f"{csv_path}: row {len(lines) + 1} is incomplete (no line end: its write was cut off, "
                      f"e.g. by a full disk or a crash); dropped it, {len(lines) - 1} complete row(s) kept",
                      DatasetWarning, stacklevel=3)
    out: dict[str, np.ndarray] = {}
    for name, values in columns.items():
        if name in _INT_COLUMNS:
            out[name] = np.array(values, dtype=int)
        elif name in _STR_COLUMNS:
            out[name] = np.array(values, dtype=str)
        else:
            out[name] = np.array(values, dtype=float)
    n = len(lines) - 1
    out.setdefault("repeat", np.zeros(n, dtype=int))
    out.setdefault("experiment", np.array([metadata.get("experiment", "")] * n, dtype=str))
    for name in layout.nullable:
        out.setdefault(name, np.full(n, np.nan))
    return Dataset(out, metadata, folder), complete_bytes, tuple(header)


def _is_empty(value: Any) -> bool:
    return value is None or (isinstance(value, (float, np.floating)) and math.isnan(value))


def _fields(line: bytes, path: Path, row: int) -> list[str]:
    """The cells of one line of ``measurements.csv`` (its line end already split off)."""
    try:
        text = line.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: row {row}: byte {exc.start + 1} is not UTF-8 text") from None
    return next(csv.reader([text.rstrip("\r")]), [])


def _parse(text: str, name: str, path: Path, row: int, layout: _Layout):
    if name in _STR_COLUMNS:
        return text
    if text == "":
        if name in layout.nullable:
            return math.nan
        raise DatasetError(f"{path}: row {row}, column {name!r} is empty")
    try:
        value = int(text) if name in _INT_COLUMNS else float(text)
    except ValueError:
        raise DatasetError(f"{path}: row {row}, column {name!r}: {text!r} is not a number") from None
    if isinstance(value, float) and not math.isfinite(value):
        raise DatasetError(f"{path}: row {row}, column {name!r}: {text!r} is not finite")
    if name in layout.tensions and value < TENSION_FLOOR_N:
        raise DatasetError(f"{path}: row {row}, column {name!r}: {text!r} {_NEGATIVE_TENSION}")
    return value


def write_dataset(folder: str | Path, rows: Iterable[Mapping[str, Any]], **meta) -> Dataset:
    """Write a whole dataset at once (for tests and synthetic data) and read it back."""
    with DatasetWriter(folder, sync=False, **meta) as writer:
        for row in rows:
            writer.write(row)
    return read_dataset(folder)
