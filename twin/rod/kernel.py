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
        routes: the tendons' routes at each RK4 step's three stations s, s + h/2 and s + h, by
            the step's interval, (K, 3, nt, ROUTE_COLUMNS) (columns ``RT_*``): they depend on
            the rod alone, so no integration evaluates them.
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
    routes: np.ndarray


# Columns of a route row (RodInputs.routes): the tendon's body-frame offset r_i = (x, y, 0) (m), its
# derivative r_i' = (x', y', 0) (1), and 1.0 if the tendon runs through the step's interval else 0.0.
RT_X, RT_Y, RT_DX, RT_DY, RT_ON = range(5)
ROUTE_COLUMNS = 5


@njit(cache=True, inline="always")
def _adjugate_sym3(a00, a01, a02, a11, a12, a22):
    """The upper triangle of the adjugate of a symmetric 3×3 matrix, given by its upper triangle,
    and the matrix's determinant (the inverse is the adjugate over the determinant). Inlined into
    the stage's Newton step, which takes it twice (the block and its Schur complement)."""
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    return c00, c01, c02, c11, c12, c22, a00 * c00 + a01 * c01 + a02 * c02


@njit(cache=True, inline="always")
def _tendon_direction(route, u0, u1, u2, v0, v1, v2):
    """A tendon's local direction in the body frame, unnormalised (1): q = û r + r' + v, with
    r, r' from its route row (RT_X … RT_DY) and u, v the rod's strains at the station."""
    rx = route[RT_X]
    ry = route[RT_Y]
    return -u2 * ry + route[RT_DX] + v0, u2 * rx + route[RT_DY] + v1, u0 * ry - u1 * rx + v2


@njit(cache=True, fastmath={"contract"})
def integrate(m0, rod, states, strains):
    """Integrate the rod from the base with base moment m0 (N·m, world) by fixed-step RK4.

    Each stage solves the constitutive law for the strains (v, u) given the body-frame n, m: as
    costly as an RK4 of R&W's (v, u) form, which solves one 6×6 system per stage as well. It
    takes one Newton step from a warm start (the previous stage's strains, an RK4 stage away),
    or, at the base and where an interval starts (a point load or a tendon's end changes the law
    there), Newton to 1e-13.

    With q_i = u × r_i + r_i' + v, t_i = q_i/|q_i| and w_i = (t_i, r_i × t_i), the law is
    [n_b; m_b] = K (vu − vu*) + Σ τ_i w_i, and its Jacobian (R&W 2011's [[K_se + A, G], [B, K_bt + H]])
    is symmetric positive definite:

        K + Σ c_i [[I, −r̂_i], [r̂_i, |r_i|² I − r_i r_iᵀ]] − Σ c_i w_i w_iᵀ,    c_i = τ_i / |q_i|,

    whose first sum needs only Σc, Σc r and Σc r rᵀ; one Cholesky solve takes the step. The whole
    integration is this one function on scalars and one work array: a stage called as a function
    with its arrays cost as much again in argument passing and reference counting.

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
    routes = rod.routes
    tendons = rod.tendons
    length = rod.length_m
    mu = rod.friction_coeff
    line_mass = rod.line_mass_kg_per_m
    pm_s = rod.point_mass_s_m
    pm_m = rod.point_mass_kg
    kse0, kse1, kse2 = rod.kse[0], rod.kse[1], rod.kse[2]
    kbt0, kbt1, kbt2 = rod.kbt[0], rod.kbt[1], rod.kbt[2]
    # K_bt u* moved to the side of Rᵀ m: the law then reads Rᵀ m + K_bt u* = K_bt u + ….
    kbu0 = kbt0 * rod.precurvature_per_m[0]
    kbu1 = kbt1 * rod.precurvature_per_m[1]
    kbu2 = kbt2 * rod.precurvature_per_m[2]
    ikse0, ikse1, ikse2 = 1.0 / kse0, 1.0 / kse1, 1.0 / kse2
    ikbt0, ikbt1, ikbt2 = 1.0 / kbt0, 1.0 / kbt1, 1.0 / kbt2
    f0, f1, f2 = rod.tip_force_n[0], rod.tip_force_n[1], rod.tip_force_n[2]
    g0, g1, g2 = rod.gravity_m_s2[0], rod.gravity_m_s2[1], rod.gravity_m_s2[2]
    nt = tendons.shape[0]
    ny = 15 + 2 * nt
    res = np.zeros(3)
    # Work array: y, the stage state, k1..k4 (ny each), then the stage's tensions (nt).
    yt_at = ny
    k_at = 2 * ny
    tau_at = 6 * ny
    work = np.empty(6 * ny + nt)
    for i in range(3):
        work[i] = rod.base_position_m[i]
        for j in range(3):
            work[3 + 3 * i + j] = rod.base_rotation[i, j]
        work[12 + i] = m0[i]
    for i in range(15, ny):
        work[i] = 0.0
    for k in range(nt):
        work[tau_at + k] = tendons[k, T_TAU]
    for i in range(ny):
        states[0, i] = work[i]
    # The base strains start from the last integration's (``strains[0]``: a shooting solve's
    # integrations lie close together), or from the straight rod's where it holds none (NaN).
    warm = True
    for i in range(6):
        warm = warm and np.isfinite(strains[0, i])
    if warm:
        v0, v1, v2, u0, u1, u2 = strains[0, 0], strains[0, 1], strains[0, 2], strains[0, 3], strains[0, 4], strains[0, 5]
    else:
        v0, v1, v2, u0, u1, u2 = 0.0, 0.0, 1.0, 0.0, 0.0, 0.0
    # The strains change smoothly within an interval: each step's k2 and k4 start from the last
    # stage's strains moved along the slope between the last two steps' k1 strains. One Newton
    # step from there puts the tip within 1.1e-7 m of fully converged constitutive solves on the
    # zoo's robots (2e-9 m on the endoscope), well inside the RK4 error at 12 steps.
    sl0 = sl1 = sl2 = sl3 = sl4 = sl5 = 0.0
    st0 = st1 = st2 = st3 = st4 = st5 = 0.0
    nsteps = nodes.shape[0] - 1
    for k in range(nsteps):
        s = nodes[k]
        h = nodes[k + 1] - s
        mid = intervals[k]
        fresh = k == 0 or mid != intervals[k - 1]
        # The point masses distal to the interval (a station on one takes the limit from inside).
        point_weight = 0.0
        for j in range(pm_s.shape[0]):
            if pm_s[j] > mid:
                point_weight += pm_m[j]
        for stage in range(4):
            y_at = 0 if stage == 0 else yt_at
            dy_at = k_at + stage * ny
            ss = s if stage == 0 else s + h if stage == 3 else s + 0.5 * h
            route = 0 if stage == 0 else 2 if stage == 3 else 1
            # n(s): the tip force plus the weight distal to s.
            wd = line_mass * (length - ss) + point_weight
            n0 = f0 + wd * g0
            n1 = f1 + wd * g1
            n2 = f2 + wd * g2
            # Body-frame n, m: Rᵀ n, Rᵀ m (R stored row-major at y[3:12]).
            ra, rb, rc = work[y_at + 3], work[y_at + 4], work[y_at + 5]
            rd, re, rf = work[y_at + 6], work[y_at + 7], work[y_at + 8]
            rg, rh, ri = work[y_at + 9], work[y_at + 10], work[y_at + 11]
            ma, mb, mc = work[y_at + 12], work[y_at + 13], work[y_at + 14]
            nb0 = ra * n0 + rd * n1 + rg * n2
            nb1 = rb * n0 + re * n1 + rh * n2
            nb2 = rc * n0 + rf * n1 + ri * n2
            mb0 = ra * ma + rd * mb + rg * mc + kbu0
            mb1 = rb * ma + re * mb + rh * mc + kbu1
            mb2 = rc * ma + rf * mb + ri * mc + kbu2
            if mu != 0.0:
                for j in range(nt):
                    work[tau_at + j] = tendons[j, T_TAU] * np.exp(-mu * tendons[j, T_SIGMA] * work[y_at + 15 + j])
            converge = stage == 0 and fresh
            retry = k == 0 and stage == 0 and warm
            iterations = 0
            while True:
                # One Newton step on the law from (v, u); err: its residual before the step as a
                # strain, max over its rows of |residual| / stiffness (force rows over K_se:
                # dimensionless; moment rows over K_bt: 1/m).
                # The tendons' part of the residual (e) and of J depend on the strains alone, not on
                # this stage's state: summed apart, they need not wait for n_b, m_b.
                e0 = e1 = e2 = e3 = e4 = e5 = 0.0
                j00 = j01 = j02 = j03 = j04 = j05 = j11 = j12 = j13 = j14 = j15 = 0.0
                j22 = j23 = j24 = j25 = j33 = j34 = j35 = j44 = j45 = j55 = 0.0
                sc = sx = sy = sxx = sxy = syy = 0.0
                for j in range(nt):
                    tau = work[tau_at + j]
                    if routes[k, route, j, RT_ON] == 0.0 or tau == 0.0:
                        continue
                    rx = routes[k, route, j, RT_X]
                    ry = routes[k, route, j, RT_Y]
                    q0, q1, q2 = _tendon_direction(routes[k, route, j], u0, u1, u2, v0, v1, v2)
                    inv = 1.0 / np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
                    t0 = q0 * inv
                    t1 = q1 * inv
                    t2 = q2 * inv
                    w3 = ry * t2
                    w4 = -rx * t2
                    w5 = rx * t1 - ry * t0
                    e0 += tau * t0
                    e1 += tau * t1
                    e2 += tau * t2
                    e3 += tau * w3
                    e4 += tau * w4
                    e5 += tau * w5
                    c = tau * inv
                    cw = c * t0
                    j00 -= cw * t0; j01 -= cw * t1; j02 -= cw * t2; j03 -= cw * w3; j04 -= cw * w4; j05 -= cw * w5
                    cw = c * t1
                    j11 -= cw * t1; j12 -= cw * t2; j13 -= cw * w3; j14 -= cw * w4; j15 -= cw * w5
                    cw = c * t2
                    j22 -= cw * t2; j23 -= cw * w3; j24 -= cw * w4; j25 -= cw * w5
                    cw = c * w3
                    j33 -= cw * w3; j34 -= cw * w4; j35 -= cw * w5
                    cw = c * w4
                    j44 -= cw * w4; j45 -= cw * w5
                    j55 -= c * w5 * w5
                    sc += c
                    sx += c * rx
                    sy += c * ry
                    sxx += c * rx * rx
                    sxy += c * rx * ry
                    syy += c * ry * ry
                b0 = nb0 - kse0 * v0 - e0
                b1 = nb1 - kse1 * v1 - e1
                b2 = nb2 - kse2 * (v2 - 1.0) - e2
                b3 = mb0 - kbt0 * u0 - e3
                b4 = mb1 - kbt1 * u1 - e4
                b5 = mb2 - kbt2 * u2 - e5
                err = 0.0
                if converge:
                    err = max(abs(b0) * ikse0, abs(b1) * ikse1, abs(b2) * ikse2,
                              abs(b3) * ikbt0, abs(b4) * ikbt1, abs(b5) * ikbt2)
                j00 += kse0 + sc
                j11 += kse1 + sc
                j22 += kse2 + sc
                j05 -= sy
                j15 += sx
                j23 += sy
                j24 -= sx
                j33 += kbt0 + syy
                j34 -= sxy
                j44 += kbt1 + sxx
                j55 += kbt2 + sxx + syy
                # The step by blocks, J = [[A, G], [Gᵀ, H]] (3×3 each): A⁻¹ by its adjugate, the
                # Schur complement S = H − Gᵀ A⁻¹ G likewise. Each stage's solve waits on the last
                # one's strains: this takes two divisions in a row where a Cholesky factor takes six
                # square roots and divisions and two triangular solves. J is positive definite iff
                # A and S are, iff their leading minors are positive (a NaN fails them too).
                c00, c01, c02, c11, c12, c22, det = _adjugate_sym3(j00, j01, j02, j11, j12, j22)
                ok = j00 > 0.0 and c22 > 0.0 and det > 0.0
                if ok:
                    inv = 1.0 / det
                    c00 *= inv; c01 *= inv; c02 *= inv; c11 *= inv; c12 *= inv; c22 *= inv
                    # P = A⁻¹ G
                    p00 = c00 * j03 + c01 * j13 + c02 * j23
                    p01 = c00 * j04 + c01 * j14 + c02 * j24
                    p02 = c00 * j05 + c01 * j15 + c02 * j25
                    p10 = c01 * j03 + c11 * j13 + c12 * j23
                    p11 = c01 * j04 + c11 * j14 + c12 * j24
                    p12 = c01 * j05 + c11 * j15 + c12 * j25
                    p20 = c02 * j03 + c12 * j13 + c22 * j23
                    p21 = c02 * j04 + c12 * j14 + c22 * j24
                    p22 = c02 * j05 + c12 * j15 + c22 * j25
                    s00 = j33 - (j03 * p00 + j13 * p10 + j23 * p20)
                    s01 = j34 - (j03 * p01 + j13 * p11 + j23 * p21)
                    s02 = j35 - (j03 * p02 + j13 * p12 + j23 * p22)
                    s11 = j44 - (j04 * p01 + j14 * p11 + j24 * p21)
                    s12 = j45 - (j04 * p02 + j14 * p12 + j24 * p22)
                    s22 = j55 - (j05 * p02 + j15 * p12 + j25 * p22)
                    d00, d01, d02, d11, d12, d22, det = _adjugate_sym3(s00, s01, s02, s11, s12, s22)
                    ok = s00 > 0.0 and d22 > 0.0 and det > 0.0
                if ok:
                    inv = 1.0 / det
                    # x_v = A⁻¹ (b_v − G x_u), x_u = S⁻¹ (b_u − Gᵀ A⁻¹ b_v)
                    a0 = c00 * b0 + c01 * b1 + c02 * b2
                    a1 = c01 * b0 + c11 * b1 + c12 * b2
                    a2 = c02 * b0 + c12 * b1 + c22 * b2
                    b3 -= j03 * a0 + j13 * a1 + j23 * a2
                    b4 -= j04 * a0 + j14 * a1 + j24 * a2
                    b5 -= j05 * a0 + j15 * a1 + j25 * a2
                    x3 = (d00 * b3 + d01 * b4 + d02 * b5) * inv
                    x4 = (d01 * b3 + d11 * b4 + d12 * b5) * inv
                    x5 = (d02 * b3 + d12 * b4 + d22 * b5) * inv
                    v0 += a0 - (p00 * x3 + p01 * x4 + p02 * x5)
                    v1 += a1 - (p10 * x3 + p11 * x4 + p12 * x5)
                    v2 += a2 - (p20 * x3 + p21 * x4 + p22 * x5)
                    u0 += x3
                    u1 += x4
                    u2 += x5
                iterations += 1
                if ok and (not converge or err * length < _LOCAL_TOL):
                    break
                if not ok or iterations >= _LOCAL_MAX_ITER:
                    if not retry:
                        return False, res
                    # A warm base start the law cannot be solved from: once more from the straight rod's.
                    v0, v1, v2, u0, u1, u2 = 0.0, 0.0, 1.0, 0.0, 0.0, 0.0
                    retry = False
                    iterations = 0
            # p' = R v
            work[dy_at] = ra * v0 + rb * v1 + rc * v2
            work[dy_at + 1] = rd * v0 + re * v1 + rf * v2
            work[dy_at + 2] = rg * v0 + rh * v1 + ri * v2
            # R' = R û
            work[dy_at + 3] = rb * u2 - rc * u1
            work[dy_at + 4] = rc * u0 - ra * u2
            work[dy_at + 5] = ra * u1 - rb * u0
            work[dy_at + 6] = re * u2 - rf * u1
            work[dy_at + 7] = rf * u0 - rd * u2
            work[dy_at + 8] = rd * u1 - re * u0
            work[dy_at + 9] = rh * u2 - ri * u1
            work[dy_at + 10] = ri * u0 - rg * u2
            work[dy_at + 11] = rg * u1 - rh * u0
            # m' = −p' × n
            px, py, pz = work[dy_at], work[dy_at + 1], work[dy_at + 2]
            work[dy_at + 12] = -(py * n2 - pz * n1)
            work[dy_at + 13] = -(pz * n0 - px * n2)
            work[dy_at + 14] = -(px * n1 - py * n0)
            for j in range(nt):
                if routes[k, route, j, RT_ON] == 0.0:
                    work[dy_at + 15 + j] = 0.0
                    work[dy_at + 15 + nt + j] = 0.0
                    continue
                rx = routes[k, route, j, RT_X]
                ry = routes[k, route, j, RT_Y]
                q0, q1, q2 = _tendon_direction(routes[k, route, j], u0, u1, u2, v0, v1, v2)
                qn = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
                work[dy_at + 15 + nt + j] = qn
                if mu == 0.0:
                    work[dy_at + 15 + j] = 0.0  # the wrap angle only ever scales μ
                    continue
                # Wrap rate |u × t| (tendon direction turning with the backbone).
                c0 = u1 * q2 - u2 * q1
                c1 = u2 * q0 - u0 * q2
                c2 = u0 * q1 - u1 * q0
                work[dy_at + 15 + j] = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2) / qn
            # The next stage's state, and the strains to start it from.
            if stage == 0:
                if k == 0:
                    strains[0, 0], strains[0, 1], strains[0, 2] = v0, v1, v2
                    strains[0, 3], strains[0, 4], strains[0, 5] = u0, u1, u2
                elif fresh:
                    sl0 = sl1 = sl2 = sl3 = sl4 = sl5 = 0.0
                else:
                    ds = s - nodes[k - 1]
                    sl0, sl1, sl2 = (v0 - st0) / ds, (v1 - st1) / ds, (v2 - st2) / ds
                    sl3, sl4, sl5 = (u0 - st3) / ds, (u1 - st4) / ds, (u2 - st5) / ds
                st0, st1, st2, st3, st4, st5 = v0, v1, v2, u0, u1, u2
            if stage == 3:
                finite = True
                for i in range(ny):
                    yi = work[i] + h / 6.0 * (work[k_at + i] + 2.0 * work[k_at + ny + i] + 2.0 * work[k_at + 2 * ny + i]
                                              + work[k_at + 3 * ny + i])
                    work[i] = yi
                    states[k + 1, i] = yi
                    finite = finite and np.isfinite(yi)
                if not finite:
                    return False, res
                strains[k + 1, 0], strains[k + 1, 1], strains[k + 1, 2] = v0, v1, v2
                strains[k + 1, 3], strains[k + 1, 4], strains[k + 1, 5] = u0, u1, u2
            else:
                a = h if stage == 2 else 0.5 * h
                for i in range(ny):
                    work[yt_at + i] = work[i] + a * work[dy_at + i]
                if stage != 1:
                    half = 0.5 * h
                    v0 += half * sl0
                    v1 += half * sl1
                    v2 += half * sl2
                    u0 += half * sl3
                    u1 += half * sl4
                    u2 += half * sl5
    for i in range(3):
        res[i] = work[12 + i] - rod.tip_moment_nm[i]
    return True, res


@njit(cache=True)
def integrate_repeatedly(m0, rod, states, strains, count):
    """``count`` integrations at m0 (the benchmark times the kernel without Python around it);
    returns how many failed. It lives beside :func:`integrate` because Numba's cache checks a
    function's own source file only: a compiled copy of the kernel cached with another module
    would outlive changes to this one.
    """
    failed = 0
    for _ in range(count):
        ok, _res = integrate(m0, rod, states, strains)
        if not ok:
            failed += 1
    return failed


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
def _nearest_solved(estimates, out, i):
    """The converged case before ``i`` whose estimate of m(0) (N·m) is nearest to case i's
    (the latest of equals), or −1 for none."""
    best = -1
    best_d2 = np.inf
    for k in range(i - 1, -1, -1):
        if out[k, 0] != _CONVERGED:
            continue
        d2 = 0.0
        for j in range(3):
            d2 += (estimates[i, j] - estimates[k, j]) ** 2
        if d2 < best_d2:
            best, best_d2 = k, d2
    return best


@njit(cache=True)
def shoot_batch(rod, tensions, sigma, forces, moments, cold, estimates, guesses, guess_jacs, guess_kind, chain, tol_nm, max_iter,
                fd_step_nm, m0_out, jac_out, states, strains, traces, out):
    """:func:`shoot` for many load cases of one rod in one compiled call (``twin.rod.solve_batch``).

    Case i sets the tensions ``tensions[i]`` (N), friction directions ``sigma[i]``, tip force
    ``forces[i]`` (N) and moment ``moments[i]`` (N·m) into ``rod`` (its tendon table and tip
    arrays are overwritten: give it copies). It starts from ``guesses[i]`` (with ``guess_jacs[i]``
    when ``guess_kind[i]`` is 2, without when 1); with ``guess_kind[i]`` 0 and ``chain`` from the
    converged earlier case whose estimate of m(0) ``estimates[i]`` (N·m) is nearest
    (:func:`_nearest_solved`), its base moment moved by the difference of the two estimates, with
    its Jacobian; else from ``cold[i]``. A warm start
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
        elif chain and _nearest_solved(estimates, out, i) >= 0:
            # The solution of the solved case whose estimate lies nearest, moved by what the
            # estimates say the load change does to m(0) (they follow the tendon tensions and
            # tip loads to first order), with its shooting Jacobian.
            near = _nearest_solved(estimates, out, i)
            for j in range(3):
                m0[j] = m0_out[near, j] + estimates[i, j] - estimates[near, j]
            jac[:, :] = jac_out[near]
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
