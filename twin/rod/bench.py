"""Predictor speed benchmark: cold, warm-started and pose + Jacobian solve times."""

from __future__ import annotations

import time

import numpy as np

from twin.params import Params, load_params
from twin.pcc import validation_grid
from twin.rod.grid import GRAVITY_TIP_FORCE_N, pcc_tensions_n
from twin.rod.jacobian import tip_jacobian
from twin.rod.model import RodModel
from twin.rod.solver import Predictor, solve

__all__ = ["bench_predictor"]


def bench_predictor(params: Params | None = None, *, stream_samples: int = 400) -> dict:
    """Median solve times on one core, and the tip accuracy against a fine-resolution solution.

    cold_s: a solve from no guess, over the robot's validation grid (:func:`twin.pcc.validation_grid`).
    warm_s: the next sample of a 40 Hz stream whose tensions and tip load change slowly
        (a 0.5 Hz sweep), each solve warm-started from the previous one by
        :class:`twin.rod.Predictor` (its base moment and shooting Jacobian).
    jacobian_s: a warm-started tip pose plus its 6 × (nt + 6) Jacobian.
    tip_error_m: the largest tip difference against 640 RK4 steps over the grid sample.
    """
    params = params or load_params()
    model = RodModel.from_params(params)
    pose = params.rig.base_rotation
    g = params.environment.gravity_m_s2
    grid = validation_grid(params)[::7]
    cases = [(pcc_tensions_n(k, phi, params), GRAVITY_TIP_FORCE_N(m, g)) for _, k, phi, m in grid]
    solve(model, cases[0][0], tip_force_n=cases[0][1], base_rotation=pose)  # compile / load cache

    cold = []
    for tensions, force in cases:
        t0 = time.perf_counter()
        solve(model, tensions, tip_force_n=force, base_rotation=pose)
        cold.append(time.perf_counter() - t0)

    fine = model.replace(steps=640)
    error = 0.0
    for tensions, force in cases[::3]:
        a = solve(model, tensions, tip_force_n=force, base_rotation=pose).tip_position_m
        b = solve(fine, tensions, tip_force_n=force, base_rotation=pose).tip_position_m
        error = max(error, float(np.linalg.norm(a - b)))

    warm, jac = [], []
    predictor = Predictor(model)
    base = pcc_tensions_n(13.0, 0.0, params)
    for k in range(stream_samples):
        t = k / 40.0
        wiggle = np.zeros(model.tendon_count)
        wiggle[:2] = [np.sin(np.pi * t), np.cos(np.pi * t)]  # the first two tendons, whatever the count
        tensions = base + 0.5 * wiggle.clip(0) * 0.5
        force = GRAVITY_TIP_FORCE_N(0.005 * (1 + np.sin(0.2 * np.pi * t)), g)
        t0 = time.perf_counter()
        sol = predictor.solve(tensions, tip_force_n=force, base_rotation=pose)
        t1 = time.perf_counter()
        tip_jacobian(model, sol)
        t2 = time.perf_counter()
        if k > 0:
            warm.append(t1 - t0)
            jac.append(t2 - t0)
    return {
        "cold_s": float(np.median(cold)),
        "warm_s": float(np.median(warm)),
        "jacobian_s": float(np.median(jac)),
        "tip_error_m": error,
        "steps": model.steps,
        "cases": len(cases),
        "stream_samples": stream_samples,
    }
