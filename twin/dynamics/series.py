"""The dynamic dataset on disk: a folder of time series, one pair of CSV files per experiment.

The format is documented for labs in ``docs/dynamic-dataset.md``. Every file is written whole
(:func:`twin.data.dataset.write_atomic`: a temporary file synced and renamed), so a crash or a
full disk leaves each file either complete or absent: an experiment is in the dataset when both
its files are, and ``metadata.json``'s ``completed`` list (rewritten after each experiment)
names those written so far.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import io
import json
import math
from pathlib import Path

import numpy as np

from twin.data.dataset import DatasetError, recorded_params, recorded_rotation, write_atomic
from twin.dynamics.protocols import Command, Experiment, Series
from twin.params import ParameterError, Params

__all__ = ["DYNAMICS_FOLDER", "FORMAT", "VERSION", "DynamicRun", "SeriesWriter", "read_run"]

FORMAT = "twin-dynamics"
VERSION = 1
# The dataset's folder inside a run folder of ``twin dynamics record``.
DYNAMICS_FOLDER = "dynamics"
METADATA = "metadata.json"
_UNITS = {"tensions": "n", "lengths": "m"}


def _csv(header: list[str], rows) -> str:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow(["" if isinstance(v, float) and math.isnan(v) else repr(float(v)) for v in row])
    return buffer.getvalue()


def _telemetry_header(n: int) -> list[str]:
    return (["time_s"] + [f"length_{i + 1}_m" for i in range(n)] + [f"tension_{i + 1}_n" for i in range(n)]
            + ["tip_x_m", "tip_y_m", "tip_z_m", "tip_qw", "tip_qx", "tip_qy", "tip_qz"])


def _command_header(mode: str, n: int) -> list[str]:
    quantity = "tension" if mode == "tensions" else "length"
    return ["time_s", "sent_s"] + [f"{quantity}_{i + 1}_{_UNITS[mode]}" for i in range(n)]


class SeriesWriter:
    """Writes a dynamic dataset experiment by experiment.

    Args:
        folder: the dataset folder (created; it must not hold a dynamic dataset yet).
        params: the parameter set the experiments are sized from and the twin is built with.
        device: the device URL.
        base_rotation: the device's pose (3×3, body → world).
        calibration: the load-cell calibration the device applies.
        seed: the twin's noise seed on ``sim://`` (None on a rig).
        robot: ``--robot``'s name, if given.
        planned: the experiments' names in the order they run.

    Raises:
        DatasetError: the folder already holds a dynamic dataset.
        OSError: the folder or a file cannot be written.
    """

    def __init__(self, folder: str | Path, *, params: Params, device: str, base_rotation, calibration: dict | None,
                 seed: int | None, robot: str | None, planned: list[str], quick: bool):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        if (self.folder / METADATA).exists():
            raise DatasetError(f"{self.folder}: already holds a dynamic dataset; record into a new run folder")
        self._n = params.tendons.count
        self.metadata = {
            "format": FORMAT, "version": VERSION,
            "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "device": device, "robot": {"name": robot}, "tendons": self._n,
            "base_rotation": np.asarray(base_rotation, dtype=float).tolist(), "seed": seed, "quick": quick,
            "calibration": calibration, "params": params.to_dict(), "planned": list(planned), "experiments": [],
        }
        self._write_metadata()

    @classmethod
    def resume(cls, folder: str | Path) -> "SeriesWriter":
        """A writer that goes on appending to the dynamic dataset in ``folder``: the experiments its
        metadata lists stay; files of one written but not yet listed are overwritten.

        Raises:
            DatasetError: no readable dataset metadata in ``folder``.
        """
        self = cls.__new__(cls)
        self.folder = Path(folder)
        try:
            self.metadata = json.loads((self.folder / METADATA).read_text())
            self._n = int(self.metadata["tendons"])
            self.metadata["experiments"] = list(self.metadata["experiments"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise DatasetError(f"{self.folder / METADATA}: cannot be resumed ({exc})") from None
        return self

    def _write_metadata(self) -> None:
        write_atomic(self.folder / METADATA, json.dumps(self.metadata, indent=1))

    def write(self, series: Series) -> None:
        """Write one experiment's commands and telemetry, then list it in the metadata."""
        e = series.experiment
        commands = [(c.time_s, sent, *c.values) for c, sent in zip(e.commands, series.sent_s)]
        write_atomic(self.folder / f"{e.name}.commands.csv", _csv(_command_header(e.mode, self._n), commands))
        telemetry = np.column_stack([series.time_s, series.lengths_m, series.tensions_n, series.tip_m, series.tip_quat])
        write_atomic(self.folder / f"{e.name}.telemetry.csv", _csv(_telemetry_header(self._n), telemetry))
        self.metadata["experiments"].append({"name": e.name, "mode": e.mode, "duration_s": e.duration_s,
                                             "commands": len(e.commands), "samples": int(series.time_s.size)})
        self._write_metadata()


@dataclasses.dataclass
class DynamicRun:
    """A dynamic dataset read back.

    Attributes:
        folder: the dataset folder.
        metadata: ``metadata.json``.
        series: each complete experiment, in recorded order.
    """

    folder: Path
    metadata: dict
    series: list[Series]

    @property
    def params(self) -> Params:
        """The parameter set recorded with the data."""
        return recorded_params(self.metadata, origin=f"{self.folder / METADATA} params")

    @property
    def base_rotation(self) -> np.ndarray:
        """The pose the data were taken in (3×3, body → world)."""
        return recorded_rotation(self.metadata["base_rotation"])

    def named(self, names) -> list[Series]:
        """The series of the experiments named, in recorded order."""
        return [s for s in self.series if s.experiment.name in set(names)]


def _read_csv(path: Path, header: list[str]) -> np.ndarray:
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise DatasetError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if not rows or rows[0] != header:
        raise DatasetError(f"{path}: expected the header {','.join(header)}")
    try:
        return np.array([[float(v) if v != "" else math.nan for v in row] for row in rows[1:]],
                        dtype=float).reshape(-1, len(header))
    except ValueError as exc:
        raise DatasetError(f"{path}: a value is not a number ({exc})") from None


def read_run(folder: str | Path) -> DynamicRun:
    """Read a dynamic dataset: its folder, or the run folder of ``twin dynamics record``.

    Raises:
        DatasetError: no dynamic dataset there, another format or version, a damaged file.
    """
    folder = Path(folder)
    if not (folder / METADATA).exists() and (folder / DYNAMICS_FOLDER / METADATA).exists():
        folder = folder / DYNAMICS_FOLDER
    path = folder / METADATA
    try:
        metadata = json.loads(path.read_text())
    except FileNotFoundError:
        raise DatasetError(f"{folder}: not a dynamic dataset (no {METADATA}, nor {DYNAMICS_FOLDER}/{METADATA})") from None
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: unreadable ({exc})") from None
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT or metadata.get("version") != VERSION:
        raise DatasetError(f"{path}: not a {FORMAT} version {VERSION} dataset")
    try:
        recorded_rotation(metadata.get("base_rotation"))
    except ValueError as exc:
        raise DatasetError(f"{path}: base_rotation {metadata.get('base_rotation')!r} is not a 3x3 rotation or a "
                           f"unit quaternion (w, x, y, z): {exc}") from None
    n = int(metadata["tendons"])
    series = []
    for entry in metadata["experiments"]:
        name, mode = entry["name"], entry["mode"]
        commands = _read_csv(folder / f"{name}.commands.csv", _command_header(mode, n))
        telemetry = _read_csv(folder / f"{name}.telemetry.csv", _telemetry_header(n))
        experiment = Experiment(name, mode, tuple(Command(float(r[0]), tuple(float(v) for v in r[2:]))
                                                  for r in commands), float(entry["duration_s"]))
        series.append(Series(experiment, commands[:, 1], telemetry[:, 0], telemetry[:, 1:1 + n],
                             telemetry[:, 1 + n:1 + 2 * n], telemetry[:, 1 + 2 * n:4 + 2 * n], telemetry[:, 4 + 2 * n:]))
    if not series:
        raise DatasetError(f"{folder}: the dynamic dataset holds no complete experiment")
    run = DynamicRun(folder, metadata, series)
    try:
        run.params
    except ParameterError as exc:
        raise DatasetError(f"{path}: its parameter set does not load today ({exc})") from None
    return run
