"""How large the residuals of a perfect model would be: the measurement noise of a dataset.

Three estimates, the first that applies:

``repeats``
    Configurations measured more than once (same κ, φ and tip mass): the pooled scatter of the
    residuals within each configuration, per axis. Residuals rather than raw positions, so a
    repeat that settled under slightly different tensions is not counted as noise.
``frames``
    Rows that record their tip's standard error (``tip_sem_x_m`` …: the scatter of the tracker
    frames averaged into the row, over √frames; ``docs/dataset.md``): its mean square per axis,
    plus the load-cell noise carried through the model as for the prior, over √frames too (the
    telemetry is averaged over the same window). The noise a row's mean really carries, not a
    single frame's.
``prior``
    The stated tracker noise ``sensors.tracker_noise_m`` per axis, plus the load-cell noise
    ``sensors.loadcell_noise_n`` carried through the model to the tip (each channel's
    sensitivity by a finite difference, every row), added in quadrature: the noise of one frame,
    an upper bound for a row that averages several.

Neither sees systematic errors that repeat with the configuration; those are what the
discrepancy workflow is looking for.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from twin.data.dataset import Dataset
from twin.data.prediction import predict_rows
from twin.params import Params

__all__ = ["NoiseEstimate", "estimate_noise", "configuration_keys"]

# Fewest configurations with repeats that make a pooled estimate worth more than the prior.
_MIN_REPEATED_CONFIGS = 5
# Share of rows that must record their tip's standard error for the ``frames`` estimate: a
# dataset resumed from an older file may have a few rows without it.
_MIN_FRAME_SHARE = 0.5
# Tension step of the sensitivity difference (N): well above rounding, well inside linearity.
_TENSION_STEP_N = 0.05


@dataclasses.dataclass(frozen=True)
class NoiseEstimate:
    """Per-axis noise of the measured tip positions.

    Attributes:
        sigma_m: (3,) standard deviation per axis (m).
        source: ``repeats``, ``frames`` or ``prior``.
        detail: how it was obtained, one sentence.
    """

    sigma_m: np.ndarray
    source: str
    detail: str

    @property
    def rms_3d_m(self) -> float:
        """Expected RMS of |p̂ − p*| for a perfect model (m)."""
        return float(np.sqrt(np.sum(self.sigma_m**2)))

    def to_dict(self) -> dict:
        return {"sigma_m": self.sigma_m.tolist(), "rms_3d_m": self.rms_3d_m, "source": self.source,
                "detail": self.detail}


def configuration_keys(dataset: Dataset) -> np.ndarray:
    """(rows,) integer label per configuration: rows of one experiment with equal κ, φ and tip
    mass share one. The same setpoints in another experiment (a deciding experiment approaches
    them from the other side, or at another pretension) are another configuration, not a repeat.
    A free pose (no command: :attr:`~twin.data.dataset.Dataset.free`) is its config number's: rows
    of one config number are repeats of one pose."""
    free = dataset.free
    kappa = np.where(free, -1.0 - np.asarray(dataset["config"], dtype=float), dataset["kappa_cmd_per_m"])
    table = np.stack([kappa, np.where(free, 0.0, dataset["phi_cmd_deg"]), dataset["tip_mass_kg"]], axis=1)
    _, experiment = np.unique(np.asarray(dataset["experiment"]), return_inverse=True)
    table = np.concatenate([np.round(table, 9), experiment.reshape(-1, 1)], axis=1)
    _, labels = np.unique(table, axis=0, return_inverse=True)
    return labels.reshape(-1)


def estimate_noise(dataset: Dataset, params: Params, errors_m: np.ndarray, converged: np.ndarray) -> NoiseEstimate:
    """Estimate the noise from repeated configurations if there are enough, else from the
    frames each row averaged if recorded, else from the prior (module doc).

    Args:
        dataset: the measurements.
        params: the parameter set (its sensor noise is the prior; its model carries load-cell noise).
        errors_m: (rows, 3) predicted − measured (m).
        converged: (rows,) which predictions exist.
    """
    labels = configuration_keys(dataset)
    ok = np.asarray(converged, dtype=bool)
    sums, dof, groups = np.zeros(3), 0, 0
    for label in np.unique(labels[ok]):
        members = errors_m[(labels == label) & ok]
        if len(members) > 1:
            sums += np.sum((members - members.mean(axis=0)) ** 2, axis=0)
            dof += len(members) - 1
            groups += 1
    if groups >= _MIN_REPEATED_CONFIGS:
        return NoiseEstimate(np.sqrt(sums / dof), "repeats",
                             f"pooled residual scatter within {groups} repeated configurations ({dof} degrees of freedom)")
    sigma_t = params.sensors.tracker_noise_m
    sigma_l = params.sensors.loadcell_noise_n
    sem = np.stack([np.asarray(dataset[f"tip_sem_{a}_m"], dtype=float) for a in "xyz"], axis=1)
    frames = np.asarray(dataset["tip_frames"], dtype=float)
    recorded = ok & np.all(np.isfinite(sem), axis=1) & np.isfinite(frames) & (frames > 1)
    if recorded.sum() >= _MIN_FRAME_SHARE * max(1, ok.sum()) and recorded.any():
        count = float(np.mean(frames[recorded]))
        carried = _carried_variance(dataset, params, ok, sigma_l / np.sqrt(count))
        variance = np.mean(sem[recorded] ** 2, axis=0) + carried
        return NoiseEstimate(np.sqrt(variance), "frames",
                             f"the scatter of the {count:.3g} tracker frames averaged into each of "
                             f"{int(recorded.sum())} rows (their standard error), and load-cell noise {sigma_l:.3g} N "
                             "(sensors.loadcell_noise_n) over as many samples, carried through the model")
    variance = np.full(3, sigma_t**2) + _carried_variance(dataset, params, ok, sigma_l)
    return NoiseEstimate(np.sqrt(variance), "prior",
                         f"tracker noise {sigma_t * 1e3:.3g} mm per axis (sensors.tracker_noise_m) and load-cell "
                         f"noise {sigma_l:.3g} N (sensors.loadcell_noise_n) carried through the model")


def _carried_variance(dataset: Dataset, params: Params, ok: np.ndarray, sigma_l: float) -> np.ndarray:
    """(3,) mean variance of the tip (m²) that load-cell noise ``sigma_l`` (N) on each channel
    makes through the model (each channel's sensitivity by a finite difference, every row)."""
    if not (sigma_l > 0 and ok.any()):
        return np.zeros(3)
    data = dataset.subset(ok)
    args = (data["tip_mass_kg"], data.lengths_m)
    solutions = [None] * len(data)
    tip0, ok0, _, _ = predict_rows(params, data.base_rotation, data.tensions_n, *args, guesses=solutions,
                                   sliding_state=data.sliding_state)
    carried = np.zeros((len(data), 3))
    for channel in range(data.tensions_n.shape[1]):
        bumped = data.tensions_n.copy()
        bumped[:, channel] += _TENSION_STEP_N
        tip1, ok1, _, _ = predict_rows(params, data.base_rotation, bumped, *args, guesses=list(solutions),
                                       sliding_state=data.sliding_state)
        step = np.where((ok0 & ok1)[:, None], tip1 - tip0, 0.0)
        carried += (step * sigma_l / _TENSION_STEP_N) ** 2
    return carried.mean(axis=0)
