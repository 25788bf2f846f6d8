"""Predictor speed benchmarks (``twin bench predictor``, ``twin bench peers``), on CPU time.

Every time is CPU time of this process (:class:`twin.stopwatch.Stopwatch`), with the wall time
beside it under a ``_wall`` name: on a shared machine the wall clock runs several times the CPU
time and would judge a healthy build slow.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np

from twin.params import Params, load_params
from twin.pcc import validation_grid
from twin.resources import NativeBuildError, build_cached
from twin.rod import kernel
from twin.rod.grid import GRAVITY_TIP_FORCE_N, pcc_tensions_n
from twin.rod.jacobian import tip_jacobian
from twin.rod.model import RodModel
from twin.rod.solver import Predictor, rod_inputs, solve, solve_batch
from twin.stopwatch import Stopwatch

__all__ = ["bench_peers", "bench_predictor", "integration_s", "standin_integration"]

_STANDIN = Path(__file__).resolve().parent / "native" / "rk4_standin.cpp"
# Release flags, as a CMake Release build of an Eigen peer would compile with.
_STANDIN_FLAGS = ("-O3", "-DNDEBUG", "-std=c++17")


def bench_predictor(params: Params | None = None, *, stream_samples: int = 400) -> dict:
    """Median solve times (CPU s) on one core, and the tip accuracy against a fine-resolution solution.

    cold_s: a solve from no guess, over the robot's validation grid (:func:`twin.pcc.validation_grid`).
    warm_s: the next sample of a 40 Hz stream whose tensions and tip load change slowly
        (a 0.5 Hz sweep), each solve warm-started from the previous one by
        :class:`twin.rod.Predictor` (its base moment and shooting Jacobian).
    jacobian_s: a warm-started tip pose plus its 6 × (nt + 6) Jacobian.
    integration_s: one RK4 integration of the rod inside the compiled code (:func:`integration_s`).
    batch_s: per solve, the whole thesis grid (216 sets) in one :func:`twin.rod.solve_batch`;
        loop_s: the same sets one :meth:`Predictor.solve` after another (warm-started likewise).
    tip_error_m: the largest tip difference against 640 RK4 steps over the grid sample.
    """
    params = params or load_params()
    model = RodModel.from_params(params)
    pose = params.rig.base_rotation
    g = params.environment.gravity_m_s2
    full = [(pcc_tensions_n(k, phi, params), GRAVITY_TIP_FORCE_N(m, g)) for _, k, phi, m in validation_grid(params)]
    cases = full[::7]
    first = solve(model, cases[0][0], tip_force_n=cases[0][1], base_rotation=pose)  # compile / load cache
    tip_jacobian(model, first)

    cold, cold_wall = [], []
    for tensions, force in cases:
        with Stopwatch() as watch:
            solve(model, tensions, tip_force_n=force, base_rotation=pose)
        cold.append(watch.cpu_s)
        cold_wall.append(watch.wall_s)

    fine = model.replace(steps=640)
    error = 0.0
    for tensions, force in cases[::3]:
        a = solve(model, tensions, tip_force_n=force, base_rotation=pose).tip_position_m
        b = solve(fine, tensions, tip_force_n=force, base_rotation=pose).tip_position_m
        error = max(error, float(np.linalg.norm(a - b)))

    warm, warm_wall, jac, jac_wall = [], [], [], []
    predictor = Predictor(model)
    base = pcc_tensions_n(13.0, 0.0, params)
    for k in range(stream_samples):
        t = k / 40.0
        wiggle = np.zeros(model.tendon_count)
        wiggle[:2] = [np.sin(np.pi * t), np.cos(np.pi * t)]  # the first two tendons, whatever the count
        tensions = base + 0.5 * wiggle.clip(0) * 0.5
        force = GRAVITY_TIP_FORCE_N(0.005 * (1 + np.sin(0.2 * np.pi * t)), g)
        with Stopwatch() as solve_watch:
            sol = predictor.solve(tensions, tip_force_n=force, base_rotation=pose)
        with Stopwatch() as jac_watch:
            tip_jacobian(model, sol)
        if k > 0:
            warm.append(solve_watch.cpu_s)
            warm_wall.append(solve_watch.wall_s)
            jac.append(solve_watch.cpu_s + jac_watch.cpu_s)
            jac_wall.append(solve_watch.wall_s + jac_watch.wall_s)

    tensions = np.array([t for t, _ in full])
    forces = np.array([f for _, f in full])
    batch_watch, loop_watch = _batch_and_loop(model, tensions, forces, pose)
    per_integration, per_integration_wall = integration_s(model, first)
    return {
        "cold_s": float(np.median(cold)),
        "warm_s": float(np.median(warm)),
        "jacobian_s": float(np.median(jac)),
        "integration_s": per_integration,
        "batch_s": batch_watch.cpu_s / len(full),
        "loop_s": loop_watch.cpu_s / len(full),
        "tip_error_m": error,
        "cold_wall_s": float(np.median(cold_wall)),
        "warm_wall_s": float(np.median(warm_wall)),
        "jacobian_wall_s": float(np.median(jac_wall)),
        "integration_wall_s": per_integration_wall,
        "batch_wall_s": batch_watch.wall_s / len(full),
        "loop_wall_s": loop_watch.wall_s / len(full),
        "batch_sets": len(full),
        "steps": model.steps,
        "cases": len(cases),
        "stream_samples": stream_samples,
    }


def _batch_and_loop(model: RodModel, tensions: np.ndarray, forces: np.ndarray, pose: np.ndarray,
                    rounds: int = 3) -> tuple[Stopwatch, Stopwatch]:
    """The fastest of ``rounds`` alternating runs of the sets as one batch and as a loop."""
    best_batch = best_loop = None
    for _ in range(rounds):
        with Stopwatch() as batch:
            solve_batch(model, tensions, tip_force_n=forces, base_rotation=pose)
        predictor = Predictor(model)
        with Stopwatch() as loop:
            for t, f in zip(tensions, forces):
                predictor.solve(t, tip_force_n=f, base_rotation=pose)
        if best_batch is None or batch.cpu_s < best_batch.cpu_s:
            best_batch = batch
        if best_loop is None or loop.cpu_s < best_loop.cpu_s:
            best_loop = loop
    if best_batch is None or best_loop is None:
        raise ValueError(f"rounds = {rounds!r}: must be >= 1")
    return best_batch, best_loop


def integration_s(model: RodModel, solution, *, count: int = 2000, rounds: int = 5) -> tuple[float, float]:
    """(CPU s, wall s) of one integration of ``model`` at a solution's base moment and load, inside
    compiled code: the fastest of ``rounds`` runs of ``count``."""
    rod = rod_inputs(model, solution.load)
    states = np.empty((model.stations, 15 + 2 * model.tendon_count))
    strains = np.empty((model.stations, 6))
    strains[0] = solution.strains[0]  # the base strains to start from, as a shooting solve's integrations have
    m0 = np.asarray(solution.base_moment_nm, dtype=float)
    kernel.integrate_repeatedly(m0, rod, states, strains, 1)
    best = None
    for _ in range(rounds):
        with Stopwatch() as watch:
            kernel.integrate_repeatedly(m0, rod, states, strains, count)
        if best is None or watch.cpu_s < best.cpu_s:
            best = watch
    if best is None:
        raise ValueError(f"rounds = {rounds!r}: must be >= 1")
    return best.cpu_s / count, best.wall_s / count


def _standin_executable() -> Path:
    def build(tmp: Path, compiler: str) -> None:
        result = subprocess.run([compiler, *_STANDIN_FLAGS, "-o", str(tmp / "rk4_standin"), str(_STANDIN)],
                                capture_output=True, text=True, check=False)
        if result.returncode != 0:
            raise NativeBuildError(f"building the RK4 stand-in failed:\n{result.stderr.strip()}")

    return build_cached("rk4_standin", [_STANDIN], _STANDIN_FLAGS, build, what="the benchmark's RK4 stand-in")


def standin_integration(model: RodModel, solution, *, count: int = 2000) -> tuple[float, np.ndarray]:
    """(CPU s per integration, tip position m) of the C++ RK4 stand-in (``native/rk4_standin.cpp``)
    integrating ``model`` from a solution's base strains, at the model's step count.

    The stand-in integrates R&W's (v, u) form with distributed weight and tendons to the tip; a
    model with point masses, tendon ends before the tip or friction is refused.
    """
    if model.point_masses or model.friction_coeff or any(t.end_m is not None for t in model.tendons):
        raise ValueError("standin_integration: the stand-in models no point masses, tendon ends or friction")
    load = solution.load
    a = model.arrays
    weight = model.line_mass_kg_per_m * a["grav"]
    table = a["tendons"]
    args = [model.stations - 1, count, model.length_m, *a["kse"], *a["kbt"], *weight,
            *load.base_rotation.reshape(-1), *solution.strains[0], model.tendon_count]
    for row, tau in zip(table, load.tensions_n):
        args += [row[kernel.T_R0], row[kernel.T_R1], row[kernel.T_ALPHA], row[kernel.T_OMEGA], tau]
    result = subprocess.run([str(_standin_executable()), *(repr(float(x)) if not isinstance(x, int) else str(x)
                                                             for x in args)],
                            capture_output=True, text=True, check=True)
    fields = result.stdout.split()
    return float(fields[0]), np.array([float(x) for x in fields[1:4]]) + load.base_position_m


def bench_peers(params: Params | None = None, *, rounds: int = 5) -> dict:
    """The kernel beside a plain C++ RK4 stand-in for the Eigen integrators of Till's examples.

    Both integrate the same rod (the parameter set's, without its point masses, friction and
    early tendon ends, which the stand-in does not model) from the same base strains at the same
    step count; the stand-in is compiled with g++ -O3 at the first run. Alternating ``rounds``
    runs of each, the fastest of each is kept.

    Returns:
        ``integration_s`` (kernel, CPU s per integration), ``standin_integration_s``,
        ``integration_ratio`` (kernel over stand-in: at most 1 is as fast or faster),
        ``tip_difference_m`` (the two tips; both are RK4 at this step count, of different forms of
        the same equations), ``steps``.
    """
    params = params or load_params()
    model = RodModel.from_params(params, with_effects=False)
    model = model.replace(point_masses=(), friction_coeff=0.0,
                          tendons=tuple(t.__class__(t.radius_m, t.angle_deg, t.helix_rad_per_m, t.tip_radius_m)
                                        for t in model.tendons))
    sol = solve(model, pcc_tensions_n(13.0, 30.0, params), base_rotation=params.rig.base_rotation)
    ours, theirs, ours_wall = [], [], []
    tip = None
    for _ in range(rounds):
        cpu, wall = integration_s(model, sol, rounds=1)
        ours.append(cpu)
        ours_wall.append(wall)
        per, tip = standin_integration(model, sol)
        theirs.append(per)
    return {
        "integration_s": min(ours),
        "standin_integration_s": min(theirs),
        "integration_ratio": min(ours) / min(theirs),
        "tip_difference_m": float(np.linalg.norm(tip - sol.tip_position_m)),
        "integration_wall_s": min(ours_wall),
        "steps": model.stations - 1,
        "tendons": model.tendon_count,
    }
