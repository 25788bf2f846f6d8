"""The measurement dataset: one row per static measurement, plus a metadata file.

Format ``twin-dataset`` version 1 — a folder with

``measurements.csv``
    One row per static measurement, each written as one complete line (CRLF-terminated,
    one ``write``, then synced to disk), so a run that stops half-way keeps every sample taken
    (and can be resumed: :meth:`DatasetWriter.completed`). A row is complete only with its line
    end: a last line without one is a write that was cut off (a full disk, a crash) and is
    dropped on reading and on resuming, with a :class:`DatasetWarning` naming file and row.
    Columns (units in the names; empty cell = not measured):

    ==========================  ====================================================================
    config                      configuration number (int), unique per (κ, φ, tip mass, repeat)
    experiment                  ``validation`` / ``stiffness`` / ... (str)
    repeat                      repetition index (int)
    kappa_cmd_per_m             commanded PCC curvature (1/m)
    phi_cmd_deg                 commanded bending plane (deg)
    tip_mass_kg                 nominal mass hung at the tip (kg)
    tension_1_n … tension_4_n   calibrated tensions at the load cells (N)
    length_1_m … length_4_m     relative tendon lengths from the encoders (m, + = paid out)
    tip_x_m, tip_y_m, tip_z_m   tip position, base frame: origin at the base centre, world axes (m)
    tip_qw … tip_qz             tip orientation quaternion (w, x, y, z), world axes, when measured
    time_s                      device time of the measurement (s)
    ==========================  ====================================================================

``metadata.json``
    ``format``, ``version``, ``experiment``, ``created``, ``device`` (URL), ``base_rotation``
    (3×3, body → world), ``gravity_m_s2``, ``params`` (the full parameter set with sources),
    ``calibration`` (the load-cell calibration applied, or null), ``notes``.

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
import io
import json
import math
import os
import warnings
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from twin.params import Params, _from_dict, load_params

__all__ = [
    "FORMAT",
    "TENSION_FLOOR_N",
    "VERSION",
    "COLUMNS",
    "REQUIRED_COLUMNS",
    "DatasetError",
    "DatasetWarning",
    "Dataset",
    "DatasetWriter",
    "read_dataset",
    "read_metadata",
    "recorded_params",
    "write_atomic",
    "write_dataset",
]

FORMAT = "twin-dataset"
VERSION = 1
TENDONS = 4
MEASUREMENTS = "measurements.csv"
METADATA = "metadata.json"
# Where a ``twin validate`` run folder keeps its dataset.
RUN_DATASET = "dataset"

_INT_COLUMNS = ("config", "repeat")
_STR_COLUMNS = ("experiment",)
REQUIRED_COLUMNS = (
    ("config", "kappa_cmd_per_m", "phi_cmd_deg", "tip_mass_kg")
    + tuple(f"tension_{i}_n" for i in range(1, TENDONS + 1))
    + tuple(f"length_{i}_m" for i in range(1, TENDONS + 1))
    + ("tip_x_m", "tip_y_m", "tip_z_m")
)
OPTIONAL_COLUMNS = ("experiment", "repeat", "tip_qw", "tip_qx", "tip_qy", "tip_qz", "time_s")
COLUMNS = REQUIRED_COLUMNS[:1] + ("experiment", "repeat") + REQUIRED_COLUMNS[1:] + (
    "tip_qw", "tip_qx", "tip_qy", "tip_qz", "time_s")
# Columns that may be empty (not measured).
_NULLABLE = ("tip_qw", "tip_qx", "tip_qy", "tip_qz", "time_s")
_TENSION_COLUMNS = tuple(f"tension_{i}_n" for i in range(1, TENDONS + 1))
# Lowest tension (N) a row may report: a slack tendon reads its load cell's noise around zero
# (millinewtons); a reading further below is a wiring, sign or calibration fault, which a
# prediction must not quietly read as a slack tendon.
TENSION_FLOOR_N = -0.5


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
    def tensions_n(self) -> np.ndarray:
        """(rows, 4) calibrated tensions (N)."""
        return np.stack([self.columns[f"tension_{i}_n"] for i in range(1, TENDONS + 1)], axis=1)

    @property
    def lengths_m(self) -> np.ndarray:
        """(rows, 4) relative tendon lengths (m)."""
        return np.stack([self.columns[f"length_{i}_m"] for i in range(1, TENDONS + 1)], axis=1)

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
        return np.asarray(self.metadata["base_rotation"], dtype=float)

    @property
    def params(self) -> Params:
        """The parameter set recorded with the data (what the model believed at the time).

        Keys added to the parameter set after the data was recorded take today's defaults,
        marked as such in their source.
        """
        return recorded_params(self.metadata, origin=f"{self.path or 'dataset'} metadata params")

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


def _line(cells: Iterable[str]) -> str:
    """One CSV row as a complete line, quoted as csv.writer quotes it."""
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator=_LINE_END).writerow(cells)
    return buffer.getvalue()


def _metadata(*, experiment: str, device: str, params: Params, base_rotation, calibration=None,
              notes: str = "") -> dict:
    rot = np.asarray(base_rotation, dtype=float)
    return {
        "format": FORMAT,
        "version": VERSION,
        "experiment": experiment,
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "device": device,
        "base_rotation": rot.tolist(),
        "gravity_m_s2": params.environment.gravity_m_s2,
        "params": params.to_dict(),
        "calibration": calibration,
        "notes": notes,
        "columns": list(COLUMNS),
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
        sync: sync every row to disk (the default: a row is seconds of rig time); with False,
            rows are synced once, on :meth:`close` (bulk writes of synthetic data).

    Raises:
        DatasetError: the folder holds another experiment, a damaged dataset, or is being
            written by another writer.
        OSError: the folder or its files cannot be created or written.
    """

    def __init__(self, folder: str | Path, *, experiment: str, device: str, params: Params, base_rotation,
                 calibration: Mapping | None = None, notes: str = "", sync: bool = True):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.experiment = experiment
        self.path = self.folder / MEASUREMENTS
        self._sync = sync
        self._done: set[int] = set()
        if self.path.exists() and self.path.stat().st_size > 0:
            existing, complete_bytes = _read(self.folder)
            if existing.metadata.get("experiment") != experiment:
                raise DatasetError(f"{self.folder}: holds a {existing.metadata.get('experiment')!r} dataset; "
                                   f"cannot resume it as {experiment!r}")
            self._done = set(int(c) for c in existing["config"])
        else:
            meta = _metadata(experiment=experiment, device=device, params=params, base_rotation=base_rotation,
                             calibration=calibration, notes=notes)
            write_atomic(self.folder / METADATA, json.dumps(meta, indent=1))
            try:
                write_atomic(self.path, _line(COLUMNS))
            except OSError:
                # No half-made dataset: without its header the folder is plainly not a dataset yet.
                (self.folder / METADATA).unlink(missing_ok=True)
                raise
            complete_bytes = None
        self._fd = os.open(self.path, os.O_RDWR | os.O_APPEND)
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
        missing = [c for c in REQUIRED_COLUMNS if c not in row]
        if missing:
            raise DatasetError(f"row for config {config!r} lacks column(s) {missing}")
        unknown = set(row) - set(COLUMNS)
        if unknown:
            raise DatasetError(f"row for config {config!r} has unknown column(s) {sorted(unknown)}")
        values = dict(row)
        values.setdefault("experiment", self.experiment)
        values.setdefault("repeat", 0)
        cells = [self._cell(c, values.get(c), config) for c in COLUMNS]
        data = _line(cells).encode("utf-8")
        start = os.fstat(self._fd).st_size
        try:
            written = 0
            while written < len(data):
                written += os.write(self._fd, data[written:])
            if self._sync:
                os.fsync(self._fd)
        except OSError as exc:
            try:
                os.ftruncate(self._fd, start)
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
            if name in _NULLABLE:
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
        if name in _TENSION_COLUMNS and value < TENSION_FLOOR_N:
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
        metadata = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{meta_path}: not valid JSON: {exc}") from None
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT:
        found = metadata.get("format") if isinstance(metadata, dict) else type(metadata).__name__
        raise DatasetError(f"{meta_path}: format {found!r}, expected {FORMAT!r}")
    if metadata.get("version") != VERSION:
        raise DatasetError(f"{meta_path}: version {metadata.get('version')!r}; this reader reads version {VERSION}")
    for key in ("base_rotation", "params"):
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
        rot = np.asarray(metadata["base_rotation"], dtype=float)
    except (TypeError, ValueError):
        rot = np.zeros(0)
    if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6):
        raise DatasetError(f"{meta_path}: base_rotation {metadata['base_rotation']!r} is not a 3x3 rotation")
    return metadata


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


def _read(folder: str | Path) -> tuple[Dataset, int]:
    """The dataset and the length (bytes) of its ``measurements.csv`` up to the last complete row."""
    folder = _dataset_folder(folder)
    csv_path = folder / MEASUREMENTS
    metadata = read_metadata(folder)
    if not csv_path.exists():
        raise DatasetError(f"{csv_path}: missing (a twin dataset folder holds {MEASUREMENTS} and {METADATA})")
    data = csv_path.read_bytes()
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
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        raise DatasetError(f"{csv_path}: missing column(s) {missing}")
    index = {name: i for i, name in enumerate(header)}
    columns: dict[str, list] = {name: [] for name in header if name in COLUMNS}
    for r, line in enumerate(lines[1:], start=2):
        row = _fields(line, csv_path, r)
        if len(row) != len(header):
            raise DatasetError(f"{csv_path}: row {r} has {len(row)} fields, the header {len(header)}")
        for name in columns:
            columns[name].append(_parse(row[index[name]].strip(), name, csv_path, r))
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
    for name in _NULLABLE:
        out.setdefault(name, np.full(n, np.nan))
    return Dataset(out, metadata, folder), complete_bytes


def _fields(line: bytes, path: Path, row: int) -> list[str]:
    """The cells of one line of ``measurements.csv`` (its line end already split off)."""
    try:
        text = line.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: row {row}: byte {exc.start + 1} is not UTF-8 text") from None
    return next(csv.reader([text.rstrip("\r")]), [])


def _parse(text: str, name: str, path: Path, row: int):
    if name in _STR_COLUMNS:
        return text
    if text == "":
        if name in _NULLABLE:
            return math.nan
        raise DatasetError(f"{path}: row {row}, column {name!r} is empty")
    try:
        value = int(text) if name in _INT_COLUMNS else float(text)
    except ValueError:
        raise DatasetError(f"{path}: row {row}, column {name!r}: {text!r} is not a number") from None
    if isinstance(value, float) and not math.isfinite(value):
        raise DatasetError(f"{path}: row {row}, column {name!r}: {text!r} is not finite")
    if name in _TENSION_COLUMNS and value < TENSION_FLOOR_N:
        raise DatasetError(f"{path}: row {row}, column {name!r}: {text!r} {_NEGATIVE_TENSION}")
    return value


def write_dataset(folder: str | Path, rows: Iterable[Mapping[str, Any]], **meta) -> Dataset:
    """Write a whole dataset at once (for tests and synthetic data) and read it back."""
    with DatasetWriter(folder, sync=False, **meta) as writer:
        for row in rows:
            writer.write(row)
    return read_dataset(folder)
