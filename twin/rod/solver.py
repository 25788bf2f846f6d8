"""Shooting solver with warm starts and continuation; result types.

A solve never hands back an unconverged shape as an answer: :func:`solve` raises
:class:`ConvergenceError` (with the residual) unless ``raise_on_failure=False``, in which
case the returned :class:`RodSolution` has ``converged=False`` and NaN geometry.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import numpy as np

from twin.checks import finite_vector
from twin.rod import kernel
from twin.rod.kernel import RodInputs, SolverStatus
from twin.rod.model import RodModel

__all__ = ["ConvergenceError", "NewtonIteration", "RodSolution", "LoadCase", "SolverStatus", "rod_inputs",
           "solve", "solve_batch", "Predictor"]


@dataclasses.dataclass(frozen=True)
class NewtonIteration:
    """One iteration of the shooting Newton solve (the counterpart of ``mujoco.minimize.IterLog``).

    Attributes:
        load_factor: continuation factor λ of the shooting run it belongs to (1: the full load).
        iteration: index within that run; 0 is the starting guess.
        residual_nm: tip moment residual |m(L) − M_e| (N·m) at the start of the iteration.
        step_fraction: line-search factor α of the Newton step accepted from it (1: the full
            step); 0 when none was (the run ended here, or the step was rejected).
        step_nm: size |Δm(0)| (N·m) of that accepted step; 0 when none was.
        fresh_jacobian: ∂res/∂m0 was recomputed by finite differences for this step; False when
            the Broyden-updated one carried over was used.
    """

    load_factor: float
    iteration: int
    residual_nm: float
    step_fraction: float
    step_nm: float
    fresh_jacobian: bool


def _iterations(log) -> tuple[NewtonIteration, ...]:
    """The trace of a solve from its runs' (load factor, kernel trace rows) pairs."""
    return tuple(
        NewtonIteration(load_factor=lam, iteration=i, residual_nm=float(row[kernel.TR_RESIDUAL]),
                        step_fraction=float(row[kernel.TR_STEP_FRACTION]), step_nm=float(row[kernel.TR_STEP]),
                        fresh_jacobian=bool(row[kernel.TR_FRESH]))
        for lam, rows in log for i, row in enumerate(rows)
    )


class ConvergenceError(RuntimeError):
    """The boundary-value problem was not solved to tolerance.

    Attributes:
        residual_nm: tip moment residual |m(L) − M_e| (N·m) at the best iterate.
        iterations: Newton iterations spent.
        status: what stopped the solver.
        trace: every Newton iteration of the solve, in order (its last ``residual_nm`` is this one's).
    """

    def __init__(self, message: str, *, residual_nm: float, iterations: int, status: SolverStatus,
                 trace: tuple[NewtonIteration, ...] = ()):
        super().__init__(message)
        self.residual_nm = residual_nm
        self.iterations = iterations
        self.status = status
        self.trace = trace


@dataclasses.dataclass(frozen=True)
class LoadCase:
    """What acts on the rod: tendon tensions at the base, tip loads, base pose (all SI, world frame).

    ``friction_direction`` per tendon: the sliding state σ of the friction, +1 pulled (tension
    lost towards the tip), −1 released, between them part of the way through a reversal (the
    Dahl state :class:`twin.effects.SlidingState` records), 0 no friction; used only when the
    model has a friction coefficient.
    """

    tensions_n: np.ndarray
    tip_force_n: np.ndarray
    tip_moment_nm: np.ndarray
    base_rotation: np.ndarray
    base_position_m: np.ndarray
    friction_direction: np.ndarray

    @classmethod
    def make(cls, model: RodModel, tensions_n, *, tip_force_n=None, tip_moment_nm=None,
             base_rotation=None, base_position_m=None, friction_direction=None) -> "LoadCase":
        # Checked in plain Python floats: a load is a handful of numbers, and numpy's per-call
        # overhead on them would cost more than the rod's integration.
        nt = model.tendon_count
        tensions = finite_vector("tensions_n", tensions_n, nt)
        if any(t < 0 for t in tensions.tolist()):
            raise ValueError(f"tensions_n = {tensions.tolist()}: tendons only pull; tensions must be >= 0")
        if base_rotation is None:
            rot = np.eye(3)
        else:
            rot = np.ascontiguousarray(base_rotation, dtype=float)
            if rot.shape != (3, 3) or not (rot.tobytes() in _ROTATIONS or _is_rotation(rot.tolist())):
                raise ValueError(f"base_rotation = {rot.tolist()}: must be a proper 3x3 rotation")
        if friction_direction is None:
            direction = np.ones(nt)
        else:
            direction = np.clip(finite_vector("friction_direction", friction_direction, nt), -1.0, 1.0)
        return _built(
            cls,
            tensions_n=tensions,
            tip_force_n=np.zeros(3) if tip_force_n is None else finite_vector("tip_force_n", tip_force_n, 3),
            tip_moment_nm=np.zeros(3) if tip_moment_nm is None else finite_vector("tip_moment_nm", tip_moment_nm, 3),
            base_rotation=rot,
            base_position_m=np.zeros(3) if base_position_m is None else finite_vector("base_position_m", base_position_m, 3),
            friction_direction=direction,
        )

    def scaled(self, factor: float) -> "LoadCase":
        """Tensions and tip loads scaled by ``factor`` (the continuation parameter)."""
        return dataclasses.replace(self, tensions_n=self.tensions_n * factor,
                                   tip_force_n=self.tip_force_n * factor,
                                   tip_moment_nm=self.tip_moment_nm * factor)


def _built(cls, **fields):
    """An instance of the frozen dataclass ``cls`` from all of its ``fields``, without the generated
    ``__init__``, whose ``object.__setattr__`` per field costs a frozen dataclass of 19 fields
    ~4 µs: a few percent of a warm solve. Only for classes without ``__post_init__``, given every
    field (``tests/test_rod.py`` checks both)."""
    obj = object.__new__(cls)
    obj.__dict__.update(fields)
    return obj


# The bytes of base rotations already found proper (a stream passes the same one every time);
# bounded, since a caller may pass a new rotation with every solve.
_ROTATIONS: set[bytes] = set()


def _is_rotation(r: list[list[float]]) -> bool:
    """Orthonormal to 1e-9 (np.allclose's test, element by element: 1e-9 + 1e-5 on the diagonal)
    and proper (determinant > 0), for a 3×3 given as nested lists; remembered in ``_ROTATIONS``."""
    for i in range(3):
        for j in range(i, 3):
            dot = r[i][0] * r[j][0] + r[i][1] * r[j][1] + r[i][2] * r[j][2]
            if not abs(dot - (i == j)) <= 1e-9 + 1e-5 * (i == j):
                return False
    a, b, c = r
    det = (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
           + a[2] * (b[0] * c[1] - b[1] * c[0]))
    if not det > 0:
        return False
    if len(_ROTATIONS) < 64:
        _ROTATIONS.add(np.array(r, dtype=float).tobytes())
    return True


@dataclasses.dataclass(frozen=True)
class RodSolution:
    """A converged static shape (or, with ``converged=False``, a report of the failure).

    Attributes:
        s_m: station arc lengths (m), (K,).
        positions_m: backbone positions p(s), world frame (K, 3).
        rotations: backbone rotations R(s), body → world (K, 3, 3).
        internal_force_n, internal_moment_nm: total section force n(s) and moment m(s)
            (rod + tendons, world frame) (K, 3).
        strains: (v, u) at the stations (K, 6): shear/extension and curvature/twist (1, 1/m).
        tip_position_m, tip_rotation: p(L) (3,), R(L) (3, 3).
        tendon_lengths_m: path length of each tendon from the base to its termination (nt,).
        tendon_tensions_n: tension of each tendon along s (K, nt) (varies only with friction).
        base_moment_nm: the solved m(0), reusable as a warm start.
        converged, residual_nm, iterations, integrations, continuation_steps, solve_time_s.
        status: the :class:`SolverStatus` that ended the (last) shooting run.
        trace: every Newton iteration of the solve, in order, as :class:`NewtonIteration`
            (built on first access); the last one's ``residual_nm`` is this solution's.
        load: the :class:`LoadCase` that was solved.
        shooting_jacobian: (3, 3) ∂(tip moment residual)/∂m(0) (1) as the solve left it (finite
            differences kept current by Broyden updates), reusable with the warm start
            (``solve(..., guess_jacobian=...)``); None when the solve failed. Too rough for
            sensitivities: :func:`twin.rod.tip_jacobian` computes its own.
    """

    s_m: np.ndarray
    positions_m: np.ndarray
    rotations: np.ndarray
    internal_force_n: np.ndarray
    internal_moment_nm: np.ndarray
    strains: np.ndarray
    tendon_lengths_m: np.ndarray
    tendon_tensions_n: np.ndarray
    base_moment_nm: np.ndarray
    converged: bool
    status: SolverStatus
    residual_nm: float
    iterations: int
    integrations: int
    continuation_steps: int
    solve_time_s: float
    load: LoadCase
    shooting_jacobian: np.ndarray | None = None
    # The kernel's trace rows per shooting run, (load factor, (n, TRACE_COLUMNS) array), from
    # which ``trace`` is built on first access: most solves' traces are never read.
    trace_log: tuple[tuple[float, np.ndarray], ...] = dataclasses.field(default=(), repr=False, compare=False)

    @functools.cached_property
    def trace(self) -> tuple[NewtonIteration, ...]:
        return _iterations(self.trace_log)

    @property
    def tip_position_m(self) -> np.ndarray:
        return self.positions_m[-1]

    @property
    def tip_rotation(self) -> np.ndarray:
        return self.rotations[-1]

    def to_dict(self) -> dict:
        """JSON-ready summary (the ``twin predict --json`` keys)."""
        return {
            "tip_position_m": self.tip_position_m.tolist(),
            "tip_rotation": self.tip_rotation.tolist(),
            "converged": self.converged,
            "status": self.status.label,
            "residual": self.residual_nm,
            "iterations": self.iterations,
            "continuation_steps": self.continuation_steps,
            "solve_time_s": self.solve_time_s,
            "tendon_lengths_m": self.tendon_lengths_m.tolist(),
            "backbone_positions_m": self.positions_m.tolist(),
            "s_m": self.s_m.tolist(),
        }


def rod_inputs(model: RodModel, load: LoadCase) -> RodInputs:
    """The kernels' :class:`~twin.rod.kernel.RodInputs` for this model and load (its own tendon table)."""
    a = model.arrays
    tendons = a["tendons"].copy()
    tendons[:, kernel.T_TAU] = load.tensions_n
    tendons[:, kernel.T_SIGMA] = load.friction_direction
    return RodInputs(
        base_position_m=load.base_position_m, base_rotation=load.base_rotation, nodes=a["nodes"],
        intervals=a["intervals"], kse=a["kse"], kbt=a["kbt"], tendons=tendons, length_m=model.length_m,
        friction_coeff=model.friction_coeff, tip_force_n=load.tip_force_n, tip_moment_nm=load.tip_moment_nm,
        gravity_m_s2=a["grav"], line_mass_kg_per_m=model.line_mass_kg_per_m, point_mass_s_m=a["pm_s"],
        point_mass_kg=a["pm_m"], precurvature_per_m=a["ustar"], routes=a["routes"],
    )


def _run(model: RodModel, rod: RodInputs, m0: np.ndarray, states, strains, log: list,
         jac: np.ndarray | None = None, load_factor: float = 1.0):
    """Shoot from m0 (updated in place) for the load case in ``rod``; ``jac``, if given, is the
    ∂res/∂m0 to start from. Appends (``load_factor``, the run's trace rows) to ``log``.

    Returns (status code, residual N·m, iterations, integrations, the final ∂res/∂m0)."""
    tol = model.tolerance * model.moment_scale_nm
    out = np.array(jac, dtype=float) if jac is not None else np.zeros((3, 3))
    trace = np.empty((model.max_iterations + 1, kernel.TRACE_COLUMNS))
    try:
        code, res, iters, calls, rows = kernel.shoot(m0, rod, states, strains, tol,
                                                     model.max_iterations, 1e-7 * model.moment_scale_nm, out,
                                                     jac is not None, trace)
    except ZeroDivisionError:
        # A stiffness that underflowed to 0 (a fit's trial with an undetermined modulus run off to
        # 1e-280): the rod cannot be integrated, which is the caller's failed solve, not a crash.
        log.append((load_factor, trace[:0]))
        return int(kernel.SolverStatus.INTEGRATION_FAILED), float("inf"), 0, 1, out
    log.append((load_factor, trace[:rows]))
    return code, res, iters, calls, out


def _initial_guess(model: RodModel, load: LoadCase) -> np.ndarray:
    """Base moment of the straight rod: the tendon moments plus the moment of the loads about the base."""
    return _initial_guesses(model, load.base_rotation, load.tensions_n[None], load.tip_force_n[None],
                            load.tip_moment_nm[None])[0]


def _initial_guesses(model: RodModel, rotation: np.ndarray, tensions_n: np.ndarray, tip_force_n: np.ndarray,
                     tip_moment_nm: np.ndarray) -> np.ndarray:
    """:func:`_initial_guess` for m load cases at once: (m, nt) tensions, (m, 3) tip force and moment."""
    # Σ r_i × τ_i e_z in the body frame, r_i = ρ_i (cos α_i, sin α_i, 0).
    table = model.arrays["tendons"]
    lever = tensions_n * table[:, kernel.T_R0]
    body = np.stack([lever @ np.sin(table[:, kernel.T_ALPHA]), -(lever @ np.cos(table[:, kernel.T_ALPHA])),
                     np.zeros(len(tensions_n))], axis=1)
    axis = rotation[:, 2]
    # The weight's moment: axis × g times its first moment about the base, Σ s m.
    first_moment = model.line_mass_kg_per_m * model.length_m ** 2 / 2 + sum(s * mass for s, mass in model.point_masses)
    g = np.array([0.0, 0.0, -model.gravity_m_s2])
    return body @ rotation.T + np.cross(axis, model.length_m * tip_force_n + first_moment * g) + tip_moment_nm


def _load_moments(model: RodModel, rotation: np.ndarray, tensions_n: np.ndarray, tip_force_n: np.ndarray,
                  tip_moment_nm: np.ndarray) -> np.ndarray:
    """An estimate of m(0) (N·m, world) for m load cases: (m, nt) tensions, (m, 3) tip force and moment.

    The tendons' terminations are internal forces (:mod:`twin.rod.kernel`), so m(0) is the
    moment of the external loads about the base in the shape they leave:
    M_e + (p(L) − p(0)) × F_e + Σ m_k (p_k − p(0)) × g over the rod's mass. The shape taken is
    the arc the tendons alone bend the weightless rod into: body-frame curvature
    u = −K_bt⁻¹ Σ τ_i r_i × e_z at their base radii, constant along the rod. On the endoscope's
    validation grid it lies within 2.5 % (median) of the solved m(0); :func:`solve_batch` moves
    a solved neighbour's m(0) by the difference of two. Not the cold start: where the arc curls
    through turns (60 N on one endoscope tendon) the first integration from it fails, where the
    straight rod's :func:`_initial_guesses` integrates.
    """
    table = model.arrays["tendons"]
    lever = tensions_n * table[:, kernel.T_R0]
    ei = model.bending_stiffness_nm2
    ux = -(lever @ np.sin(table[:, kernel.T_ALPHA])) / ei
    uy = (lever @ np.cos(table[:, kernel.T_ALPHA])) / ei
    kappa = np.hypot(ux, uy)
    bent = kappa > 0.0
    safe = np.where(bent, kappa, 1.0)
    # The arc's body-frame bending direction d (u × e_z / κ) and, at arc length s, its offset
    # from the base along d, (1 − cos κs)/κ, and along e_z, sin(κs)/κ, with the integrals of
    # both over [0, L] for the rod's own weight; sin²-forms keep them exact as κ → 0.
    d = np.stack([np.where(bent, uy / safe, 0.0), np.where(bent, -ux / safe, 0.0), np.zeros_like(ux)], axis=1)
    ez = np.array([0.0, 0.0, 1.0])

    def offset(s: float) -> np.ndarray:
        half = 0.5 * kappa * s
        sinc = np.sinc(half / np.pi)  # sin(κs/2) / (κs/2)
        across = 0.5 * kappa * s * s * sinc * sinc  # 2 sin²(κs/2) / κ
        along = s * np.sinc(kappa * s / np.pi)  # sin(κs) / κ
        return across[:, None] * d + along[:, None] * ez

    length = model.length_m
    x = kappa * length
    # ∫ (1 − cos κs)/κ ds = (κL − sin κL)/κ², ∫ sin(κs)/κ ds = (1 − cos κL)/κ²; series where κL is tiny.
    small = x < 1e-3
    xs = np.where(small, 1.0, x)
    across_int = np.where(small, length ** 3 * kappa / 6.0 * (1 - x * x / 20.0),
                          length ** 2 * (xs - np.sin(xs)) / xs ** 2)
    sinc = np.sinc(0.5 * x / np.pi)
    along_int = 0.5 * length ** 2 * sinc * sinc
    moment = model.line_mass_kg_per_m * (across_int[:, None] * d + along_int[:, None] * ez)
    for s, mass in model.point_masses:
        moment = moment + mass * offset(s)
    g = np.array([0.0, 0.0, -model.gravity_m_s2])
    tip = offset(length) @ rotation.T
    return np.cross(tip, tip_force_n) + np.cross(moment @ rotation.T, g) + tip_moment_nm


def solve(model: RodModel, tensions_n, *, tip_force_n=None, tip_moment_nm=None, base_rotation=None,
          base_position_m=None, friction_direction=None, guess_nm=None, guess_jacobian=None,
          continuation: bool = True, raise_on_failure: bool = True) -> RodSolution:
    """Solve the static shape of the rod under tendon tensions, gravity and tip loads.

    Args:
        model: the rod (see :meth:`RodModel.from_params`).
        tensions_n: tendon tensions at the base (N), one per ``model.tendons``.
        tip_force_n, tip_moment_nm: external tip force (N) and moment (N·m), world frame.
        base_rotation: base orientation (3×3, body → world); default identity ("up").
        base_position_m: base position (m), world frame.
        friction_direction: per tendon sliding state, +1 pulled … −1 released (only with friction).
        guess_nm: base moment m(0) to start from (warm start), e.g. a previous ``base_moment_nm``.
        guess_jacobian: with ``guess_nm``, that solution's ``shooting_jacobian``: Newton then
            starts with Broyden updates of it (one integration per iteration) instead of finite
            differences (four); a stale one is replaced on its own.
        continuation: if the direct solve fails, step the loads up from a solved smaller case.
        raise_on_failure: raise :class:`ConvergenceError` (default) instead of returning a
            ``converged=False`` report.

    Returns:
        The :class:`RodSolution`.

    Raises:
        ConvergenceError: no solution to tolerance (with the residual), if ``raise_on_failure``.
        ValueError: malformed input (names the argument and value).
    """
    load = LoadCase.make(model, tensions_n, tip_force_n=tip_force_n, tip_moment_nm=tip_moment_nm,
                         base_rotation=base_rotation, base_position_m=base_position_m,
                         friction_direction=friction_direction)
    if guess_jacobian is not None:
        guess_jacobian = np.asarray(guess_jacobian, dtype=float)
        # Nine numbers: checked as Python floats, cheaper than numpy's reductions on so few.
        if guess_nm is None or guess_jacobian.shape != (3, 3) or not all(map(math.isfinite, guess_jacobian.ravel().tolist())):
            raise ValueError(f"guess_jacobian = {np.asarray(guess_jacobian).tolist()!r}: expected the 3x3 "
                             "shooting_jacobian of a converged solution, with its guess_nm")
    return _solve_load(model, load, guess_nm, continuation, raise_on_failure, guess_jacobian)


def _solve_load(model, load, guess_nm, continuation, raise_on_failure, guess_jacobian=None) -> RodSolution:
    start = time.perf_counter()
    k = model.stations
    nt = model.tendon_count
    states = np.empty((k, 15 + 2 * nt))
    strains = np.empty((k, 6))
    strains[0] = np.nan  # no base strains to start from (kernel.integrate)
    # Both are fresh arrays, which the solve updates in place.
    m0 = _initial_guess(model, load) if guess_nm is None else np.array(guess_nm, dtype=float)
    log: list[tuple[float, np.ndarray]] = []
    rod = rod_inputs(model, load)
    code, res, iters, calls, jac = _run(model, rod, m0, states, strains, log, guess_jacobian)
    steps_taken = 0
    if code != 0 and guess_nm is not None:
        m0 = _initial_guess(model, load)
        code, res, it2, c2, jac = _run(model, rod, m0, states, strains, log)
        iters, calls = iters + it2, calls + c2
    if code != 0 and continuation:
        code, res, it2, c2, steps_taken, m0, jac = _continuation(model, load, states, strains, log)
        iters, calls = iters + it2, calls + c2
    elapsed = time.perf_counter() - start
    status = _STATUSES[code]
    if code != 0:
        if raise_on_failure:
            raise ConvergenceError(
                f"rod solve failed ({status.label}) after {iters} iterations and {steps_taken} continuation "
                f"steps: tip moment residual {res:.3e} N·m (tolerance "
                f"{model.tolerance * model.moment_scale_nm:.1e} N·m)",
                residual_nm=float(res), iterations=iters, status=status, trace=_iterations(log),
            )
        states[:] = np.nan
        strains[:] = np.nan
    return _package(model, load, states, strains, m0, code == 0, status, float(res), iters, calls,
                    steps_taken, elapsed, jac if code == 0 else None, tuple(log))


# Indexed by the kernel's status code (every solve converts one).
_STATUSES = tuple(SolverStatus)


def _continuation(model, load, states, strains, log):
    """Step the load factor λ from 0 to 1, halving the step on failure (warm start each time)."""
    lam, step = 0.0, 0.25
    m0 = _initial_guess(model, load.scaled(0.0))
    iters = calls = steps = 0
    code, res, it, c, jac = _run(model, rod_inputs(model, load.scaled(0.0)), m0, states, strains, log,
                                 load_factor=0.0)
    iters, calls = iters + it, calls + c
    if code != 0:
        return code, res, iters, calls, steps, m0, jac
    while lam < 1.0:
        target = min(1.0, lam + step)
        trial = m0.copy()
        code, res, it, c, jac = _run(model, rod_inputs(model, load.scaled(target)), trial, states, strains, log,
                                     load_factor=target)
        iters, calls, steps = iters + it, calls + c, steps + 1
        if code == 0:
            lam, m0 = target, trial
            step = min(step * 1.5, 0.5)
        else:
            step *= 0.5
            if step < 1e-3:
                return code, res, iters, calls, steps, m0, jac
    return 0, res, iters, calls, steps, m0, jac


def _package(model, load, states, strains, m0, converged, status, res, iters, calls, steps, elapsed, jac=None, log=()):
    # ``states`` and ``strains`` belong to this solve alone: the solution keeps views of them.
    a = model.arrays
    nt = model.tendon_count
    k = states.shape[0]
    # n(s) = F_e + (weight distal to s) g.
    forces = load.tip_force_n + a["distal_weight_n"]
    if model.friction_coeff:
        tensions = load.tensions_n * np.exp(-model.friction_coeff * load.friction_direction * states[:, 15:15 + nt])
    else:
        tensions = _rows_of(load.tensions_n, k)  # constant along s
    return _built(
        RodSolution,
        s_m=a["nodes"].copy(),
        positions_m=states[:, 0:3],
        rotations=states[:, 3:12].reshape(k, 3, 3),
        internal_force_n=forces,
        internal_moment_nm=states[:, 12:15],
        strains=strains,
        tendon_lengths_m=states[-1, 15 + nt:15 + 2 * nt],
        tendon_tensions_n=tensions,
        base_moment_nm=m0.copy(),
        converged=converged,
        status=status,
        residual_nm=res,
        iterations=iters,
        integrations=calls,
        continuation_steps=steps,
        solve_time_s=elapsed,
        load=load,
        shooting_jacobian=jac,
        trace_log=log,
    )


def _rows_of(row: np.ndarray, k: int) -> np.ndarray:
    """``row`` repeated ``k`` times as a read-only (k, n) view of it: what ``np.broadcast_to``
    gives, without its ~9 µs of argument handling on a warm solve of ~120 µs."""
    if row.dtype != np.float64 or row.ndim != 1 or row.strides != (8,):
        return np.broadcast_to(row, (k, row.shape[0]))
    view = np.ndarray((k, row.shape[0]), np.float64, row, 0, (0, 8))
    view.flags.writeable = False
    return view


def _rows(value, m, n, name, default=0.0) -> np.ndarray:
    """``value`` as an (m, n) array of finite numbers: one row per case, or one row for all."""
    if value is None:
        return np.full((m, n), default)
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 1 and arr.size == n:
        arr = np.broadcast_to(arr, (m, n))
    if arr.shape != (m, n) or not np.isfinite(arr).all():
        raise ValueError(f"{name} = {np.asarray(value).tolist()!r}: expected {n} finite numbers, or {m} rows of them")
    return np.ascontiguousarray(arr)


def solve_batch(model: RodModel, tensions_n, *, tip_force_n=None, tip_moment_nm=None, base_rotation=None,
                base_position_m=None, friction_direction=None, guesses=None, chain: bool = True,
                continuation: bool = True, raise_on_failure: bool = True) -> list[RodSolution]:
    """Solve many load cases of one rod in one compiled call: what :func:`solve` gives for each.

    The cases run one after another inside the kernel (no Python between them); with ``chain``
    each case without a guess starts from the converged earlier case nearest to it (by the
    estimates of m(0) :func:`_load_moments` gives, the moments of the loads about the base): that
    case's base moment moved by the difference of the two estimates, and its shooting Jacobian.
    This makes neighbouring cases (a sweep, a dataset's rows, a fit's repeated evaluations) cost
    a few integrations each, and a load met before (the same tensions under another plane's
    label) one. A case whose warm start
    fails is retried cold, and one that still fails goes through :func:`solve`'s continuation.

    Args:
        model: the rod.
        tensions_n: (m, nt) tendon tensions at the base (N), one row per case.
        tip_force_n, tip_moment_nm: (3,) for every case or (m, 3) per case (N, N·m, world frame).
        base_rotation, base_position_m: the base pose, shared by the cases.
        friction_direction: (nt,) or (m, nt) sliding states (see :class:`LoadCase`).
        guesses: None, or one entry per case: a converged :class:`RodSolution` to start from
            (its base moment and shooting Jacobian), or None for that case.
        chain: warm-start a case without a guess from the nearest solved case's solution.
        continuation, raise_on_failure: as for :func:`solve`.

    Returns:
        One :class:`RodSolution` per case, in order; ``solve_time_s`` is each case's share of the
        compiled call (wall time) plus its own continuation, if any.

    Raises:
        ConvergenceError: a case has no solution to tolerance, if ``raise_on_failure``.
        ValueError: malformed input (names the argument and value).
    """
    start = time.perf_counter()
    nt = model.tendon_count
    tensions = np.asarray(tensions_n, dtype=float)
    if tensions.ndim != 2 or tensions.shape[1] != nt or not np.isfinite(tensions).all():
        raise ValueError(f"tensions_n: expected (cases, {nt}) finite tensions, got shape {tensions.shape}")
    if (tensions < 0).any():
        raise ValueError(f"tensions_n: tendons only pull; tensions must be >= 0 (min {tensions.min()!r})")
    m = tensions.shape[0]
    forces = _rows(tip_force_n, m, 3, "tip_force_n")
    moments = _rows(tip_moment_nm, m, 3, "tip_moment_nm")
    sigma = np.clip(_rows(friction_direction, m, nt, "friction_direction", default=1.0), -1.0, 1.0)
    if guesses is not None and len(guesses) != m:
        raise ValueError(f"guesses: expected {m} entries (a RodSolution or None each), got {len(guesses)}")
    pose = LoadCase.make(model, tensions[0] if m else np.zeros(nt), base_rotation=base_rotation,
                         base_position_m=base_position_m)
    loads = [LoadCase(tensions_n=tensions[i], tip_force_n=forces[i], tip_moment_nm=moments[i],
                      base_rotation=pose.base_rotation, base_position_m=pose.base_position_m,
                      friction_direction=sigma[i]) for i in range(m)]
    cold = _initial_guesses(model, pose.base_rotation, tensions, forces, moments)
    estimates = _load_moments(model, pose.base_rotation, tensions, forces, moments)
    guess_m0 = np.zeros((m, 3))
    guess_jac = np.zeros((m, 3, 3))
    kind = np.zeros(m, dtype=np.int64)
    for i, guess in enumerate(guesses or ()):
        if guess is not None and guess.converged:
            guess_m0[i] = guess.base_moment_nm
            kind[i] = 1
            if guess.shooting_jacobian is not None:
                guess_jac[i] = guess.shooting_jacobian
                kind[i] = 2
    k = model.stations
    states = np.empty((m, k, 15 + 2 * nt))
    strains = np.empty((m, k, 6))
    strains[:, 0] = np.nan  # no base strains to start from (kernel.integrate)
    m0 = np.empty((m, 3))
    jac = np.zeros((m, 3, 3))
    traces = np.empty((m, 2, model.max_iterations + 1, kernel.TRACE_COLUMNS))
    out = np.zeros((m, 7))
    rod = rod_inputs(model, pose)._replace(tip_force_n=np.zeros(3), tip_moment_nm=np.zeros(3))
    kernel.shoot_batch(rod, tensions, sigma, forces, moments, cold, estimates, guess_m0, guess_jac, kind, chain,
                       model.tolerance * model.moment_scale_nm, model.max_iterations,
                       1e-7 * model.moment_scale_nm, m0, jac, states, strains, traces, out)
    share = (time.perf_counter() - start) / max(m, 1)
    solutions = []
    for i in range(m):
        code = int(out[i, 0])
        if code != 0:
            sol = _solve_load(model, loads[i], None, continuation, raise_on_failure)
            solutions.append(dataclasses.replace(sol, solve_time_s=sol.solve_time_s + share))
            continue
        log = [(1.0, traces[i, 0, :int(out[i, 4])])]
        if out[i, 5]:
            log.append((1.0, traces[i, 1, :int(out[i, 5])]))
        solutions.append(_package(model, loads[i], states[i], strains[i], m0[i], True, SolverStatus.CONVERGED,
                                  float(out[i, 1]), int(out[i, 2]), int(out[i, 3]), 0, share, jac[i], tuple(log)))
    return solutions


class Predictor:
    """A warm-started predictor for a stream of slowly changing load cases (e.g. 40 Hz telemetry).

    Each solve starts from the previous solution's base moment; a failed warm start falls back
    to a cold start and continuation, so a stream never silently returns a stale shape.
    """

    def __init__(self, model: RodModel):
        self.model = model
        self._guess: RodSolution | None = None

    def reset(self) -> None:
        self._guess = None

    def solve(self, tensions_n, *, tip_force_n=None, tip_moment_nm=None, base_rotation=None, base_position_m=None,
              friction_direction=None, continuation: bool = True, raise_on_failure: bool = True) -> RodSolution:
        """:func:`solve` of the next load case, warm-started from the last converged one (its own
        base moment and shooting Jacobian, which need no checking)."""
        last = self._guess
        load = LoadCase.make(self.model, tensions_n, tip_force_n=tip_force_n, tip_moment_nm=tip_moment_nm,
                             base_rotation=base_rotation, base_position_m=base_position_m,
                             friction_direction=friction_direction)
        sol = _solve_load(self.model, load, None if last is None else last.base_moment_nm, continuation,
                          raise_on_failure, None if last is None else last.shooting_jacobian)
        if sol.converged:
            self._guess = sol
        return sol
