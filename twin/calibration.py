"""Load-cell calibration: known masses, a line per channel, a file the host applies (thesis §4.3).

Each tendon runs over a ball-bearing pulley on a load cell read by an HX711 (thesis §4). A known
mass hung on the tendon sets its tension to m·g. The fit direction follows the thesis
(Fig. 9) and the statistics: the tension is known exactly and the counts are noisy, so each
channel is fitted as

    raw_counts = offset_counts + gain_counts_per_n · tension_n

by ordinary least squares, and the host applies the inverse,
``tension_n = (raw_counts − offset_counts) / gain_counts_per_n``. The gain is that of the
tendon tension, not of the force on the load cell: the pulley geometry is folded in.

Pieces: :func:`fit_channel` / :func:`fit_all` (line, residuals, standard errors, R²);
:class:`Calibration` (apply, save, load; the file keeps the averaged points so a later refit
can drop one); :func:`check` (a calibration against new known-mass readings);
:func:`run_calibration` (the guided procedure, written against two callables a device
provides).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from twin.checks import finite_vector

__all__ = [
    "CALIBRATION_FORMAT",
    "CALIBRATION_VERSION",
    "TABLE2_MASSES_G",
    "Calibration",
    "CalibrationFileError",
    "CalibrationRun",
    "ChannelCalibration",
    "ChannelFit",
    "CheckResult",
    "check",
    "fit_all",
    "fit_channel",
    "load_calibration",
    "run_calibration",
    "tensions_from_masses_n",
]

# Thesis Table 2: masses hung over the sensor pulley (0 … 2.45 N).
TABLE2_MASSES_G = (0.0, 5.0, 10.0, 20.0, 30.0, 50.0, 70.0, 100.0, 120.0, 150.0, 200.0, 250.0)
CALIBRATION_FORMAT = "twin.loadcell-calibration"
CALIBRATION_VERSION = 1


class CalibrationFileError(ValueError):
    """A calibration file is malformed; the message names the file, the field and the value."""


def tensions_from_masses_n(masses_g, gravity_m_s2: float) -> np.ndarray:
    """Tendon tension (N) of each hung mass (g) under gravity (m/s², ``environment.gravity_m_s2``):
    m·g, the pulley taken as frictionless."""
    return np.asarray(masses_g, dtype=float) * 1e-3 * gravity_m_s2


@dataclasses.dataclass(frozen=True, eq=False)
class ChannelFit:
    """Least-squares line of one channel, ``raw_counts = offset_counts + gain · tension_n``.

    Attributes:
        gain_counts_per_n: slope (counts/N).
        offset_counts: intercept, the unloaded reading (counts).
        gain_se_counts_per_n: standard error of the slope (counts/N).
        offset_se_counts: standard error of the intercept (counts).
        r_squared: coefficient of determination.
        tensions_n: (n,) known tensions fitted (N).
        residuals_counts: (n,) measured minus fitted counts.
    """

    gain_counts_per_n: float
    offset_counts: float
    gain_se_counts_per_n: float
    offset_se_counts: float
    r_squared: float
    tensions_n: np.ndarray
    residuals_counts: np.ndarray

    @property
    def residuals_n(self) -> np.ndarray:
        """Residuals expressed as tension (N): what the calibrated reading is off by."""
        return self.residuals_counts / self.gain_counts_per_n

    @property
    def rms_residual_n(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_n**2)))

    @property
    def max_residual_n(self) -> float:
        """Largest absolute residual (N)."""
        return float(np.max(np.abs(self.residuals_n)))


def fit_channel(raw_counts, tensions_n) -> ChannelFit:
    """Fit one channel's line through (known tension, raw reading) pairs.

    Args:
        raw_counts: (n,) raw readings (counts), e.g. the mean of several samples per mass.
        tensions_n: (n,) known tensions (N); at least two distinct values.

    Returns:
        The :class:`ChannelFit`. Standard errors come from the residual scatter with n − 2
        degrees of freedom, so at least three points are needed.

    Raises:
        ValueError: shapes differ, fewer than three points, non-finite values, a single
            tension, or no response to the load (zero slope).
    """
    y = np.asarray(raw_counts, dtype=float)
    x = np.asarray(tensions_n, dtype=float)
    if y.ndim != 1 or x.shape != y.shape:
        raise ValueError(f"raw_counts shape {y.shape} and tensions_n shape {x.shape}: expected equal (n,)")
    if y.size < 3:
        raise ValueError(f"raw_counts has {y.size} points: a line with uncertainties needs at least 3")
    for name, v in (("raw_counts", y), ("tensions_n", x)):
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{name} = {v.tolist()}: must be finite")
    n = y.size
    x_mean, y_mean = x.mean(), y.mean()
    sxx = float(np.sum((x - x_mean) ** 2))
    if sxx <= 0:
        raise ValueError(f"tensions_n = {x.tolist()}: needs at least two distinct tensions")
    gain = float(np.sum((x - x_mean) * (y - y_mean)) / sxx)
    if gain == 0:
        raise ValueError(f"raw_counts = {y.tolist()}: no response to the load (zero slope)")
    offset = float(y_mean - gain * x_mean)
    residuals = y - (offset + gain * x)
    ss_res = float(np.sum(residuals**2))
    ss_tot = float(np.sum((y - y_mean) ** 2))
    s2 = ss_res / (n - 2)
    return ChannelFit(
        gain_counts_per_n=gain,
        offset_counts=offset,
        gain_se_counts_per_n=math.sqrt(s2 / sxx),
        offset_se_counts=math.sqrt(s2 * (1.0 / n + x_mean**2 / sxx)),
        r_squared=1.0 - ss_res / ss_tot,
        tensions_n=x,
        residuals_counts=residuals,
    )


def fit_all(raw_counts, tensions_n) -> tuple[ChannelFit, ...]:
    """Fit every channel: ``raw_counts`` (n, channels) against ``tensions_n`` (n,)."""
    raw = np.asarray(raw_counts, dtype=float)
    if raw.ndim != 2:
        raise ValueError(f"raw_counts shape {raw.shape}: expected (n, channels)")
    return tuple(fit_channel(raw[:, c], tensions_n) for c in range(raw.shape[1]))


@dataclasses.dataclass(frozen=True)
class ChannelCalibration:
    """One channel as stored in the file: its line and the quality of its fit.

    Attributes:
        gain_counts_per_n: slope (counts/N); non-zero (its sign follows the wiring).
        offset_counts: reading at zero tension (counts).
        gain_se_counts_per_n, offset_se_counts: standard errors of the fit.
        r_squared: coefficient of determination of the fit.
        rms_residual_n, max_residual_n: RMS and largest absolute residual (N).
    """

    gain_counts_per_n: float
    offset_counts: float
    gain_se_counts_per_n: float
    offset_se_counts: float
    r_squared: float
    rms_residual_n: float
    max_residual_n: float

    @classmethod
    def from_fit(cls, fit: ChannelFit) -> "ChannelCalibration":
        return cls(
            fit.gain_counts_per_n,
            fit.offset_counts,
            fit.gain_se_counts_per_n,
            fit.offset_se_counts,
            fit.r_squared,
            fit.rms_residual_n,
            fit.max_residual_n,
        )


@dataclasses.dataclass(frozen=True)
class Calibration:
    """Per-channel gain and offset that turn raw load-cell counts into tendon tension.

    Attributes:
        channels: one :class:`ChannelCalibration` per load cell, in channel order.
        masses_g: the hung masses used (g).
        raw_counts: per mass, the averaged reading of each channel (counts), shape
            (len(masses_g), len(channels)); kept so a later refit can drop a point.
        gravity_m_s2: g used to turn masses into tensions (m/s²).
        samples_per_mass: samples averaged for each reading.
        device: the device URL the run was taken on.
        date: when it was taken, ISO 8601.
    """

    channels: tuple[ChannelCalibration, ...]
    masses_g: tuple[float, ...]
    raw_counts: tuple[tuple[float, ...], ...]
    gravity_m_s2: float
    samples_per_mass: int = 1
    device: str = ""
    date: str = ""

    @classmethod
    def from_fits(
        cls,
        fits: Sequence[ChannelFit],
        raw_counts,
        *,
        masses_g: Sequence[float],
        gravity_m_s2: float,
        samples_per_mass: int = 1,
        device: str = "",
        date: str | None = None,
    ) -> "Calibration":
        """A calibration from :func:`fit_all` output; ``date`` defaults to now (UTC)."""
        data = {
            "format": CALIBRATION_FORMAT,
            "version": CALIBRATION_VERSION,
            "date": date or datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "device": device,
            "gravity_m_s2": gravity_m_s2,
            "samples_per_mass": samples_per_mass,
            "masses_g": [float(m) for m in masses_g],
            "raw_counts": np.asarray(raw_counts, dtype=float).tolist(),
            "channels": [dataclasses.asdict(ChannelCalibration.from_fit(f)) for f in fits],
        }
        # Going through the file validator gives one set of checks for built and loaded objects.
        return cls.from_dict(data, origin="Calibration.from_fits()")

    @property
    def gain_counts_per_n(self) -> np.ndarray:
        """(channels,) gains (counts/N)."""
        return np.array([c.gain_counts_per_n for c in self.channels])

    @property
    def offset_counts(self) -> np.ndarray:
        """(channels,) offsets (counts)."""
        return np.array([c.offset_counts for c in self.channels])

    @property
    def tensions_n(self) -> np.ndarray:
        """(len(masses_g),) the known tensions of the calibration points (N)."""
        return tensions_from_masses_n(self.masses_g, self.gravity_m_s2)

    def to_newtons(self, raw_counts) -> np.ndarray:
        """Tendon tension (N) of raw readings (counts) of shape (..., channels)."""
        raw = np.asarray(raw_counts, dtype=float)
        if raw.ndim == 0 or raw.shape[-1] != len(self.channels):
            raise ValueError(
                f"raw_counts shape {raw.shape}: last axis must be the {len(self.channels)} channels"
            )
        return (raw - self.offset_counts) / self.gain_counts_per_n

    def to_dict(self) -> dict[str, Any]:
        """The file's content: format tag and version first, then metadata and channels."""
        return {
            "format": CALIBRATION_FORMAT,
            "version": CALIBRATION_VERSION,
            "date": self.date,
            "device": self.device,
            "gravity_m_s2": self.gravity_m_s2,
            "samples_per_mass": self.samples_per_mass,
            "masses_g": list(self.masses_g),
            "raw_counts": [list(row) for row in self.raw_counts],
            "channels": [dataclasses.asdict(c) for c in self.channels],
        }

    def save(self, path: str | Path) -> Path:
        """Write the calibration as JSON to ``path``."""
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return path

    @classmethod
    def from_dict(cls, data: Any, origin: str = "calibration") -> "Calibration":
        """Validate and build from the file's content; refuses anything malformed.

        Raises:
            CalibrationFileError: naming ``origin``, the field and its value.
        """
        return _parse(data, origin)


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration file written by :meth:`Calibration.save`.

    Raises:
        CalibrationFileError: the file is not JSON or a field is missing or malformed.
    """
    from twin.inputs import CALIBRATION_MAX_BYTES, InputFileError, read_input

    path = Path(path)
    try:
        data = json.loads(read_input(path, max_bytes=CALIBRATION_MAX_BYTES).decode("utf-8"))
    except InputFileError as exc:
        raise CalibrationFileError(f"{exc}; a calibration file was expected") from None
    except UnicodeDecodeError as exc:
        raise CalibrationFileError(f"{path}: not a calibration file (byte {exc.start + 1} is not UTF-8 text; "
                                   "is it a binary file?)") from None
    except json.JSONDecodeError as exc:
        raise CalibrationFileError(f"{path}: not valid JSON ({exc})") from None
    return _parse(data, str(path))


_TOP_FIELDS = ("format", "version", "date", "device", "gravity_m_s2", "samples_per_mass",
               "masses_g", "raw_counts", "channels")
_CHANNEL_FIELDS = tuple(f.name for f in dataclasses.fields(ChannelCalibration))


def _number(origin: str, field: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CalibrationFileError(f"{origin}: {field} = {value!r}: must be a finite number")
    return float(value)


def _mapping(origin: str, field: str, value: Any, fields: Sequence[str]) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise CalibrationFileError(f"{origin}: {field} = {value!r}: must be an object")
    missing = [k for k in fields if k not in value]
    if missing:
        raise CalibrationFileError(f"{origin}: {field} is missing field(s) {', '.join(missing)}")
    unknown = sorted(set(value) - set(fields))
    if unknown:
        raise CalibrationFileError(f"{origin}: {field} has unknown field(s) {', '.join(unknown)}")
    return value


def _parse(data: Any, origin: str) -> Calibration:
    d = _mapping(origin, "the file", data, _TOP_FIELDS)
    if d["format"] != CALIBRATION_FORMAT:
        raise CalibrationFileError(f"{origin}: format = {d['format']!r}: expected {CALIBRATION_FORMAT!r}")
    if d["version"] != CALIBRATION_VERSION:
        raise CalibrationFileError(f"{origin}: version = {d['version']!r}: this reader knows {CALIBRATION_VERSION}")
    for field in ("date", "device"):
        if not isinstance(d[field], str):
            raise CalibrationFileError(f"{origin}: {field} = {d[field]!r}: must be a string")
    try:
        datetime.datetime.fromisoformat(d["date"])
    except ValueError:
        raise CalibrationFileError(f"{origin}: date = {d['date']!r}: must be an ISO 8601 date") from None
    gravity = _number(origin, "gravity_m_s2", d["gravity_m_s2"])
    if gravity <= 0:
        raise CalibrationFileError(f"{origin}: gravity_m_s2 = {gravity!r}: must be > 0")
    samples = d["samples_per_mass"]
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise CalibrationFileError(f"{origin}: samples_per_mass = {samples!r}: must be a whole number >= 1")
    if not isinstance(d["masses_g"], list) or len(d["masses_g"]) < 3:
        raise CalibrationFileError(f"{origin}: masses_g = {d['masses_g']!r}: must be a list of at least 3 masses")
    masses = tuple(_number(origin, f"masses_g[{i}]", m) for i, m in enumerate(d["masses_g"]))
    for i, m in enumerate(masses):
        if m < 0:
            raise CalibrationFileError(f"{origin}: masses_g[{i}] = {m!r}: must be >= 0")
    if not isinstance(d["channels"], list) or not d["channels"]:
        raise CalibrationFileError(f"{origin}: channels = {d['channels']!r}: must be a non-empty list")
    channels = []
    for i, entry in enumerate(d["channels"]):
        c = _mapping(origin, f"channels[{i}]", entry, _CHANNEL_FIELDS)
        values = {k: _number(origin, f"channels[{i}].{k}", c[k]) for k in _CHANNEL_FIELDS}
        if values["gain_counts_per_n"] == 0:
            raise CalibrationFileError(f"{origin}: channels[{i}].gain_counts_per_n = 0.0: must be non-zero")
        channels.append(ChannelCalibration(**values))
    raw = d["raw_counts"]
    if not isinstance(raw, list) or len(raw) != len(masses):
        raise CalibrationFileError(
            f"{origin}: raw_counts = {raw!r}: must be a list of {len(masses)} rows, one per mass"
        )
    rows = []
    for i, row in enumerate(raw):
        if not isinstance(row, list) or len(row) != len(channels):
            raise CalibrationFileError(
                f"{origin}: raw_counts[{i}] = {row!r}: must list {len(channels)} readings, one per channel"
            )
        rows.append(tuple(_number(origin, f"raw_counts[{i}][{j}]", v) for j, v in enumerate(row)))
    return Calibration(
        channels=tuple(channels),
        masses_g=masses,
        raw_counts=tuple(rows),
        gravity_m_s2=gravity,
        samples_per_mass=samples,
        device=d["device"],
        date=d["date"],
    )


@dataclasses.dataclass(frozen=True, eq=False)
class CheckResult:
    """A calibration checked against known tensions.

    Attributes:
        errors_n: (n, channels) calibrated minus known tension (N).
        tolerance_n: largest accepted absolute error (N).
    """

    errors_n: np.ndarray
    tolerance_n: float

    @property
    def max_abs_error_n(self) -> np.ndarray:
        """(channels,) largest absolute error per channel (N)."""
        return np.max(np.abs(self.errors_n), axis=0)

    @property
    def channel_passed(self) -> np.ndarray:
        """(channels,) True where every error is within the tolerance."""
        return self.max_abs_error_n <= self.tolerance_n

    @property
    def passed(self) -> bool:
        return bool(np.all(self.channel_passed))


def check(calibration: Calibration, raw_counts, tensions_n, *, tolerance_n: float = 0.02) -> CheckResult:
    """Check a calibration against new readings at known tensions (thesis §4.3 validation).

    Args:
        calibration: the calibration under test.
        raw_counts: (n, channels) readings (counts) with known loads hung.
        tensions_n: (n,) the known tensions (N), e.g. :func:`tensions_from_masses_n`.
        tolerance_n: largest accepted error (N). The default, 0.02 N (2 g), is an assumption:
            four times the load cells' 0.005 N noise, well under the 1.2 N pretension.

    Returns:
        A :class:`CheckResult`: per-point errors and pass/fail per channel and overall.
    """
    if not (math.isfinite(tolerance_n) and tolerance_n > 0):
        raise ValueError(f"tolerance_n = {tolerance_n!r}: must be finite and > 0")
    raw = np.asarray(raw_counts, dtype=float)
    known = np.asarray(tensions_n, dtype=float)
    if raw.ndim != 2 or known.shape != (raw.shape[0],):
        raise ValueError(f"raw_counts shape {raw.shape}, tensions_n shape {known.shape}: expected (n, channels), (n,)")
    return CheckResult(calibration.to_newtons(raw) - known[:, None], tolerance_n)


@dataclasses.dataclass(frozen=True, eq=False)
class CalibrationRun:
    """What a guided run measured and the calibration it produced.

    Attributes:
        tensions_n: (n,) known tension of each mass (N).
        raw_counts: (n, channels) mean reading per mass (counts).
        raw_std_counts: (n, channels) sample standard deviation per mass (counts); a large
            one flags a swinging mass or a loose tendon.
        fits: per-channel :class:`ChannelFit`, with residuals.
        calibration: the resulting :class:`Calibration`.
    """

    tensions_n: np.ndarray
    raw_counts: np.ndarray
    raw_std_counts: np.ndarray
    fits: tuple[ChannelFit, ...]
    calibration: Calibration


def run_calibration(
    read_raw_counts: Callable[[], Any],
    hang_mass: Callable[[float, tuple[int, ...]], None],
    *,
    masses_g: Sequence[float] = TABLE2_MASSES_G,
    samples_per_mass: int = 20,
    channels: int = 4,
    one_at_a_time: bool = False,
    gravity_m_s2: float,
    device: str = "",
) -> CalibrationRun:
    """The thesis's calibration procedure as a guided run on a device.

    The device layer provides two callables (the protocol of this function):

    - ``hang_mass(mass_g, channels)`` asks for ``mass_g`` (g, 0 = nothing) to hang on the
      tendon over each load cell in ``channels`` and returns once it hangs still: on the rig
      an operator prompt, on the twin a hook that sets the load.
    - ``read_raw_counts()`` returns the next raw sample of all load cells, shape
      (channels,), in counts; it blocks until a new sample exists (80 Hz on the HX711).

    Args:
        read_raw_counts: next raw sample of every channel (counts).
        hang_mass: places a mass on the listed channels, returns when it is settled.
        masses_g: the masses to hang (g); default thesis Table 2.
        samples_per_mass: samples averaged per mass.
        channels: number of load cells.
        one_at_a_time: hang each mass on one channel at a time (one set of masses, four
            times the prompts) rather than on all channels at once.
        gravity_m_s2: g to turn masses into tensions.
        device: the device URL, recorded in the calibration.

    Returns:
        A :class:`CalibrationRun` with the averaged readings, the fits and the calibration.

    Raises:
        ValueError: bad arguments, or a reading of the wrong shape or not finite.
    """
    masses = [float(m) for m in masses_g]
    if samples_per_mass < 1:
        raise ValueError(f"samples_per_mass = {samples_per_mass!r}: must be >= 1")
    if channels < 1:
        raise ValueError(f"channels = {channels!r}: must be >= 1")

    def read() -> np.ndarray:
        return finite_vector("read_raw_counts()", read_raw_counts(), channels, what="counts")

    means = np.empty((len(masses), channels))
    stds = np.empty((len(masses), channels))
    groups = [(c,) for c in range(channels)] if one_at_a_time else [tuple(range(channels))]
    for group in groups:
        for i, mass_g in enumerate(masses):
            hang_mass(mass_g, group)
            block = np.array([read() for _ in range(samples_per_mass)])[:, list(group)]
            means[i, list(group)] = block.mean(axis=0)
            # ddof=1 needs two samples; a single sample has no scatter to report.
            stds[i, list(group)] = block.std(axis=0, ddof=1) if samples_per_mass > 1 else 0.0
    tensions = tensions_from_masses_n(masses, gravity_m_s2)
    fits = fit_all(means, tensions)
    calibration = Calibration.from_fits(
        fits,
        means,
        masses_g=masses,
        gravity_m_s2=gravity_m_s2,
        samples_per_mass=samples_per_mass,
        device=device,
    )
    return CalibrationRun(tensions, means, stds, fits, calibration)
