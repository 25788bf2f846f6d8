"""Validation-sweep datasets with a hidden effect, made with the predictor (fast, known truth).

The proof of the discrepancy workflow needs data in which an effect is hidden: the endoscope
and rig behave as the *true* parameter set says, while the dataset's metadata records the
*nominal* set the model believes. Each row is a validation-grid configuration (thesis §8.3):

* the tendons carry the tensions that bend the nominal, weightless model to (κ, φ) on top of a
  pretension drawn from the thesis's 1.2–1.5 N (the reference holder is never exact);
* the true endoscope (its stiffness, weight, disc mass and capstan friction, with each tendon's
  sliding direction from its encoder length, :func:`twin.effects.friction_direction`) is solved
  under the true tip load and the true, possibly tilted, clamp;
* the sensors report as :mod:`twin.sim.sensors` does: load cells gain · τ + offset plus noise
  (:func:`twin.effects.loadcell_response`),
  encoders quantised to one count, the tracker at its offset from the tip plus noise.

The prediction side (:mod:`twin.data.prediction`) undoes exactly this measurement model
when it is given the true parameters, so a perfect fit leaves only noise.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np
from scipy.spatial.transform import Rotation

from twin import effects
from twin.data.dataset import Dataset, write_dataset
from twin.params import Params
from twin.pcc import tendon_length_changes_m, validation_grid
from twin.pose import HORIZONTAL
from twin.rod import RodModel, solve_batch
from twin.rod.grid import pcc_tensions_n

__all__ = ["PRETENSION_RANGE_N", "synthetic_validation_dataset"]

PRETENSION_RANGE_N = (1.2, 1.5)  # thesis §8.3: set by hand in the reference holder


def synthetic_validation_dataset(folder: str | Path, nominal: Params, truth: Params, *,
                                 grid: Iterable[tuple[int, float, float, float]] | None = None,
                                 repeats: int = 1, seed: int = 0, tracker_noise_m: float | None = None,
                                 loadcell_noise_n: float | None = None, base_rotation=HORIZONTAL,
                                 tip_moment_nm=None, tracker_rotation_deg=None,
                                 precurvature_per_m=None, frames: int = 1) -> Dataset:
    """Write a validation dataset measured on the ``truth`` endoscope, labelled with ``nominal``.

    Args:
        folder: where to write the dataset (created).
        nominal: the parameter set the model believes (recorded in the metadata).
        truth: the parameter set the data obey (its effects are the hidden ones).
        grid: (config, κ 1/m, φ deg, tip mass kg) tuples; default the 216 of thesis §8.3.
        repeats: measurements per configuration (fresh pretension and noise each).
        seed: random seed of pretensions and noise.
        tracker_noise_m: tracker noise per axis and frame (m); default ``truth.sensors.tracker_noise_m``.
        loadcell_noise_n: load-cell noise per sample (N); default ``truth.sensors.loadcell_noise_n``.
        frames: tracker frames (and load-cell samples) averaged into each row, as the rig's
            measurement window does; with more than one, each row records them and its tip's
            standard error (``tip_frames``, ``tip_sem_*_m``).
        base_rotation: nominal clamp orientation (3×3, body → world).
        tip_moment_nm: a constant moment at the tip (N·m, world frame), as a cable or a contact
            would put there: an effect no parameter of the model carries.
        tracker_rotation_deg: the tracker's frame turned about the base origin by this rotation
            vector (deg, world axes; e.g. (0, 0, 1): 1° about the vertical), as a registration
            error would leave it: every measured position is R · p. No parameter carries it.
        precurvature_per_m: the backbone's intrinsic curvature (body frame, 1/m, 3 components:
            bending about the body x and y axes, twist), as a backbone set in a curve would have
            (:attr:`twin.rod.RodModel.precurvature_per_m`). No parameter carries it.

    Returns:
        The dataset as read back. Configurations the true model cannot solve are left out (none
        on the thesis grid with lab-sized effects).
    """
    rng = np.random.default_rng(seed)
    tracker_sigma = truth.sensors.tracker_noise_m if tracker_noise_m is None else tracker_noise_m
    loadcell_sigma = truth.sensors.loadcell_noise_n if loadcell_noise_n is None else loadcell_noise_n
    model = RodModel.from_params(truth)
    if precurvature_per_m is not None:
        model = model.replace(precurvature_per_m=tuple(float(u) for u in precurvature_per_m))
    registration = np.eye(3) if tracker_rotation_deg is None else \
        Rotation.from_rotvec(np.radians(np.asarray(tracker_rotation_deg, dtype=float))).as_matrix()
    clamp = effects.clamp_rotation(truth, base_rotation)
    gain, offset = effects.loadcell_response(truth)
    count_m = truth.rig.tendon_m_per_count
    cases = list(validation_grid() if grid is None else grid)
    stride = max(int(c[0]) for c in cases) + 1  # repeats get their own configuration numbers
    nt = truth.tendons.count
    rows = []
    for repeat in range(repeats):
        # Each case's random draws first, in the order a case-by-case loop makes them (pretension,
        # tracker noise, load-cell noise), then all of the repeat's cases in one batch solve.
        tensions, lengths, tracker, loadcell = [], [], [], []
        for _, kappa, phi, _ in cases:
            pretension = rng.uniform(*PRETENSION_RANGE_N, size=nt)
            tensions.append(pcc_tensions_n(kappa, phi, nominal, pretension_n=0.0) + pretension)
            # Encoders count whole steps, which also settles the sign of the tendons that do
            # not move (cos(φ − α) = 0 up to rounding): they stay as the holder pulled them.
            lengths.append(np.round(tendon_length_changes_m(kappa, phi, nominal) / count_m) * count_m + 0.0)
            tracker.append(rng.normal(0.0, tracker_sigma, (frames, 3)))
            loadcell.append(rng.normal(0.0, loadcell_sigma, (frames, nt)).mean(axis=0))
        solutions = solve_batch(
            model, np.array(tensions), tip_force_n=np.array([effects.tip_force_n(truth, c[3]) for c in cases]),
            base_rotation=clamp, tip_moment_nm=tip_moment_nm,
            friction_direction=np.array([effects.friction_direction(x, truth.effects.tendon_friction_direction)
                                         for x in lengths]), raise_on_failure=False)
        for (config, kappa, phi, mass), sol, t, x, noise, cell_noise in zip(cases, solutions, tensions, lengths, tracker,
                                                                             loadcell):
            if not sol.converged:
                continue
            tip = registration @ effects.tracked_point_m(truth, sol.tip_position_m, sol.tip_rotation)
            seen = tip + noise
            tip = seen.mean(axis=0)
            reported = gain * t + offset + cell_noise
            row = {"config": repeat * stride + config, "repeat": repeat, "kappa_cmd_per_m": kappa,
                   "phi_cmd_deg": phi, "tip_mass_kg": mass, "tip_x_m": tip[0], "tip_y_m": tip[1], "tip_z_m": tip[2]}
            if frames > 1:
                sem = seen.std(axis=0, ddof=1) / np.sqrt(frames)
                row.update({"tip_frames": frames, "tip_sem_x_m": sem[0], "tip_sem_y_m": sem[1], "tip_sem_z_m": sem[2]})
            for i in range(t.size):
                row[f"tension_{i + 1}_n"] = reported[i]
                row[f"length_{i + 1}_m"] = x[i]
            rows.append(row)
    return write_dataset(folder, rows, experiment="validation", device="synthetic://predictor", params=nominal,
                         base_rotation=base_rotation,
                         notes=f"synthetic: predictor with hidden effects, seed {seed}, {repeats} repeat(s)")
