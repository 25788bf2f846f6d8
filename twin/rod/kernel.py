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

from twin.resources import announce_kernel_compile

announce_kernel_compile(__file__, "the predictor's kernels")

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


@njit(cache=True, inline="always")
def _cholesky_solve6(a, b):
    """Solve a x = b for a symmetric positive definite 6×6 ``a`` given by its upper triangle
    (overwritten by its Cholesky factor); x overwrites b. False if ``a`` is not positive definite."""
    for j in range(6):
        d = a[j, j]
        for k in range(j):
            d -= a[k, j] * a[k, j]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        a[j, j] = d
        for i in range(j + 1, 6):
            acc = a[j, i]
            for k in range(j):
                acc -= a[k, j] * a[k, i]
            a[j, i] = acc / d
    for i in range(6):
        acc = b[i]
        for k in range(i):
            acc -= a[k, i] * b[k]
        b[i] = acc / a[i, i]
    for i in range(5, -1, -1):
        acc = b[i]
        for k in range(i + 1, 6):
            acc -= a[i, k] * b[k]
        b[i] = acc / a[i, i]
    return True


@njit(cache=True, inline="always")
def _routes(s, mid, tendons, length, trig, routes):
    """The body-frame offsets r_i(s) = (x, y, 0) and their derivatives r_i'(s) = (x', y', 0) of
    the tendons that run through the interval around ``mid``, into ``routes`` rows (x, y, x', y',
    1.0); a tendon that ended before it gets a row whose last column is 0.

    ``trig`` holds each tendon's (cos, sin) of its base angle, used when its helix rate is zero.
    """
    for k in range(tendons.shape[0]):
        if tendons[k, T_END] < mid:
            routes[k, 4] = 0.0
            continue
        r0 = tendons[k, T_R0]
        drho = (tendons[k, T_R1] - r0) / length
        rho = r0 + drho * s
        omega = tendons[k, T_OMEGA]
        if omega == 0.0:
            c = trig[k, 0]
            sn = trig[k, 1]
        else:
            th = tendons[k, T_ALPHA] + omega * s
            c = np.cos(th)
            sn = np.sin(th)
        routes[k, 0] = rho * c
        routes[k, 1] = rho * sn
        routes[k, 2] = drho * c - rho * omega * sn
        routes[k, 3] = drho * sn + rho * omega * c
        routes[k, 4] = 1.0


@njit(cache=True, inline="always")
def _newton_step(nb, mb, kse, kbt, routes, taus, vu, jac, rhs, w):
    """One Newton step on the constitutive law for (v, u) given body-frame n, m; updates ``vu``.

    With q_i = u × r_i + r_i' + v, t_i = q_i/|q_i| and w_i = (t_i, r_i × t_i), the law is
    [n_b; m_b] = K (vu − vu*) + Σ τ_i w_i, and its Jacobian (R&W 2011's [[K_se + A, G], [B, K_bt + H]])
    is symmetric positive definite:

        K + Σ c_i [[I, −r̂_i], [r̂_i, |r_i|² I − r_i r_iᵀ]] − Σ c_i w_i w_iᵀ,    c_i = τ_i / |q_i|,

    whose first sum needs only Σc, Σc r and Σc r rᵀ; one Cholesky solve takes the step.

    Returns:
        The residual before the step as a strain, max over its rows of |residual| / stiffness
        (force rows over K_se: dimensionless; moment rows over K_bt: 1/m), or −1.0 when the
        matrix was not positive definite.
    """
    v0 = vu[0]
    v1 = vu[1]
    v2 = vu[2]
    u0 = vu[3]
    u1 = vu[4]
    u2 = vu[5]
    rhs[0] = nb[0] - kse[0] * v0
    rhs[1] = nb[1] - kse[1] * v1
    rhs[2] = nb[2] - kse[2] * (v2 - 1.0)
    rhs[3] = mb[0] - kbt[0] * u0
    rhs[4] = mb[1] - kbt[1] * u1
    rhs[5] = mb[2] - kbt[2] * u2
    for a in range(6):
        for b in range(a, 6):
            jac[a, b] = 0.0
    sc = sx = sy = sxx = sxy = syy = 0.0
    for k in range(taus.shape[0]):
        tau = taus[k]
        if routes[k, 4] == 0.0 or tau == 0.0:
            continue
        rx = routes[k, 0]
        ry = routes[k, 1]
        q0 = -u2 * ry + routes[k, 2] + v0
        q1 = u2 * rx + routes[k, 3] + v1
        q2 = u0 * ry - u1 * rx + v2
        inv = 1.0 / np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
        t0 = q0 * inv
        t1 = q1 * inv
        t2 = q2 * inv
        w[0] = t0
        w[1] = t1
        w[2] = t2
        w[3] = ry * t2
        w[4] = -rx * t2
        w[5] = rx * t1 - ry * t0
        c = tau * inv
        for a in range(6):
            rhs[a] -= tau * w[a]
            cw = c * w[a]
            for b in range(a, 6):
                jac[a, b] -= cw * w[b]
        sc += c
        sx += c * rx
        sy += c * ry
        sxx += c * rx * rx
        sxy += c * rx * ry
        syy += c * ry * ry
    err = 0.0
    for i in range(3):
        err = max(err, abs(rhs[i]) / kse[i], abs(rhs[3 + i]) / kbt[i])
    jac[0, 0] += kse[0] + sc
    jac[1, 1] += kse[1] + sc
    jac[2, 2] += kse[2] + sc
    jac[0, 5] -= sy
    jac[1, 5] += sx
    jac[2, 3] += sy
    jac[2, 4] -= sx
    jac[3, 3] += kbt[0] + syy
    jac[3, 4] -= sxy
    jac[4, 4] += kbt[1] + sxx
    jac[5, 5] += kbt[2] + sxx + syy
    if not _cholesky_solve6(jac, rhs):
        return -1.0
    for i in range(6):
        vu[i] += rhs[i]
    return err


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


# The stage takes the fields it uses, not a RodInputs: it runs at every RK4 stage, and a
# RodInputs argument would hand it all of its arrays each time.
@njit(cache=True)
def _stage(y, s, mid, converge, vu, kse, kbt, ustar, tendons, length, mu, tip_force, grav, line_mass, pm_s, pm_m,
           trig, routes, taus, n, nb, mb, jac, rhs, w, dy):
    """dy/ds of the state at (y, s), with the strains vu (in: the warm start, out: the strains).

    The constitutive law is solved by one Newton step from the warm start (the previous stage's
    strains, an RK4 stage away), or, with ``converge``, by Newton to 1e-13 (at the base and
    where an interval starts: a point load or a tendon's end changes the law there).

    Returns:
        False if the constitutive solve failed.
    """
    nt = tendons.shape[0]
    _internal_force(s, mid, length, tip_force, grav, line_mass, pm_s, pm_m, n)
    # Body-frame n, m: Rᵀ n, Rᵀ m (R stored row-major at y[3:12]).
    for i in range(3):
        nb[i] = y[3 + i] * n[0] + y[6 + i] * n[1] + y[9 + i] * n[2]
        # K_bt u* moved to this side: the law then reads Rᵀ m + K_bt u* = K_bt u + ….
        mb[i] = y[3 + i] * y[12] + y[6 + i] * y[13] + y[9 + i] * y[14] + kbt[i] * ustar[i]
    if routes[0, 5] != s or routes[0, 6] != mid:
        _routes(s, mid, tendons, length, trig, routes)
        routes[0, 5] = s
        routes[0, 6] = mid
    for k in range(nt):
        taus[k] = tendons[k, T_TAU]
        if mu != 0.0:
            taus[k] *= np.exp(-mu * tendons[k, T_SIGMA] * y[15 + k])
    if converge:
        for _ in range(_LOCAL_MAX_ITER):
            err = _newton_step(nb, mb, kse, kbt, routes, taus, vu, jac, rhs, w)
            if err < 0.0:
                return False
            if err * length < _LOCAL_TOL:
                break
        else:
            return False
    elif _newton_step(nb, mb, kse, kbt, routes, taus, vu, jac, rhs, w) < 0.0:
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
        if routes[k, 4] == 0.0:
            dy[15 + k] = 0.0
            dy[15 + nt + k] = 0.0
            continue
        rx = routes[k, 0]
        ry = routes[k, 1]
        q0 = -u2 * ry + routes[k, 2] + v0
        q1 = u2 * rx + routes[k, 3] + v1
        q2 = u0 * ry - u1 * rx + v2
        qn = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
        dy[15 + nt + k] = qn
        if mu == 0.0:
            dy[15 + k] = 0.0  # the wrap angle only ever scales μ
            continue
        # Wrap rate |u × t| (tendon direction turning with the backbone).
        c0 = u1 * q2 - u2 * q1
        c1 = u2 * q0 - u0 * q2
        c2 = u0 * q1 - u1 * q0
        dy[15 + k] = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2) / qn
    return True


@njit(cache=True)
def integrate(m0, rod, states, strains):
    """Integrate the rod from the base with base moment m0 (N·m, world) by fixed-step RK4.

    Each stage takes one constitutive solve (:func:`_stage`): the integration is as costly as
    an RK4 of R&W's (v, u) form, which solves one 6×6 system per stage as well.

    Args:
        m0: base moment m(0) (N·m, world) (3,).
        rod: the :class:`RodInputs`.
        states: output (K+1, 15 + 2 nt) states at the stations.
        strains: output (K+1, 6) strains (v, u) at the stations; its row 0, if finite, is the
            starting guess for the base strains (NaN for none).

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
    # The base strains start from the last integration's (``strains[0]``: a shooting solve's
    # integrations lie close together), or from the straight rod's where it holds none (NaN).
    vu = np.empty(6)
    warm = True
    for i in range(6):
        vu[i] = strains[0, i]
        warm = warm and np.isfinite(vu[i])
    if not warm:
        vu[:] = 0.0
        vu[2] = 1.0
    k1 = np.empty(ny)
    k2 = np.empty(ny)
    k3 = np.empty(ny)
    k4 = np.empty(ny)
    yt = np.empty(ny)
    trig = np.empty((nt, 2))
    for k in range(nt):
        trig[k, 0] = np.cos(tendons[k, T_ALPHA])
        trig[k, 1] = np.sin(tendons[k, T_ALPHA])
    # Columns 5, 6 of row 0: the (s, mid) the routes were evaluated at (k2 and k3 share theirs).
    routes = np.full((max(nt, 1), 7), np.nan)
    taus = np.empty(nt)
    vec = np.empty((4, 3))
    jac = np.empty((6, 6))
    rhs = np.empty(6)
    w = np.empty(6)
    res = np.zeros(3)
    states[0, :] = y
    nsteps = nodes.shape[0] - 1
    # The base: its strains are station 0's output and the first step's k1.
    if not _stage(y, nodes[0], intervals[0], True, vu, kse, kbt, ustar, tendons, length, mu, tip_force, grav, line_mass,
                  pm_s, pm_m, trig, routes, taus, vec[0], vec[1], vec[2], jac, rhs, w, k1):
        if not warm:
            return False, res
        vu[:] = 0.0
        vu[2] = 1.0
        if not _stage(y, nodes[0], intervals[0], True, vu, kse, kbt, ustar, tendons, length, mu, tip_force, grav,
                      line_mass, pm_s, pm_m, trig, routes, taus, vec[0], vec[1], vec[2], jac, rhs, w, k1):
            return False, res
    strains[0, :] = vu
    # The strains change smoothly within an interval: each step's k2 and k4 start from the last
    # stage's strains moved along the slope between the last two steps' k1 strains. One Newton
    # step from there puts the tip within 1.1e-7 m of fully converged constitutive solves on the
    # zoo's robots (2e-9 m on the endoscope), well inside the RK4 error at 12 steps.
    slope = np.zeros(6)
    start = vu.copy()
    for k in range(nsteps):
        s = nodes[k]
        h = nodes[k + 1] - s
        mid = intervals[k]
        if k > 0:
            fresh = mid != intervals[k - 1]
            if not _stage(y, s, mid, fresh, vu, kse, kbt, ustar, tendons, length, mu, tip_force, grav, line_mass, pm_s,
                          pm_m, trig, routes, taus, vec[0], vec[1], vec[2], jac, rhs, w, k1):
                return False, res
            for i in range(6):
                slope[i] = 0.0 if fresh else (vu[i] - start[i]) / (s - nodes[k - 1])
                start[i] = vu[i]
        for i in range(ny):
            yt[i] = y[i] + 0.5 * h * k1[i]
        for i in range(6):
            vu[i] += 0.5 * h * slope[i]
        if not _stage(yt, s + 0.5 * h, mid, False, vu, kse, kbt, ustar, tendons, length, mu, tip_force, grav, line_mass,
                      pm_s, pm_m, trig, routes, taus, vec[0], vec[1], vec[2], jac, rhs, w, k2):
            return False, res
        for i in range(ny):
            yt[i] = y[i] + 0.5 * h * k2[i]
        if not _stage(yt, s + 0.5 * h, mid, False, vu, kse, kbt, ustar, tendons, length, mu, tip_force, grav, line_mass,
                      pm_s, pm_m, trig, routes, taus, vec[0], vec[1], vec[2], jac, rhs, w, k3):
            return False, res
        for i in range(ny):
            yt[i] = y[i] + h * k3[i]
        for i in range(6):
            vu[i] += 0.5 * h * slope[i]
        if not _stage(yt, s + h, mid, False, vu, kse, kbt, ustar, tendons, length, mu, tip_force, grav, line_mass,
                      pm_s, pm_m, trig, routes, taus, vec[0], vec[1], vec[2], jac, rhs, w, k4):
            return False, res
        finite = True
        for i in range(ny):
            y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            finite = finite and np.isfinite(y[i])
        if not finite:
            return False, res
        states[k + 1, :] = y
        strains[k + 1, :] = vu
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
    at the converged base moment m0 (4 + nt + 3 of them, in one compiled call).

    ∂r/∂m0 (3, 3) and ∂T/∂m0 (6, 3) (step ``h_m``, N·m), ∂r/∂θ and ∂T/∂θ for θ = each tension
    (step ``h_tau``, N) then each tip force component (``h_f``, N), all by forward differences
    against an integration at m0, written into the first nt + 3 columns of
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
    pose_0 = np.empty(6)
    pose = np.empty(6)
    ok, res_0 = integrate(m0, rod, states, strains)
    if not ok:
        return False
    _tip_change(states, p_ref, r_ref, pose_0)
    for j in range(3):
        for i in range(3):
            trial[i] = m0[i]
        trial[j] = m0[j] + h_m
        ok, res_p = integrate(trial, rod, states, strains)
        if not ok:
            return False
        _tip_change(states, p_ref, r_ref, pose_p)
        for i in range(3):
            dr_dm[i, j] = (res_p[i] - res_0[i]) / h_m
        for i in range(6):
            dt_dm[i, j] = (pose_p[i] - pose_0[i]) / h_m
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


@njit(cache=True)
def shoot_batch(rod, tensions, sigma, forces, moments, cold, guesses, guess_jacs, guess_kind, chain, tol_nm, max_iter,
                fd_step_nm, m0_out, jac_out, states, strains, traces, out):
    """:func:`shoot` for many load cases of one rod in one compiled call (``twin.rod.solve_batch``).

    Case i sets the tensions ``tensions[i]`` (N), friction directions ``sigma[i]``, tip force
    ``forces[i]`` (N) and moment ``moments[i]`` (N·m) into ``rod`` (its tendon table and tip
    arrays are overwritten: give it copies). It starts from ``guesses[i]`` (with ``guess_jacs[i]``
    when ``guess_kind[i]`` is 2, without when 1); with ``guess_kind[i]`` 0 from the previous
    case's solution when ``chain`` and that one converged, else from ``cold[i]``. A warm start
    that fails is retried from ``cold[i]``, as :func:`twin.rod.solve` does.

    Outputs per case: ``m0_out`` (N·m), ``jac_out`` (the final ∂res/∂m0), ``states``,
    ``strains``, ``traces[i, run]`` (the two runs' trace rows), and ``out[i]``
    = (status, residual N·m, iterations, integrations, rows of run 0, rows of run 1, 1.0 if warm-started).
    """
    tendons = rod.tendons
    nt = tendons.shape[0]
    for i in range(tensions.shape[0]):
        for k in range(nt):
            tendons[k, T_TAU] = tensions[i, k]
            tendons[k, T_SIGMA] = sigma[i, k]
        for j in range(3):
            rod.tip_force_n[j] = forces[i, j]
            rod.tip_moment_nm[j] = moments[i, j]
        m0 = m0_out[i]
        jac = jac_out[i]
        warm = True
        have_jac = False
        if guess_kind[i] > 0:
            m0[:] = guesses[i]
            if guess_kind[i] == 2:
                jac[:, :] = guess_jacs[i]
                have_jac = True
        elif chain and i > 0 and out[i - 1, 0] == _CONVERGED:
            m0[:] = m0_out[i - 1]
            jac[:, :] = jac_out[i - 1]
            have_jac = True
        else:
            m0[:] = cold[i]
            warm = False
        code, norm, iters, calls, rows = shoot(m0, rod, states[i], strains[i], tol_nm, max_iter, fd_step_nm, jac,
                                               have_jac, traces[i, 0])
        rows2 = 0
        if code != _CONVERGED and warm:
            m0[:] = cold[i]
            code, norm, it2, c2, rows2 = shoot(m0, rod, states[i], strains[i], tol_nm, max_iter, fd_step_nm, jac,
                                               False, traces[i, 1])
            iters += it2
            calls += c2
        out[i, 0] = code
        out[i, 1] = norm
        out[i, 2] = iters
        out[i, 3] = calls
        out[i, 4] = rows
        out[i, 5] = rows2
        out[i, 6] = 1.0 if warm else 0.0
