"""The tip force estimate on the rig-like path: hidden tip loads on the twin behind a ``sim://``
device, estimated from what the device reports (load-cell tensions, the tracker's tip pose).

Unlike :mod:`twin.force.bench`, the truth here is the MuJoCo twin's, not the predictor's: the
estimate meets the model-form error between the two, the tension loops' ripple and the tracker's
fused frames, as it would on a rig.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from twin.control.pretension import pretension_straight
from twin.experiments.protocols import wait_for_rest
from twin.force.estimator import estimate_tip_wrench
from twin.pcc import tendon_length_changes_m
from twin.rod import RodModel
from twin.rod.grid import pcc_realisable

__all__ = ["RIG_POSES", "rig_trials", "rig_summary"]

# (name, curvature (1/m), bending plane (deg)): straight and bent (the thesis grid's middle curvature).
RIG_POSES = (("straight", 0.0, 0.0), ("bent", 5.0, 0.0))


def rig_trials(device, params, forces_n, *, poses=RIG_POSES, frames: int = 8, model_error_fraction: float = 0.02,
               settle_timeout_s: float = 4.0, progress=None) -> list[dict]:
    """Per pose and hidden force: ``frames`` live (warm) estimates from single telemetry frames.

    Each row: pose, true force (N), error (N, in the observable directions), whether the 95 %
    ellipsoid covers the truth, converged, observable dimensions.
    """
    model = RodModel.from_params(params)
    rows = []
    for pose, kappa, phi in poses:
        phi = next(phi + 30.0 * k for k in range(12) if pcc_realisable(phi + 30.0 * k, params))
        device.fixture.apply_tip_load((0.0, 0.0, 0.0))
        zero = pretension_straight(device, params, mode="lengths")
        device.set_lengths(zero + tendon_length_changes_m(kappa, phi, params))
        previous = None
        for force in np.atleast_2d(np.asarray(forces_n, dtype=float)):
            device.fixture.apply_tip_load(force)
            wait_for_rest(device, tension_tolerance_n=np.inf, timeout_s=settle_timeout_s)
            for _ in range(frames):
                sample = device.wait_next(timeout_s=1.0)
                fused = device.tracker.read()
                if not fused.ok:
                    continue
                est = estimate_tip_wrench(params, sample.tensions_n, fused.pose.position_m, fused.pose.rotation,
                                          base_rotation=device.base_rotation, model=model, previous=previous,
                                          model_error_fraction=model_error_fraction)
                previous = est if est.converged else None
                unobs = est.unobservable_force_directions
                seen = np.eye(3) - (unobs.T @ unobs if unobs.size else 0.0)
                err = seen @ (est.force_observable_n - force)
                dims = int(round(np.trace(seen)))
                d2 = float(err @ np.linalg.pinv(est.force_observable_cov_n2, rcond=1e-10, hermitian=True) @ err)
                rows.append({"pose": pose, "true_force_n": force.tolist(), "error_n": float(np.linalg.norm(err)),
                             "covered": bool(d2 <= chi2.ppf(0.95, max(dims, 1))), "converged": est.converged,
                             "observable_dims": dims, "iterations": est.iterations,
                             "estimate_time_s": est.estimate_time_s})
            if progress:
                progress()
    device.fixture.apply_tip_load((0.0, 0.0, 0.0))
    return rows


def rig_summary(rows: list[dict]) -> list[dict]:
    """Per pose: median and 95th percentile error (N), median error over its goal (5 % + 2 mN),
    coverage, the converged fraction and the median CPU time of an estimate (s)."""
    out = []
    for pose in dict.fromkeys(r["pose"] for r in rows):
        group = [r for r in rows if r["pose"] == pose]
        err = np.array([r["error_n"] for r in group])
        goal = np.array([0.05 * np.linalg.norm(r["true_force_n"]) + 0.002 for r in group])
        out.append({"pose": pose, "estimates": len(group), "median_error_n": float(np.median(err)),
                    "p95_error_n": float(np.percentile(err, 95)),
                    "median_error_over_goal": float(np.median(err / goal)),
                    "coverage": float(np.mean([r["covered"] for r in group])),
                    "converged": float(np.mean([r["converged"] for r in group])),
                    "median_estimate_s": float(np.median([r["estimate_time_s"] for r in group]))})
    return out
