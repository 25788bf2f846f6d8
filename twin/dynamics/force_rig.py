"""The tip force estimate on the rig-like path: hidden tip loads on the twin behind a ``sim://``
device, estimated from what the device reports (load-cell tensions, the tracker's tip pose).

Unlike :mod:`twin.force.bench`, the truth here is the MuJoCo twin's, not the predictor's: the
estimate meets the model-form error between the two, the tension loops' ripple and the tracker's
fused frames, as it would on a rig.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from twin import effects
from twin.control.pretension import pretension_straight
from twin.effects.tendon_friction import SlidingState
from twin.experiments.protocols import wait_for_rest
from twin.force.estimator import estimate_tip_wrench
from twin.pcc import tendon_length_changes_m
from twin.rod import RodModel
from twin.rod.grid import pcc_realisable

__all__ = ["RIG_POSES", "rig_trials", "rig_summary", "bench_force_rig", "contact_run", "bench_contact"]

# (name, curvature (1/m), bending plane (deg)): straight and bent (the thesis grid's middle curvature).
RIG_POSES = (("straight", 0.0, 0.0), ("bent", 5.0, 0.0))


def rig_trials(device, params, forces_n, *, poses=RIG_POSES, frames: int = 8, model_error_fraction: float = 0.02,
               settle_timeout_s: float = 4.0, progress=None) -> list[dict]:
    """Per pose and hidden force: ``frames`` live (warm) estimates from single telemetry frames.

    Each row: pose, true force (N), error (N, in the observable directions), whether the 95 %
    ellipsoid covers the truth, converged, observable dimensions.
    """
    model = RodModel.from_params(params)
    sliding = SlidingState(device.info.tendon_m_per_count)
    sliding.follow(device.drain())
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
                # With tendon friction the tension along a tendon depends on how it slides: the
                # state its encoder's history gives (the dataset's record of it, the same way).
                direction = effects.friction_direction(sample.tendon_lengths_m - zero,
                                                       params.effects.tendon_friction_direction,
                                                       sliding.follow(device.drain()))
                est = estimate_tip_wrench(params, sample.tensions_n, fused.pose.position_m, fused.pose.rotation,
                                          base_rotation=device.base_rotation, model=model, previous=previous,
                                          model_error_fraction=model_error_fraction, friction_direction=direction)
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


def contact_run(device, params, *, clean_s: float = 20.0, loads_n=(), load_hold_s: float = 1.0,
                quiet_s: float = 2.0, bend_per_m: float = 5.0, swing_per_m: float = 3.0, period_s: float = 4.0,
                detector=None, progress=None) -> dict:
    """A moving robot on the twin: first ``clean_s`` of clean motion (every flag a false alarm),
    then each load of ``loads_n`` (N, (k, 3)) applied at once for ``load_hold_s`` and removed for
    ``quiet_s`` (the detector reset when it is removed: the contact is over).

    The robot follows a curvature of ``bend_per_m`` ± ``swing_per_m`` 1/m over ``period_s`` in
    lengths mode; every telemetry frame gets a live estimate (:class:`twin.force.stream.ForceStream`,
    which follows the sliding states from the encoders) and a detector step.

    Returns: clean time (s), false alarms in it, per load its latency (device s; NaN when missed
    within ``load_hold_s``), the estimates' median and 95th percentile CPU time (s).
    """
    from twin.force.contact import ContactDetector
    from twin.force.stream import ForceStream

    rate = params.rig.telemetry_rate_hz
    detector = detector or ContactDetector(rate_hz=rate)
    phi = next(30.0 * k for k in range(12) if pcc_realisable(30.0 * k, params))
    device.fixture.apply_tip_load((0.0, 0.0, 0.0))
    zero = pretension_straight(device, params, mode="lengths")
    settle_s = device.fixture.settle_s
    device.fixture.settle_s = 0.0  # a load appears at once, as a contact does
    stream = ForceStream.for_device(device, params, detector=detector)
    stream.follow(device.drain())
    times: list[float] = []
    start = device.time_s

    def step():
        t = device.time_s - start
        kappa = bend_per_m + swing_per_m * np.sin(2 * np.pi * t / period_s)
        device.set_lengths(zero + tendon_length_changes_m(kappa, phi, params))
        sample = device.wait_next(timeout_s=1.0)
        fused = device.tracker.read()
        if not fused.ok:
            stream.follow(device.drain())
            return None
        out = stream.update(sample, fused.pose.position_m, fused.pose.rotation, samples=device.drain())
        times.append(out.estimate_time_s)
        return out

    try:
        # The robot starts moving from straight: a second to reach its swing before anything counts.
        end = device.time_s + 1.0
        while device.time_s < end:
            step()
        detector.reset()
        false_alarms, end = 0, device.time_s + clean_s
        while device.time_s < end:
            out = step()
            if out is not None and out.contact:
                false_alarms += 1
                detector.reset()
            if progress:
                progress()
        latencies = []
        for load in np.atleast_2d(np.asarray(loads_n, dtype=float)) if len(loads_n) else []:
            device.fixture.apply_tip_load(load)
            applied = device.time_s
            latency = float("nan")
            while device.time_s < applied + load_hold_s:
                out = step()
                if out is not None and out.contact and not np.isfinite(latency):
                    latency = device.time_s - applied
            device.fixture.apply_tip_load((0.0, 0.0, 0.0))
            detector.reset()
            end = device.time_s + quiet_s
            while device.time_s < end:
                step()
            latencies.append(latency)
            if progress:
                progress()
    finally:
        device.fixture.settle_s = settle_s
        device.fixture.apply_tip_load((0.0, 0.0, 0.0))
    return {"clean_s": float(clean_s), "false_alarms": false_alarms, "latencies_s": latencies,
            "median_estimate_s": float(np.median(times)) if times else float("nan"),
            "p95_estimate_s": float(np.percentile(times, 95)) if times else float("nan")}


def bench_contact(params=None, *, clean_s: float = 600.0, loads: int = 20, min_load_n: float = 0.02,
                  max_load_n: float = 0.3, seed: int = 0) -> dict:
    """Contact detection on the twin (``sim://``) with the robot moving (:func:`contact_run`):
    false alarms over ``clean_s`` of clean motion (default the 10 minutes the goal names), then
    ``loads`` tip loads of ``min_load_n``–``max_load_n`` N in random directions, each held 1 s.

    Returns: false_alarms, clean_s, detected (fraction of loads flagged within their hold),
    latency_max_s, latency_p95_s and latency_median_s (device time from the load's appearance to
    the flag), estimate_s and estimate_p95_s (median and 95th percentile CPU time of a live
    estimate in the run).
    """
    from tqdm import tqdm

    from twin.driver import open_device
    from twin.params import load_params

    params = params or load_params()
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(loads, 3))
    forces = rng.uniform(min_load_n, max_load_n, (loads, 1)) * directions / np.linalg.norm(directions, axis=1,
                                                                                           keepdims=True)
    frames = int(clean_s * params.rig.telemetry_rate_hz)
    with tqdm(total=frames + loads, desc="contact run", unit="frame", leave=False) as bar, \
            open_device(f"sim://?seed={seed}", params=params) as device:
        out = contact_run(device, params, clean_s=clean_s, loads_n=forces, progress=bar.update)
    latencies = np.array(out["latencies_s"])
    found = latencies[np.isfinite(latencies)]
    return {"false_alarms": out["false_alarms"], "clean_s": out["clean_s"],
            "detected": float(found.size / max(latencies.size, 1)),
            "latency_max_s": float(found.max()) if found.size == latencies.size and found.size else float("inf"),
            "latency_median_s": float(np.median(found)) if found.size else float("nan"),
            "latency_p95_s": float(np.percentile(found, 95)) if found.size else float("nan"),
            "smallest_load_n": float(np.linalg.norm(forces, axis=1).min()) if loads else float("nan"),
            "estimate_s": out["median_estimate_s"], "estimate_p95_s": out["p95_estimate_s"]}


def bench_force_rig(params=None, *, loads: int = 8, frames: int = 5, max_load_n: float = 0.3, seed: int = 0) -> dict:
    """The accuracy table on the rig-like path (:func:`rig_trials` on ``sim://``): no load and
    ``loads`` random loads of up to ``max_load_n`` N, in the straight and bent poses, ``frames``
    live estimates each.

    Returns: the worst pose's median error over its goal (5 % + 2 mN), coverage over every
    estimate, the converged fraction, the median CPU time of an estimate (s) and the per-pose table.
    """
    from tqdm import tqdm

    from twin.driver import open_device
    from twin.params import load_params

    params = params or load_params()
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(loads, 3))
    forces = np.vstack([np.zeros(3), rng.uniform(0.0, max_load_n, (loads, 1)) * directions
                        / np.linalg.norm(directions, axis=1, keepdims=True)])
    with tqdm(total=len(forces) * len(RIG_POSES), desc="rig force trials", unit="load", leave=False) as bar, \
            open_device(f"sim://?seed={seed}", params=params) as device:
        rows = rig_trials(device, params, forces, frames=frames, progress=bar.update)
    table = rig_summary(rows)
    return {"worst_median_error_over_goal": max(r["median_error_over_goal"] for r in table),
            "coverage": float(np.mean([r["covered"] for r in rows])),
            "converged_fraction": float(np.mean([r["converged"] for r in rows])),
            "estimate_s": float(np.median([r["estimate_time_s"] for r in rows])),
            "table": [{k: (float(f"{v:.4g}") if isinstance(v, float) else v) for k, v in r.items()} for r in table]}
