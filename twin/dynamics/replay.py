"""Replay a dynamic dataset on the twin and compare the series.

:func:`replay` sends the recorded commands, at their recorded times, to a ``sim://`` device built
from a parameter set, through the same protocol runner that recorded them
(:func:`twin.dynamics.protocols.run_experiment`), one experiment after the other on one twin as
they were recorded: what an experiment leaves (a backlash taken up on one side, a friction state)
carries into the next one on both. The twin's sensors are noiseless there: the replay is the model's expectation, and what the
measurement adds to it is noise or a missing effect. :func:`compare` puts the replay on the
measurement's sample times (linear interpolation) and gives per-channel RMS gaps.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from twin.dynamics.protocols import Series, run_experiment
from twin.params import Params
from twin.pose import matrix_to_quat

__all__ = ["GROUPS", "NOISE_FLOORS", "TRIM", "UNITS", "Comparison", "compare", "replay", "replay_params",
           "trimmed_mean_square"]

# The channel groups compared, each with the smallest gap that counts as noise: two encoder
# counts (0.94 µm a count; a length loop's noiseless replay repeats to the count, a model never
# does), a tenth of the HX711's 5 mN noise, a micrometre of tip.
GROUPS = ("lengths", "tensions", "tip")
NOISE_FLOORS = {"lengths": 2e-6, "tensions": 5e-4, "tip": 1e-6}
UNITS = {"lengths": "m", "tensions": "N", "tip": "m"}
# Share of the samples with the largest gaps a score leaves out (:func:`trimmed_mean_square`):
# the two-segment robot's clean chirp has 3 of its 104 samples at engagement spikes of 0.2-0.3 N.
TRIM = 0.03


def replay_params(params: Params, base_rotation, *, noiseless: bool = True) -> Params:
    """``params`` as the replay's twin runs it: in the recorded pose, with noiseless sensors
    unless ``noiseless`` is False."""
    changes: dict[str, object] = {"rig.base_quat": [float(q) for q in matrix_to_quat(np.asarray(base_rotation))]}
    if noiseless:
        changes.update({"sensors.loadcell_noise_n": 0.0, "sensors.tracker_noise_m": 0.0,
                        "sensors.tracker_noise_rad": 0.0})
    return params.replace(changes, source="dynamics replay")


def replay(measured: list[Series], params: Params, base_rotation, *, noise_seed: int | None = None) -> list[Series]:
    """The twin's series for the commands of each measured series (same experiments, same order,
    one after the other from the twin's start).

    Args:
        measured: the recorded series (their experiments give the commands and times).
        params: the twin's parameter set (the model under test).
        base_rotation: the pose the data were taken in (3×3, body → world).
        noise_seed: None for noiseless sensors (the model's expectation); a seed for the
            parameter set's sensor noise (what a measurement without a missing effect looks like).
    """
    from twin.driver import open_device
    from twin.experiments.protocols import apply_calibration, nominal_calibration

    twin_params = replay_params(params, base_rotation, noiseless=noise_seed is None)
    calibration = nominal_calibration(twin_params)
    device = open_device("sim://", params=twin_params, seed=noise_seed or 0)
    try:
        device.connect()
        apply_calibration(device, calibration)
        return [run_experiment(device, series.experiment, twin_params) for series in measured]
    finally:
        device.close()


@dataclasses.dataclass
class Comparison:
    """Measured against replayed series.

    Attributes:
        names: the experiments, in order.
        residuals: per experiment, group → (T, channels) measured − replay at the measured
            sample times (tip rows without a valid frame dropped).
    """

    names: list[str]
    residuals: list[dict[str, np.ndarray]]

    def stacked(self, group: str) -> np.ndarray:
        """One group's residuals of every experiment, stacked (rows, channels)."""
        return np.vstack([r[group] for r in self.residuals])

    def rms(self, group: str) -> np.ndarray:
        """Per-channel RMS gap of a group over every experiment (its unit, :data:`UNITS`)."""
        return np.sqrt(np.mean(self.stacked(group) ** 2, axis=0))

    def group_rms(self, group: str) -> float:
        """RMS gap of a group over its channels (the tip: 3-D distance)."""
        r = self.stacked(group)
        per_row = np.sum(r ** 2, axis=1) if group == "tip" else np.mean(r ** 2, axis=1)
        return float(math.sqrt(np.mean(per_row)))

    def levels(self) -> list[dict[str, float]]:
        """Per experiment, each group's RMS gap per channel (:func:`trimmed_mean_square`), at least
        :data:`NOISE_FLOORS`: of a comparison of a noisy twin with the noiseless one, the gap at
        the noise level."""
        return [{g: max(math.sqrt(trimmed_mean_square(r[g])), NOISE_FLOORS[g]) for g in GROUPS}
                for r in self.residuals]

    def scores(self, noise: list[dict[str, float]]) -> np.ndarray:
        """(experiments, groups) each group's mean squared gap (:func:`trimmed_mean_square`) over
        its noise level squared (``noise``: :meth:`levels` of the noise reference): about 1 at the
        noise level."""
        return np.array([[trimmed_mean_square(r[g]) / n[g] ** 2 for g in GROUPS]
                         for r, n in zip(self.residuals, noise)])

    def to_dict(self) -> dict:
        """Per group: the per-channel RMS gaps over every experiment (``rms``), their unit, and
        each experiment's (``by_experiment``: name → per-channel RMS; empty for a tip never tracked)."""
        return {g: {"rms": self.rms(g).tolist(), "unit": UNITS[g],
                    "by_experiment": {name: np.sqrt(np.mean(r[g] ** 2, axis=0)).tolist() if r[g].size else []
                                      for name, r in zip(self.names, self.residuals)}} for g in GROUPS}


def trimmed_mean_square(gaps: np.ndarray) -> float:
    """Mean over samples and channels of the squared gaps (rows, channels), leaving out the
    :data:`TRIM` share of samples with the largest: a slack tendon taken up spikes its tension
    for a sample or two at a time the noise decides, and a few such spikes would otherwise
    outweigh seconds of agreement. A missing effect shows in most samples, not a few."""
    if gaps.size == 0:
        return 0.0
    per_sample = np.sort(np.mean(gaps ** 2, axis=1))
    keep = max(1, int(round(per_sample.size * (1.0 - TRIM))))
    return float(np.mean(per_sample[:keep]))


def compare(measured: list[Series], replayed: list[Series]) -> Comparison:
    """Residuals measured − replay on the measured sample times, per experiment and group."""
    residuals = []
    for m, r in zip(measured, replayed):
        def on_measured(values: np.ndarray) -> np.ndarray:
            return np.column_stack([np.interp(m.time_s, r.time_s, values[:, j]) for j in range(values.shape[1])])

        tip_r = on_measured(np.where(np.isfinite(r.tip_m), r.tip_m, np.nan))
        tip = m.tip_m - tip_r
        residuals.append({"lengths": m.lengths_m - on_measured(r.lengths_m),
                          "tensions": m.tensions_n - on_measured(r.tensions_n),
                          "tip": tip[np.all(np.isfinite(tip), axis=1)]})
    return Comparison([s.experiment.name for s in measured], residuals)
