"""Intrinsic tip force sensing: the tip wrench from measured tendon tensions and the tracked tip pose.

The predictor maps (tensions τ, tip force F, tip moment M) to the tip pose; with τ measured by the
load cells and the pose by the tracker, the unknown load is what makes the predicted pose meet the
measured one. :func:`estimate_tip_wrench` finds it by Levenberg-Marquardt on the pose residual, weighted by
the measurement covariance

    Σ_y = diag(σ_p² I, σ_φ² I) + J_τ σ_τ² J_τᵀ

(tracker position and rotation noise, load-cell noise carried through the tension Jacobian), and
returns the covariance of the estimate from the Fisher information Jᵀ Σ_y⁻¹ J (J the Jacobian of the
pose with respect to the unknowns) plus a model-form term (a relative uncertainty of the force
itself, for a model whose stiffness is only known to that fraction).

What the measurements cannot see is said, not guessed: an eigendirection of the information whose
standard deviation exceeds ``max_std_n`` (e.g. the axial force of a straight rod, which only
shortens it by F L / EA) is unobservable; the estimate has no component along it, and a world axis
that has a sizeable share of an unobservable direction is reported as NaN, never as zero.

By default the load is a force at a point contact (no tip moment): six pose measurements then
determine three unknowns. ``estimate_moment=True`` adds the tip moment as three more unknowns; a
tip force and a tip moment bend a rod in nearly the same way, so expect most of it to be reported as
unobservable unless the pose is measured well.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import scipy.stats

from twin import effects
from twin.params import Params
from twin.rod import RodModel, solve, tip_jacobian

__all__ = ["WrenchEstimate", "estimate_tip_wrench", "rotation_vector"]

# Floors on the sensor noise (a simulated sensor may report 0): the predictor's own resolution,
# about 1 µm and 10 µrad at its default tolerance, below which a residual means nothing.
_POSITION_FLOOR_M = 1e-6
_ROTATION_FLOOR_RAD = 1e-5
# A world axis is reported unobservable when an unobservable direction has at least this share
# (cosine) along it: its component would otherwise carry an arbitrary part of that direction.
_AXIS_SHARE = 0.1


def rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """The rotation vector φ (rad, (3,)) of a 3×3 rotation: axis · angle (log map)."""
    r = np.asarray(rotation, dtype=float)
    cos = np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)
    angle = float(np.arccos(cos))
    axis2 = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if angle < 1e-6:
        return 0.5 * axis2
    if np.pi - angle < 1e-4:
        # Near π the antisymmetric part vanishes: the axis from the symmetric part.
        k = int(np.argmax(np.diag(r)))
        axis = (r[:, k] + np.eye(3)[k]) / np.sqrt(2.0 * (1.0 + r[k, k]))
        return angle * axis
    return angle / (2.0 * np.sin(angle)) * axis2


def _skew(v) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclasses.dataclass(frozen=True)
class WrenchEstimate:
    """A tip wrench estimate (world frame: the load applied at the tip).

    Attributes:
        force_n: (3,) tip force (N); NaN on an axis that is not observable.
        force_cov_n2: (3, 3) covariance of ``force_n`` (N²); NaN rows/columns on unobservable axes.
        force_observable: (3,) per world axis, whether its component is observable.
        force_observable_n: (3,) the estimate's projection on the observable subspace (N), every axis.
        force_observable_cov_n2: (3, 3) its covariance (N², rank = the observable directions).
        unobservable_force_directions: (k, 3) unit vectors along which the force is not seen.
        moment_nm: (3,) tip moment (N·m); None when not estimated (point contact), NaN on
            unobservable axes.
        moment_cov_nm2, moment_observable, unobservable_moment_directions: as for the force; None
            when the moment is not estimated.
        force_std_n: (3,) standard deviation (N) along each principal direction of the force
            information, ascending; inf where unobservable.
        converged: the Levenberg-Marquardt iteration met its step tolerance and every solve converged.
        iterations: Levenberg-Marquardt iterations.
        residual_chi2: whitened squared pose residual at the estimate (≈ the number of pose
            measurements less the unknowns when the model and the noise are right).
        consistent: whether ``residual_chi2`` is within the 99.9 % quantile of χ² with (measurements −
            unknowns) degrees of freedom: False flags a pose no tip force explains (an unmodelled
            moment or contact along the body, a model off); None with no spare measurement.
        estimate_time_s: CPU time of the estimate (s).
        tip_position_m, tip_rotation: the predicted tip pose under the estimate.
    """

    force_n: np.ndarray
    force_cov_n2: np.ndarray
    force_observable: np.ndarray
    force_observable_n: np.ndarray
    force_observable_cov_n2: np.ndarray
    unobservable_force_directions: np.ndarray
    moment_nm: np.ndarray | None
    moment_cov_nm2: np.ndarray | None
    moment_observable: np.ndarray | None
    unobservable_moment_directions: np.ndarray | None
    force_std_n: np.ndarray
    converged: bool
    iterations: int
    residual_chi2: float
    consistent: bool | None
    estimate_time_s: float
    tip_position_m: np.ndarray
    tip_rotation: np.ndarray
    # What the next estimate of a live stream starts from (``previous=``): the unknowns (force in N;
    # moment over the rod's length, N), the predictor's solution and the linearisation at the estimate.
    unknowns: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)
    solution: object = dataclasses.field(default=None, repr=False, compare=False)
    jacobian: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)
    weight: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        """JSON-ready: NaN as null."""

        def clean(a):
            if a is None:
                return None
            a = np.asarray(a, dtype=float)
            return np.where(np.isfinite(a), a, np.nan).tolist() if a.ndim else float(a)

        def nulls(x):
            if isinstance(x, list):
                return [nulls(v) for v in x]
            return None if isinstance(x, float) and not np.isfinite(x) else x

        return {
            "force_n": nulls(clean(self.force_n)),
            "force_cov_n2": nulls(clean(self.force_cov_n2)),
            "force_observable_n": clean(self.force_observable_n),
            "force_observable_cov_n2": clean(self.force_observable_cov_n2),
            "moment_nm": nulls(clean(self.moment_nm)),
            "moment_cov_nm2": nulls(clean(self.moment_cov_nm2)),
            "observable": {
                "force": [bool(b) for b in self.force_observable],
                "unobservable_force_directions": clean(self.unobservable_force_directions),
                "moment": None if self.moment_observable is None else [bool(b) for b in self.moment_observable],
                "unobservable_moment_directions": clean(self.unobservable_moment_directions),
            },
            "force_std_n": nulls(clean(self.force_std_n)),
            "converged": bool(self.converged),
            "iterations": int(self.iterations),
            "residual_chi2": float(self.residual_chi2),
            "consistent": self.consistent,
            "estimate_time_s": float(self.estimate_time_s),
        }


def _subspace(info: np.ndarray, max_std: float):
    """(observable basis (3, k), eigenvalues (k,), unobservable basis (3, 3-k), stds ascending (3,))."""
    lam, vec = np.linalg.eigh(0.5 * (info + info.T))
    ok = lam > 1.0 / max_std**2
    std = np.where(lam > 0, 1.0 / np.sqrt(np.maximum(lam, 1e-300)), np.inf)
    std = np.where(ok, std, np.inf)
    order = np.argsort(std)
    return vec[:, ok], lam[ok], vec[:, ~ok], std[order]


def _axis_report(value, cov_obs, unobs_dirs):
    """Per world axis: observable flag, value (NaN if not), covariance with NaN rows/columns."""
    share = np.abs(unobs_dirs).max(axis=1) if unobs_dirs.size else np.zeros(3)
    observable = share < _AXIS_SHARE
    out = np.where(observable, value, np.nan)
    cov = cov_obs.copy()
    cov[~observable, :] = np.nan
    cov[:, ~observable] = np.nan
    return observable, out, cov


def estimate_tip_wrench(params: Params, tensions_n, tip_position_m, tip_rotation=None, *,
                        base_rotation=None, friction_direction=None, model: RodModel | None = None,
                        estimate_moment: bool = False, model_error_fraction: float = 0.02,
                        max_std_n: float = 0.01, max_std_nm: float = 0.0004, max_iterations: int = 40,
                        tolerance_n: float = 1e-5, previous: WrenchEstimate | None = None) -> WrenchEstimate:
    """Estimate the tip wrench that makes the predictor meet the measured tip pose.

    Args:
        params: the robot's parameter set (sensor noise from ``[sensors]``, effects applied as in
            the prediction: load-cell response, clamp, tracker offset).
        tensions_n: (n,) tensions as the load cells report them (N).
        tip_position_m: (3,) the tracker's measured position, base frame (m).
        tip_rotation: (3, 3) measured tip rotation (world), or None when not measured (position only).
        base_rotation: nominal base orientation (3×3); default the parameter set's ``rig.base_quat``.
        friction_direction: per tendon sliding state (see :class:`twin.rod.LoadCase`); default pulled.
        model: the rod (default :meth:`RodModel.from_params`), to share one between estimates.
        estimate_moment: estimate the tip moment too (default: a point contact, force only).
        model_error_fraction: relative uncertainty of the force from the model's form (stiffness
            known to about this fraction); default 0.02, an assumption of a calibrated model.
        max_std_n, max_std_nm: a direction whose standard deviation exceeds this is unobservable;
            defaults 0.01 N (a 1σ of 5 % of a mid-range 0.2 N contact force: a direction seen worse is
            not resolved to that) and 0.0004 N·m (that force at a 40 mm lever).
        max_iterations, tolerance_n: the iteration stops when a step is below ``tolerance_n`` (N;
            N·m for the moment, scaled by the rod's length) or below 0.01 of the estimate's
            standard deviation along it.
        previous: the last estimate of a live stream (same robot, options and measured rows): a warm
            estimate starts from its load and shape and steps with its Jacobian (a chord
            iteration: one predictor solve per step, none of the Jacobian's integrations), and
            linearises afresh only once, at the new estimate, for the covariance and the next
            estimate. Ignored when it does not fit (another option set, or it failed).

    Raises:
        ValueError: malformed input (names the argument and value).
    """
    start = time.process_time()
    model = model or RodModel.from_params(params)
    nt = model.tendon_count
    tensions = np.clip(effects.true_tensions_n(params, np.asarray(tensions_n, dtype=float)), 0.0, None)
    if tensions.shape != (nt,):
        raise ValueError(f"tensions_n = {np.asarray(tensions_n).tolist()}: expected {nt} tensions")
    p_meas = np.asarray(tip_position_m, dtype=float).reshape(-1)
    if p_meas.size != 3 or not np.isfinite(p_meas).all():
        raise ValueError(f"tip_position_m = {p_meas.tolist()}: expected 3 finite numbers")
    r_meas = None
    if tip_rotation is not None:
        r_meas = np.asarray(tip_rotation, dtype=float)
        if r_meas.shape != (3, 3) or not np.isfinite(r_meas).all() \
                or not np.allclose(r_meas @ r_meas.T, np.eye(3), atol=1e-4) or np.linalg.det(r_meas) < 0:
            raise ValueError(f"tip_rotation = {np.asarray(tip_rotation).tolist()}: must be a proper 3x3 rotation")
    rotation = effects.clamp_rotation(params, params.rig.base_rotation if base_rotation is None else base_rotation)
    offset = effects.tracker_offset_m(params)
    sensors = params.sensors
    sp = max(sensors.tracker_noise_m, _POSITION_FLOOR_M)
    sr = max(sensors.tracker_noise_rad, _ROTATION_FLOOR_RAD)
    st = sensors.loadcell_noise_n
    rows = 3 if r_meas is None else 6
    nu = 6 if estimate_moment else 3
    # Moment columns are scaled by L so that all unknowns are in N (a moment M acts like a force M/L).
    length = model.length_m
    theta = np.zeros(nu)
    warm = (previous is not None and previous.jacobian is not None and previous.solution is not None
            and previous.jacobian.shape == (rows, nu) and previous.unknowns is not None)
    # Steps are held within a trust radius (0.2 N: the 0–0.3 N contact range in two steps; the
    # pose is far from linear in the force over it) and halved until the weighted residual falls.
    radius = 0.2
    # A weak prior on the load, F ~ N(0, (1 N)²) (M ~ N(0, (1 N · L)²)): three times the contact range,
    # nothing against what the pose sees (2 mN), enough to keep what it cannot see near zero.
    prior = 1.0
    damping = 1e-3
    guess = None

    def evaluate(theta, guess):
        force = theta[:3]
        moment = theta[3:] * length if estimate_moment else None
        sol = solve(model, tensions, tip_force_n=force, tip_moment_nm=moment, base_rotation=rotation,
                    friction_direction=friction_direction, raise_on_failure=False,
                    guess_nm=None if guess is None else guess.base_moment_nm,
                    guess_jacobian=None if guess is None else guess.shooting_jacobian)
        if not sol.converged and guess is not None:
            sol = solve(model, tensions, tip_force_n=force, tip_moment_nm=moment, base_rotation=rotation,
                        friction_direction=friction_direction, raise_on_failure=False)
        if not sol.converged:
            return None, None
        residual = p_meas - (sol.tip_position_m + sol.tip_rotation @ offset)
        if r_meas is not None:
            residual = np.concatenate([residual, rotation_vector(r_meas @ sol.tip_rotation.T)])
        return sol, residual

    def linearise(sol):
        tj = tip_jacobian(model, sol)
        lever = sol.tip_rotation @ offset
        # Tracked point p + R o: its change is dp + δφ × (R o) = dp − [R o]× δφ.
        to_tracked = np.hstack([np.eye(3), -_skew(lever)])
        full = np.vstack([to_tracked @ tj.matrix, tj.matrix[3:]])[:rows]
        j_tau = full[:, :nt]
        jac = full[:, nt:nt + 3]
        if estimate_moment:
            jac = np.hstack([jac, full[:, nt + 3:] * length])
        cov_y = np.diag([sp**2] * 3 + [sr**2] * 3)[:rows, :rows] + st**2 * j_tau @ j_tau.T
        return jac, np.linalg.inv(cov_y)

    def small(step, info):
        # Below the tolerance, or below a hundredth of the estimate's own standard deviation along
        # it: where a direction is seen only to several mN, the predictor's µm resolution moves
        # its optimum by more than tolerance_n from one solve to the next, and steps there would
        # never settle below it.
        return bool(np.max(np.abs(step)) < tolerance_n or step @ (info + prior * np.eye(nu)) @ step < 1e-4)

    converged = False
    iterations = 0
    jac: np.ndarray | None = None
    weight: np.ndarray | None = None
    chi2 = float("nan")
    if warm and previous is not None and previous.unknowns is not None:
        # Near the answer already: Gauss-Newton steps, damped only if one fails to decrease the cost.
        damping = 1e-9
        theta = previous.unknowns.copy()
        sol, residual = evaluate(theta, previous.solution)
        if sol is None:
            warm, theta = False, np.zeros(nu)
    if not warm:
        sol, residual = evaluate(theta, None)
    linearised = None  # the solution ``jac`` and ``weight`` were computed at
    solved = sol is not None
    for iterations in range(1, max_iterations + 1):
        if not solved:
            break
        # Nearby loads start from this shape and its shooting Jacobian (Broyden updates of it).
        guess = sol
        if warm and iterations == 1 and previous is not None:
            # The load moves little between two estimates at 40 Hz: the last Jacobian takes the
            # first step. Later steps linearise afresh: repeated steps with a stale Jacobian
            # contract slowly where the pose is noisy (single tracker frames), and their fixed
            # point is not the least-squares one.
            jac, weight = previous.jacobian, previous.weight
        elif linearised is not sol:
            jac, weight = linearise(sol)
            linearised = sol
        assert jac is not None and weight is not None, "linearised on the first iteration"
        chi2 = float(residual @ weight @ residual)
        info = jac.T @ weight @ jac
        gradient = jac.T @ weight @ residual - prior * theta
        cost = chi2 + prior * float(theta @ theta)
        # Levenberg-Marquardt, damped alike in every direction (scaled by the mean information):
        # that holds back the directions the pose barely sees until the seen ones have settled; the
        # weak prior keeps the unseen ones from wandering.
        gauss_newton = np.linalg.solve(info + prior * np.eye(nu), gradient)
        if small(gauss_newton, info):
            # Already where the cost is least (to the tolerance): no solve to try the step.
            converged = True
            break
        for _ in range(10):
            step = np.linalg.solve(info + (prior + damping * np.trace(info) / nu) * np.eye(nu), gradient)
            size = float(np.linalg.norm(step))
            if size > radius:
                step *= radius / size
            trial_sol, trial_res = evaluate(theta + step, guess)
            if trial_sol is not None:
                trial = theta + step
                trial_cost = float(trial_res @ weight @ trial_res) + prior * float(trial @ trial)
                if trial_cost <= cost * (1 + 1e-12) + 1e-15:
                    damping = max(damping / 3.0, 1e-9)
                    break
            damping *= 4.0
        else:
            # No decrease however short the step: the estimate is where the cost is least.
            converged = bool(np.max(np.abs(step)) < tolerance_n * 10 or small(step / 10, info))
            break
        theta = theta + step
        sol, residual = trial_sol, trial_res
        if small(step, info):
            converged = True
            break
    if solved:
        if linearised is not sol:
            jac, weight = linearise(sol)
        assert jac is not None and weight is not None, "linearised on the first iteration"
        chi2 = float(residual @ weight @ residual)
    nan3 = np.full(3, np.nan)
    if not solved or jac is None:
        return WrenchEstimate(nan3, np.full((3, 3), np.nan), np.zeros(3, bool), nan3,
                              np.full((3, 3), np.nan), np.eye(3),
                              nan3 if estimate_moment else None, np.full((3, 3), np.nan) if estimate_moment else None,
                              np.zeros(3, bool) if estimate_moment else None, np.eye(3) if estimate_moment else None,
                              np.full(3, np.inf), False, iterations, float("nan"), None,
                              time.process_time() - start, nan3, np.full((3, 3), np.nan))
    # The information at the estimate.
    info = jac.T @ weight @ jac
    if estimate_moment:
        # The force's marginal information: the moment's uncertainty taken out (Schur complement),
        # with the moment's own in N·m.
        info_ff = info[:3, :3] - info[:3, 3:] @ np.linalg.pinv(info[3:, 3:]) @ info[3:, :3]
        info_mf = info[3:, 3:] - info[3:, :3] @ np.linalg.pinv(info[:3, :3]) @ info[:3, 3:]
        info_mm = info_mf / length**2
    else:
        info_ff = info
    force = theta[:3]
    obs, lam, unobs, std = _subspace(info_ff, max_std_n)
    projector = obs @ obs.T
    force_obs = projector @ force
    cov = obs @ np.diag(1.0 / lam) @ obs.T + model_error_fraction**2 * np.outer(force_obs, force_obs)
    f_observable, f_out, f_cov = _axis_report(force_obs, cov, unobs)
    m_out = m_cov = m_observable = m_unobs = None
    if estimate_moment:
        moment = theta[3:] * length
        mobs, mlam, m_unobs, _ = _subspace(info_mm, max_std_nm)
        moment_obs = mobs @ mobs.T @ moment
        mcov = mobs @ np.diag(1.0 / mlam) @ mobs.T + model_error_fraction**2 * np.outer(moment_obs, moment_obs)
        m_observable, m_out, m_cov = _axis_report(moment_obs, mcov, m_unobs)
    return WrenchEstimate(
        force_n=f_out, force_cov_n2=f_cov, force_observable=f_observable, force_observable_n=force_obs,
        force_observable_cov_n2=cov,
        unobservable_force_directions=unobs.T, moment_nm=m_out, moment_cov_nm2=m_cov, moment_observable=m_observable,
        unobservable_moment_directions=None if m_unobs is None else m_unobs.T, force_std_n=std,
        converged=converged, iterations=iterations, residual_chi2=chi2,
        consistent=bool(chi2 <= scipy.stats.chi2.ppf(0.999, rows - nu)) if rows > nu else None,
        estimate_time_s=time.process_time() - start, tip_position_m=sol.tip_position_m, tip_rotation=sol.tip_rotation,
        unknowns=theta.copy(), solution=sol, jacobian=jac, weight=weight)
