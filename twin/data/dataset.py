"""The measurement dataset: one row per static measurement, plus a metadata file.

Format ``twin-dataset`` version 1 — a folder with

``measurements.csv``
    One row per static measurement, written and flushed row by row, so a run that stops
    half-way keeps every sample taken (and can be resumed: :meth:`DatasetWriter.completed`).
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

Readers refuse files with missing or malformed columns with a message naming the file,
the row and the column.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import json
import math
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from twin.params import Params, _from_dict, load_params

__all__ = [
    "FORMAT",
    "VERSION",
    "COLUMNS",
    "REQUIRED_COLUMNS",
    "DatasetError",
    "Dataset",
    "DatasetWriter",
    "read_dataset",
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


class DatasetError(ValueError):
    """A dataset file is missing, of another format, or has missing or malformed columns."""


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
        merged = load_params().to_dict()
        for section, entries in merged.items():
            for key, entry in entries.items():
                entry["source"] = f"default (not recorded with the data): {entry['source']}"
        for section, entries in self.metadata["params"].items():
            merged.setdefault(section, {}).update(entries)
        return _from_dict(merged, origin=f"{self.path or 'dataset'} metadata params")

    def subset(self, mask: np.ndarray) -> "Dataset":
        """The rows where ``mask`` is true (same metadata)."""
        mask = np.asarray(mask)
        return Dataset({k: v[mask] for k, v in self.columns.items()}, self.metadata, self.path)


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
    """Writes a dataset row by row (flushed each time), resuming a folder that already has rows.

    Example:
        >>> with DatasetWriter(folder, experiment="validation", device="sim://", params=p,
        ...                    base_rotation=HORIZONTAL) as w:
        ...     if 7 not in w.completed():
        ...         w.write({"config": 7, ...})
    """

    def __init__(self, folder: str | Path, *, experiment: str, device: str, params: Params, base_rotation,
                 calibration: Mapping | None = None, notes: str = ""):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        meta_path = self.folder / METADATA
        csv_path = self.folder / MEASUREMENTS
        self._done: set[int] = set()
        if csv_path.exists() and csv_path.stat().st_size > 0:
            existing = read_dataset(self.folder)
            if existing.metadata.get("experiment") != experiment:
                raise DatasetError(f"{self.folder}: holds a {existing.metadata.get('experiment')!r} dataset; "
                                   f"cannot resume it as {experiment!r}")
            self._done = set(int(c) for c in existing["config"])
        else:
            meta = _metadata(experiment=experiment, device=device, params=params, base_rotation=base_rotation,
                             calibration=calibration, notes=notes)
            meta_path.write_text(json.dumps(meta, indent=1))
            with open(csv_path, "w", newline="") as fh:
                csv.writer(fh).writerow(COLUMNS)
        self.experiment = experiment
        self._fh = open(csv_path, "a", newline="")
        self._csv = csv.writer(self._fh)

    def completed(self) -> set[int]:
        """Configuration numbers already written (to skip on resume)."""
        return set(self._done)

    def write(self, row: Mapping[str, Any]) -> None:
        """Append one measurement (flushed to disk at once). Missing optional values are left empty."""
        missing = [c for c in REQUIRED_COLUMNS if c not in row]
        if missing:
            raise DatasetError(f"row for config {row.get('config')!r} lacks column(s) {missing}")
        unknown = set(row) - set(COLUMNS)
        if unknown:
            raise DatasetError(f"row for config {row.get('config')!r} has unknown column(s) {sorted(unknown)}")
        values = dict(row)
        values.setdefault("experiment", self.experiment)
        values.setdefault("repeat", 0)
        out = []
        for c in COLUMNS:
            v = values.get(c)
            if v is None or (isinstance(v, float) and math.isnan(v)):
                out.append("")
            elif isinstance(v, (float, np.floating)):
                out.append(repr(float(v)))
            else:
                out.append(str(v))
        self._csv.writerow(out)
        self._fh.flush()
        self._done.add(int(values["config"]))

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> "DatasetWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_dataset(folder: str | Path) -> Dataset:
    """Read and check a dataset folder (or a path to its ``measurements.csv``, or the run
    folder of ``twin validate``, which keeps its dataset in ``dataset/``).

    Raises:
        DatasetError: missing files, wrong format/version, missing or malformed columns
            (the message names the file, row and column).
    """
    folder = Path(folder)
    if folder.is_file():
        folder = folder.parent
    if not (folder / METADATA).exists() and (folder / RUN_DATASET / METADATA).exists():
        folder = folder / RUN_DATASET
    meta_path, csv_path = folder / METADATA, folder / MEASUREMENTS
    for path in (meta_path, csv_path):
        if not path.exists():
            raise DatasetError(f"{path}: missing (a twin dataset folder holds {MEASUREMENTS} and {METADATA})")
    try:
        metadata = json.loads(meta_path.read_text())
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{meta_path}: not valid JSON: {exc}") from None
    if metadata.get("format") != FORMAT:
        raise DatasetError(f"{meta_path}: format {metadata.get('format')!r}, expected {FORMAT!r}")
    if metadata.get("version") != VERSION:
        raise DatasetError(f"{meta_path}: version {metadata.get('version')!r}; this reader reads version {VERSION}")
    for key in ("base_rotation", "params"):
        if key not in metadata:
            raise DatasetError(f"{meta_path}: missing {key!r}")
    rot = np.asarray(metadata["base_rotation"], dtype=float)
    if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6):
        raise DatasetError(f"{meta_path}: base_rotation {metadata['base_rotation']!r} is not a 3x3 rotation")
    with open(csv_path, newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration:
            raise DatasetError(f"{csv_path}: empty file (no header)") from None
        missing = [c for c in REQUIRED_COLUMNS if c not in header]
        if missing:
            raise DatasetError(f"{csv_path}: missing column(s) {missing}")
        rows = list(reader)
    index = {name: i for i, name in enumerate(header)}
    columns: dict[str, list] = {name: [] for name in header if name in COLUMNS}
    for r, row in enumerate(rows, start=2):
        if len(row) != len(header):
            raise DatasetError(f"{csv_path}: row {r} has {len(row)} fields, the header {len(header)}")
        for name in columns:
            text = row[index[name]].strip()
            columns[name].append(_parse(text, name, csv_path, r))
    out: dict[str, np.ndarray] = {}
    for name, values in columns.items():
        if name in _INT_COLUMNS:
            out[name] = np.array(values, dtype=int)
        elif name in _STR_COLUMNS:
            out[name] = np.array(values, dtype=str)
        else:
            out[name] = np.array(values, dtype=float)
    n = len(rows)
    out.setdefault("repeat", np.zeros(n, dtype=int))
    out.setdefault("experiment", np.array([metadata.get("experiment", "")] * n, dtype=str))
    for name in _NULLABLE:
        out.setdefault(name, np.full(n, np.nan))
    return Dataset(out, metadata, folder)


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
    return value


def write_dataset(folder: str | Path, rows: Iterable[Mapping[str, Any]], **meta) -> Dataset:
    """Write a whole dataset at once (for tests and synthetic data) and read it back."""
    with DatasetWriter(folder, **meta) as writer:
        for row in rows:
            writer.write(row)
    return read_dataset(folder)
