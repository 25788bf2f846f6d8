"""Compiled kernels of the coupled Cosserat rod–tendon statics (Numba).

Formulation. Rucker & Webster (2011) integrate the rod's strains with the tendon loads as
distributed forces. Here the section is cut through the rod *and* its tendons together: the
tendon–disc contact forces (and friction) are then internal, so the total internal force
n(s) and moment m(s) (world frame, what the distal part exerts on the proximal part, moment
about p(s)) obey the plain rod balance

    n' = −f_e                  m' = −p' × n − l_e                    (R&W 2011, eq. 5)

and the tendons enter only the constitutive law, in the body frame:

    Rᵀ n = K_se (v − v*) + Σ τ_i t_i          t_i = q_i / |q_i|,  q_i = u × r_i + r_i' + v
    Rᵀ m = K_bt (u − u*) + Σ τ_i r_i × t_i                            (R&W 2011, eqs. 9, 12)

with v* = (0, 0, 1) and u* the rod's intrinsic (unloaded) curvature, constant along it (zero for
a straight rod).

which is solved for (v, u) by Newton at every stage (its Jacobian is R&W's
[[K_se + A, G], [B, K_bt + H]] matrix). The free tip gives n(L) = F_e, m(L) = M_e because the
tendon termination forces are internal too. Since f_e (weight) does not depend on the shape,
n(s) is known in closed form, and only the base moment m(0) (3 unknowns) is shot for.

Tendon friction (capstan) is carried as each tendon's accumulated wrap angle w_i(s), with
w_i' = |u × t_i| and τ_i(s) = τ_i(0) exp(−μ σ_i w_i(s)), σ_i = +1 while the tendon is pulled
(tension lost towards the tip) and −1 while it is released.

State layout per station: p (3), R (9, row-major), m (3), w (nt), ℓ (nt) — tendon path
lengths from the base.

The kernels read the rod and its load case from one :class:`RodInputs`, a named tuple, whose
fields compiled code reads as it would positional arguments.
"""

from __future__ import annotations

import enum
from typing import NamedTuple

import numpy as np
from numba import njit

# Tendon table columns: base radius (m), tip radius (m), base angle (rad), helix rate (rad/m),
# termination s (m), tension at the base (N), friction direction σ (−1, 0, +1).
T_R0, T_R1, T_ALPHA, T_OMEGA, T_END, T_TAU, T_SIGMA = range(7)
TENDON_COLUMNS = 7

# Columns of the Newton trace :func:`shoot` fills, one row per iteration: tip moment residual
# norm at its start (N·m), line-search factor α of the step accepted from it (0: none), that
# step's size |Δm(0)| (N·m), 1.0 if ∂res/∂m0 was recomputed by finite differences for it.
TR_RESIDUAL, TR_STEP_FRACTION, TR_STEP, TR_FRESH = range(4)
TRACE_COLUMNS = 4

_LOCAL_MAX_ITER = 20
_LOCAL_TOL = 1e-13


class SolverStatus(enum.IntEnum):
    """What stopped a shooting solve; the values are the codes :func:`shoot` returns."""

    CONVERGED = 0
    ITERATION_LIMIT = 1
    INTEGRATION_FAILED = 2  # at the starting guess
    LINE_SEARCH_STALLED = 3  # also: a finite-difference Jacobian could not be formed

    @property
    def label(self) -> str:
        """Human-readable form, e.g. ``"iteration limit"`` (the ``twin predict`` output)."""
        return self.name.lower().replace("_", " ")


# Plain ints for the compiled code (Numba freezes globals at compile time).
_CONVERGED = int(SolverStatus.CONVERGED)
_ITERATION_LIMIT = int(SolverStatus.ITERATION_LIMIT)
_INTEGRATION_FAILED = int(SolverStatus.INTEGRATION_FAILED)
_LINE_SEARCH_STALLED = int(SolverStatus.LINE_SEARCH_STALLED)


class RodInputs(NamedTuple):
    """What an integration of the rod reads: the model's arrays and one load case (SI, world frame).

    Built by :func:`twin.rod.solver.rod_inputs`. :func:`tip_sensitivities` perturbs ``tendons``
    and ``tip_force_n`` in place (and restores them): give it copies.

    Attributes:
        base_position_m: p(0) (3,).
        base_rotation: R(0), body → world (3, 3).
        nodes: station arc lengths (m), (K+1,), containing every interval boundary.
        intervals: for each step k, the midpoint of the event interval it lies in (m), (K,).
        kse: shear, shear and axial stiffness (N), (3,).
        kbt: bending, bending and torsional stiffness (N·m²), (3,).
        tendons: tendon table (nt, TENDON_COLUMNS), with this load's tensions and friction directions.
        length_m: rod length L.
        friction_coeff: capstan coefficient μ (1).
        tip_force_n: external tip force F_e (3,).
        tip_moment_nm: external tip moment M_e (3,).
        gravity_m_s2: gravitational acceleration vector (3,).
        line_mass_kg_per_m: distributed mass of the rod.
        point_mass_s_m: arc lengths of the lumped masses (np,).
        point_mass_kg: the lumped masses (np,).
        precurvature_per_m: the intrinsic curvature u* (body frame, 1/m) (3,).
    """

    base_position_m: np.ndarray
    base_rotation: np.ndarray
    nodes: np.ndarray
    intervals: np.ndarray
    kse: np.ndarray
    kbt: np.ndarray
    tendons: np.ndarray
    length_m: float
    friction_coeff: float
    tip_force_n: np.ndarray
    tip_moment_nm: np.ndarray
    gravity_m_s2: np.ndarray
    line_mass_kg_per_m: float
    point_mass_s_m: np.ndarray
    point_mass_kg: np.ndarray
    precurvature_per_m: np.ndarray


@njit(cache=True)
def _solve6(a, b, x):
    """Solve the 6×6 system a x = b by Gaussian elimination with partial pivoting (a, b destroyed)."""
    n = 6
    for k in range(n):
        piv = k
        big = abs(a[k, k])
        for i in range(k + 1, n):
            if abs(a[i, k]) > big:
                big = abs(a[i, k])
                piv = i
        if big == 0.0:
            return False
        if piv != k:
            for j in range(n):
                tmp = a[k, j]
                a[k, j] = a[piv, j]
                a[piv, j] = tmp
            tmp = b[k]
            b[k] = b[piv]
            b[piv] = tmp
        for i in range(k + 1, n):
            f = a[i, k] / a[k, k]
            if f != 0.0:
                for j in range(k, n):
                    a[i, j] -= f * a[k, j]
                b[i] -= f * b[k]
    for i in range(n - 1, -1, -1):
        acc = b[i]
        for j in range(i + 1, n):
            acc -= a[i, j] * x[j]
        x[i] = acc / a[i, i]
    return True


@njit(cache=True)
def _route(tendon, s, length, r, rp):
    """Tendon offset r_i(s) and its derivative r_i'(s) in the body frame (m, dimensionless)."""
    r0 = tendon[T_R0]
    rho = r0 + (tendon[T_R1] - r0) * s / length
    drho = (tendon[T_R1] - r0) / length
    omega = tendon[T_OMEGA]
    th = tendon[T_ALPHA] + omega * s
    c = np.cos(th)
    sn = np.sin(th)
    r[0] = rho * c
    r[1] = rho * sn
    r[2] = 0.0
    rp[0] = drho * c - rho * omega * sn
    rp[1] = drho * sn + rho * omega * c
    rp[2] = 0.0


@njit(cache=True)
def _strains(nb, mb, s, mid, wraps, kse, kbt, tendons, nt, length, mu, vu, jac, rhs, dx, r, rp, pm, rh, pr, routes):
    """Solve the constitutive law for (v, u) given body-frame n, m (vu holds the warm start).

    Returns the number of Newton iterations, or −1 if the local solve did not converge.
    """
    # Routing and tensions are fixed within a stage: evaluate them once.
    active = 0
    for k in range(nt):
        if tendons[k, T_END] < mid:
            continue
        tau_k = tendons[k, T_TAU] * np.exp(-mu * tendons[k, T_SIGMA] * wraps[k])
        if tau_k == 0.0:
            continue
        _route(tendons[k], s, length, r, rp)
        for i in range(3):
            routes[active, i] = r[i]
            routes[active, 3 + i] = rp[i]
        routes[active, 6] = tau_k
        active += 1
    for it in range(_LOCAL_MAX_ITER):
        # Residual pass: rhs = [n_b; m_b] − (rod + tendon terms); keeps t_i, |q_i| for the Jacobian.
        rhs[0] = nb[0] - kse[0] * vu[0]
        rhs[1] = nb[1] - kse[1] * vu[1]
        rhs[2] = nb[2] - kse[2] * (vu[2] - 1.0)
        rhs[3] = mb[0] - kbt[0] * vu[3]
        rhs[4] = mb[1] - kbt[1] * vu[4]
        rhs[5] = mb[2] - kbt[2] * vu[5]
        for k in range(active):
            r0_ = routes[k, 0]
            r1_ = routes[k, 1]
            r2_ = routes[k, 2]
            tau = routes[k, 6]
            # q = u × r + r' + v
            q0 = vu[4] * r2_ - vu[5] * r1_ + routes[k, 3] + vu[0]
            q1 = vu[5] * r0_ - vu[3] * r2_ + routes[k, 4] + vu[1]
            q2 = vu[3] * r1_ - vu[4] * r0_ + routes[k, 5] + vu[2]
            qn = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
            t0 = q0 / qn
            t1 = q1 / qn
            t2 = q2 / qn
            routes[k, 7] = t0
            routes[k, 8] = t1
            routes[k, 9] = t2
            routes[k, 10] = qn
            rhs[0] -= tau * t0
            rhs[1] -= tau * t1
            rhs[2] -= tau * t2
            rhs[3] -= tau * (r1_ * t2 - r2_ * t1)
            rhs[4] -= tau * (r2_ * t0 - r0_ * t2)
            rhs[5] -= tau * (r0_ * t1 - r1_ * t0)
        err = 0.0
        for i in range(3):
            err = max(err, abs(rhs[i]) / kse[i], abs(rhs[3 + i]) / kbt[i] * length)
        if err < _LOCAL_TOL:
            return it
        # Jacobian pass: R&W's [[K_se + A, G], [B, K_bt + H]] in this formulation.
        for i in range(6):
            for j in range(6):
                jac[i, j] = 0.0
        for i in range(3):
            jac[i, i] = kse[i]
            jac[3 + i, 3 + i] = kbt[i]
        for k in range(active):
            t0 = routes[k, 7]
            t1 = routes[k, 8]
            t2 = routes[k, 9]
            c = routes[k, 6] / routes[k, 10]
            # P = τ (I − t tᵀ)/|q|; dq/dv = I, dq/du = −r̂; blocks P, −P r̂, r̂ P, −r̂ P r̂.
            pm[0, 0] = c * (1.0 - t0 * t0)
            pm[0, 1] = -c * t0 * t1
            pm[0, 2] = -c * t0 * t2
            pm[1, 0] = pm[0, 1]
            pm[1, 1] = c * (1.0 - t1 * t1)
            pm[1, 2] = -c * t1 * t2
            pm[2, 0] = pm[0, 2]
            pm[2, 1] = pm[1, 2]
            pm[2, 2] = c * (1.0 - t2 * t2)
            rh[0, 1] = -routes[k, 2]
            rh[0, 2] = routes[k, 1]
            rh[1, 0] = routes[k, 2]
            rh[1, 2] = -routes[k, 0]
            rh[2, 0] = -routes[k, 1]
            rh[2, 1] = routes[k, 0]
            for a in range(3):
                for b in range(3):
                    acc = 0.0
                    for cc in range(3):
                        acc += pm[a, cc] * rh[cc, b]
                    pr[a, b] = acc
            for a in range(3):
                for b in range(3):
                    rpr = 0.0
                    for cc in range(3):
                        rpr += rh[a, cc] * pr[cc, b]
                    jac[a, b] += pm[a, b]
                    jac[a, 3 + b] -= pr[a, b]
                    # r̂ P = −(P r̂)ᵀ since P = Pᵀ and r̂ᵀ = −r̂.
                    jac[3 + a, b] -= pr[b, a]
                    jac[3 + a, 3 + b] -= rpr
        if not _solve6(jac, rhs, dx):
            return -1
        for i in range(6):
            vu[i] += dx[i]
    return -1


# The helpers below take the fields they use, not a RodInputs: they run at every RK4 stage, and
# a RodInputs argument would hand them all of its arrays each time.
@njit(cache=True)
def _internal_force(s, mid, length, tip_force, grav, line_mass, pm_s, pm_m, n):
    """Total internal force n(s) (N, world): tip force plus the weight distal to s.

    ``mid`` decides which point masses count as distal (the current interval's midpoint), so
    stations on a point load take the limit from inside the interval.
    """
    w = line_mass * (length - s)
    for k in range(pm_s.shape[0]):
        if pm_s[k] > mid:
            w += pm_m[k]
    for i in range(3):
        n[i] = tip_force[i] + w * grav[i]
    return n


@njit(cache=True)
def internal_forces(rod, out):
    """n(s) at every station (N, world) into ``out`` (K+1, 3): :func:`_internal_force` with each
    station's interval (the last station takes the last interval's)."""
    nodes = rod.nodes
    intervals = rod.intervals
    last = intervals.shape[0] - 1
    for k in range(nodes.shape[0]):
        _internal_force(nodes[k], intervals[min(k, last)], rod.length_m, rod.tip_force_n, rod.gravity_m_s2,
                        rod.line_mass_kg_per_m, rod.point_mass_s_m, rod.point_mass_kg, out[k])
    return out


@njit(cache=True)
def _deriv(y, s, mid, vu, kse, kbt, ustar, tendons, nt, length, mu, tip_force, grav, line_mass,
           pm_s, pm_m, dy, work6, jac, rhs, dx, r, rp, q, work, routes):
    """dy/ds of the state; updates the strains vu in place. Returns False if the local solve failed."""
    n = _internal_force(s, mid, length, tip_force, grav, line_mass, pm_s, pm_m, work6[6:9])
    # Body-frame n, m: Rᵀ n, Rᵀ m (R stored row-major at y[3:12]).
    nb = work6[0:3]
    mb = work6[3:6]
    for i in range(3):
        nb[i] = y[3 + i] * n[0] + y[6 + i] * n[1] + y[9 + i] * n[2]
        # K_bt u* moved to this side: the law then reads Rᵀ m + K_bt u* = K_bt u + ….
        mb[i] = y[3 + i] * y[12] + y[6 + i] * y[13] + y[9 + i] * y[14] + kbt[i] * ustar[i]
    wraps = y[15:15 + nt]
    if _strains(nb, mb, s, mid, wraps, kse, kbt, tendons, nt, length, mu, vu, jac, rhs, dx, r, rp,
                work[0], work[1], work[2], routes) < 0:
        return False
    v0, v1, v2, u0, u1, u2 = vu[0], vu[1], vu[2], vu[3], vu[4], vu[5]
    # p' = R v
    for i in range(3):
        dy[i] = y[3 + 3 * i] * v0 + y[4 + 3 * i] * v1 + y[5 + 3 * i] * v2
    # R' = R û
    for i in range(3):
        a = y[3 + 3 * i]
        b = y[4 + 3 * i]
        c = y[5 + 3 * i]
        dy[3 + 3 * i] = b * u2 - c * u1
        dy[4 + 3 * i] = c * u0 - a * u2
        dy[5 + 3 * i] = a * u1 - b * u0
    # m' = −p' × n
    dy[12] = -(dy[1] * n[2] - dy[2] * n[1])
    dy[13] = -(dy[2] * n[0] - dy[0] * n[2])
    dy[14] = -(dy[0] * n[1] - dy[1] * n[0])
    for k in range(nt):
        if tendons[k, T_END] < mid:
            dy[15 + k] = 0.0
            dy[15 + nt + k] = 0.0
            continue
        _route(tendons[k], s, length, r, rp)
        q[0] = u1 * r[2] - u2 * r[1] + rp[0] + v0
        q[1] = u2 * r[0] - u0 * r[2] + rp[1] + v1
        q[2] = u0 * r[1] - u1 * r[0] + rp[2] + v2
        qn = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2])
        # Wrap rate |u × t| (tendon direction turning with the backbone).
        c0 = (u1 * q[2] - u2 * q[1]) / qn
        c1 = (u2 * q[0] - u0 * q[2]) / qn
        c2 = (u0 * q[1] - u1 * q[0]) / qn
        dy[15 + k] = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        dy[15 + nt + k] = qn
    return True


@njit(cache=True)
def integrate(m0, rod, states, strains):
    """Integrate the rod from the base with base moment m0 (N·m, world) by fixed-step RK4.

    Args:
        m0: base moment m(0) (N·m, world) (3,).
        rod: the :class:`RodInputs`.
        states: output (K+1, 15 + 2 nt) states at the stations.
        strains: output (K+1, 6) strains (v, u) at the stations.

    Returns:
        (ok, residual (3,)) — residual = m(L) − M_e (N·m, world); ok False if a local solve failed.
    """
    nodes = rod.nodes
    intervals = rod.intervals
    kse = rod.kse
    kbt = rod.kbt
    ustar = rod.precurvature_per_m
    tendons = rod.tendons
    length = rod.length_m
    mu = rod.friction_coeff
    tip_force = rod.tip_force_n
    grav = rod.gravity_m_s2
    line_mass = rod.line_mass_kg_per_m
    pm_s = rod.point_mass_s_m
    pm_m = rod.point_mass_kg
    nt = tendons.shape[0]
    ny = 15 + 2 * nt
    y = np.zeros(ny)
    y[0:3] = rod.base_position_m
    r0 = rod.base_rotation
    for i in range(3):
        for j in range(3):
            y[3 + 3 * i + j] = r0[i, j]
    y[12:15] = m0
    vu = np.zeros(6)
    vu[2] = 1.0
    k1 = np.empty(ny)
    k2 = np.empty(ny)
    k3 = np.empty(ny)
    k4 = np.empty(ny)
    yt = np.empty(ny)
    work6 = np.empty(9)
    jac = np.empty((6, 6))
    rhs = np.empty(6)
    dx = np.empty(6)
    r = np.empty(3)
    rp = np.empty(3)
    q = np.empty(3)
    work = np.zeros((3, 3, 3))
    routes = np.empty((nt, 11))
    res = np.zeros(3)
    states[0, :] = y
    nsteps = nodes.shape[0] - 1
    # Strains at the base (warm start for the first stage, and the output at station 0).
    if not _deriv(y, nodes[0], intervals[0], vu, kse, kbt, ustar, tendons, nt, length, mu, tip_force, grav,
                  line_mass, pm_s, pm_m, k1, work6, jac, rhs, dx, r, rp, q, work, routes):
        return False, res
    strains[0, :] = vu
    for k in range(nsteps):
        s = nodes[k]
        h = nodes[k + 1] - s
        mid = intervals[k]
        if not _deriv(y, s, mid, vu, kse, kbt, ustar, tendons, nt, length, mu, tip_force, grav, line_mass,
                      pm_s, pm_m, k1, work6, jac, rhs, dx, r, rp, q, work, routes):
            return False, res
        for i in range(ny):
            yt[i] = y[i] + 0.5 * h * k1[i]
        if not _deriv(yt, s + 0.5 * h, mid, vu, kse, kbt, ustar, tendons, nt, length, mu, tip_force, grav,
                      line_mass, pm_s, pm_m, k2, work6, jac, rhs, dx, r, rp, q, work, routes):
            return False, res
        for i in range(ny):
            yt[i] = y[i] + 0.5 * h * k2[i]
        if not _deriv(yt, s + 0.5 * h, mid, vu, kse, kbt, ustar, tendons, nt, length, mu, tip_force, grav,
                      line_mass, pm_s, pm_m, k3, work6, jac, rhs, dx, r, rp, q, work, routes):
            return False, res
        for i in range(ny):
            yt[i] = y[i] + h * k3[i]
        if not _deriv(yt, s + h, mid, vu, kse, kbt, ustar, tendons, nt, length, mu, tip_force, grav,
                      line_mass, pm_s, pm_m, k4, work6, jac, rhs, dx, r, rp, q, work, routes):
            return False, res
        for i in range(ny):
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        states[k + 1, :] = y
        strains[k + 1, :] = vu
        if not np.all(np.isfinite(y)):
            return False, res
    for i in range(3):
        res[i] = y[12 + i] - rod.tip_moment_nm[i]
    return True, res


@njit(cache=True)
def _norm3(x):
    return np.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])


@njit(cache=True)
def _fd_jacobian(m0, res, jac, trial, rod, states, strains, fd_step_nm):
    """∂res/∂m0 by forward differences (backward where a forward step fails) into ``jac``.

    Returns (ok, integrations)."""
    calls = 0
    for j in range(3):
        for i in range(3):
            trial[i] = m0[i]
        trial[j] += fd_step_nm
        okj, rj = integrate(trial, rod, states, strains)
        calls += 1
        if not okj:
            trial[j] -= 2.0 * fd_step_nm
            okj, rj = integrate(trial, rod, states, strains)
            calls += 1
            if not okj:
                return False, calls
            for i in range(3):
                jac[i, j] = (res[i] - rj[i]) / fd_step_nm
        else:
            for i in range(3):
                jac[i, j] = (rj[i] - res[i]) / fd_step_nm
    return True, calls


@njit(cache=True)
def _log(trace, row, norm, alpha, step_nm, fresh):
    trace[row, TR_RESIDUAL] = norm
    trace[row, TR_STEP_FRACTION] = alpha
    trace[row, TR_STEP] = step_nm
    trace[row, TR_FRESH] = 1.0 if fresh else 0.0


@njit(cache=True)
def shoot(m0, rod, states, strains, tol_nm, max_iter, fd_step_nm, jac, have_jac, trace):
    """Newton shooting on the base moment m0 (updated in place) with a backtracking line search.

    ``jac`` (3, 3) is ∂res/∂m0, in and out. With ``have_jac`` the solve starts from it (a
    neighbouring solve's, e.g. the previous sample of a stream) and keeps it current by Broyden
    updates, one integration per iteration; a step it does not make good (no decrease at the full
    step, or less than halving the residual) recomputes it by finite differences, 3 integrations,
    as every iteration does without it. On return it holds the latest ∂res/∂m0 (Broyden-updated:
    good for a warm start, not for sensitivities).

    ``trace`` (max_iter + 1, TRACE_COLUMNS) receives one row per iteration (columns ``TR_*``),
    the last row being the iterate the solve ended on (no step taken from it).

    Returns:
        (status, residual norm N·m, Newton iterations, integrations, trace rows written); status
        is a :class:`SolverStatus` code.
    """
    ok, res = integrate(m0, rod, states, strains)
    calls = 1
    if not ok:
        _log(trace, 0, np.inf, 0.0, 0.0, False)
        return _INTEGRATION_FAILED, np.inf, 0, calls, 1
    norm = _norm3(res)
    trial = np.empty(3)
    fresh = False
    for it in range(max_iter):
        if norm <= tol_nm:
            _log(trace, it, norm, 0.0, 0.0, False)
            return _CONVERGED, norm, it, calls, it + 1
        if not have_jac:
            okj, c = _fd_jacobian(m0, res, jac, trial, rod, states, strains, fd_step_nm)
            calls += c
            if not okj:
                _log(trace, it, norm, 0.0, 0.0, True)
                return _LINE_SEARCH_STALLED, norm, it, calls, it + 1
            have_jac, fresh = True, True
        step = np.linalg.solve(jac, -res)
        alpha = 1.0
        accepted = False
        new_norm = norm
        for _ in range(12 if fresh else 1):
            for i in range(3):
                trial[i] = m0[i] + alpha * step[i]
            okt, rt = integrate(trial, rod, states, strains)
            calls += 1
            if okt:
                new_norm = _norm3(rt)
                if new_norm < (1.0 - 1e-4 * alpha) * norm or new_norm <= tol_nm:
                    accepted = True
                    break
            alpha *= 0.5
        if accepted:
            # Broyden's update along the step taken: jac += (Δres − jac·Δm) Δmᵀ / |Δm|².
            dm2 = 0.0
            for i in range(3):
                dm2 += (alpha * step[i]) ** 2
            if dm2 > 0.0:
                for i in range(3):
                    pred = 0.0
                    for j in range(3):
                        pred += jac[i, j] * alpha * step[j]
                    corr = (rt[i] - res[i] - pred) / dm2
                    for j in range(3):
                        jac[i, j] += corr * alpha * step[j]
            _log(trace, it, norm, alpha, np.sqrt(dm2), fresh)
            for i in range(3):
                m0[i] = trial[i]
                res[i] = rt[i]
            slow = new_norm > 0.5 * norm
            norm = new_norm
            if slow and not fresh:
                have_jac = False  # the carried Jacobian is stale: take a fresh one next
            fresh = False
        elif fresh:
            _log(trace, it, norm, 0.0, 0.0, True)
            # Leave states consistent with m0 for the caller.
            integrate(m0, rod, states, strains)
            return _LINE_SEARCH_STALLED, norm, it + 1, calls + 1, it + 1
        else:
            _log(trace, it, norm, 0.0, 0.0, False)
            have_jac = False
    _log(trace, max_iter, norm, 0.0, 0.0, False)
    if norm <= tol_nm:
        # The last accepted trial left states at m0.
        return _CONVERGED, norm, max_iter, calls, max_iter + 1
    return _ITERATION_LIMIT, norm, max_iter, calls, max_iter + 1


@njit(cache=True)
def _tip_change(states, p_ref, r_ref, out):
    """Tip pose of the last integration against (p_ref, r_ref): position change (m) and the
    world-frame rotation vector of R r_refᵀ (rad, small-angle: half the vee of its skew part)."""
    last = states.shape[0] - 1
    for i in range(3):
        out[i] = states[last, i] - p_ref[i]
    d = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += states[last, 3 + 3 * i + k] * r_ref[j, k]
            d[i, j] = acc
    out[3] = 0.5 * (d[2, 1] - d[1, 2])
    out[4] = 0.5 * (d[0, 2] - d[2, 0])
    out[5] = 0.5 * (d[1, 0] - d[0, 1])


@njit(cache=True)
def tip_sensitivities(m0, h_m, h_tau, h_f, p_ref, r_ref, rod, states, strains, dr_dm, dt_dm, dr_dth, dt_dth):
    """The partial derivatives twin.rod.jacobian.tip_jacobian combines, from single integrations
    at the converged base moment m0 (7 + nt + 3 of them, in one compiled call).

    ∂r/∂m0 (3, 3) and ∂T/∂m0 (6, 3) by central differences of step ``h_m`` (N·m); ∂r/∂θ and ∂T/∂θ
    for θ = each tension (step ``h_tau``, N) then each tip force component (``h_f``, N) by forward
    differences against an integration at m0, written into the first nt + 3 columns of
    ``dr_dth`` (3, ·) and ``dt_dth`` (6, ·). T is the tip pose change against (p_ref, r_ref):
    position (m) and rotation vector (rad). ``rod.tendons`` and ``rod.tip_force_n`` are perturbed
    in place and restored.

    Returns:
        False when a perturbed integration failed (the outputs are then incomplete).
    """
    tendons = rod.tendons
    tip_force = rod.tip_force_n
    nt = tendons.shape[0]
    trial = np.empty(3)
    pose_p = np.empty(6)
    pose_m = np.empty(6)
    pose_0 = np.empty(6)
    pose = np.empty(6)
    for j in range(3):
        for i in range(3):
            trial[i] = m0[i]
        trial[j] = m0[j] + h_m
        ok, res_p = integrate(trial, rod, states, strains)
        if not ok:
            return False
        _tip_change(states, p_ref, r_ref, pose_p)
        trial[j] = m0[j] - h_m
        ok, res_m = integrate(trial, rod, states, strains)
        if not ok:
            return False
        _tip_change(states, p_ref, r_ref, pose_m)
        for i in range(3):
            dr_dm[i, j] = (res_p[i] - res_m[i]) / (2 * h_m)
        for i in range(6):
            dt_dm[i, j] = (pose_p[i] - pose_m[i]) / (2 * h_m)
    ok, res_0 = integrate(m0, rod, states, strains)
    if not ok:
        return False
    _tip_change(states, p_ref, r_ref, pose_0)
    for j in range(nt + 3):
        if j < nt:
            h = h_tau
            saved = tendons[j, T_TAU]
            tendons[j, T_TAU] = saved + h
        else:
            h = h_f
            saved = tip_force[j - nt]
            tip_force[j - nt] = saved + h
        ok, res = integrate(m0, rod, states, strains)
        if j < nt:
            tendons[j, T_TAU] = saved
        else:
            tip_force[j - nt] = saved
        if not ok:
            return False
        _tip_change(states, p_ref, r_ref, pose)
        for i in range(3):
            dr_dth[i, j] = (res[i] - res_0[i]) / h
        for i in range(6):
            dt_dth[i, j] = (pose[i] - pose_0[i]) / h
    return True
