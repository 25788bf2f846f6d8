"""Sensitivities of the tip pose to tendon tensions and tip loads, at a solved shape.

With the boundary residual r(m0, θ) = m(L) − M_e = 0 at the solution, the implicit function
theorem gives dm0/dθ = −(∂r/∂m0)⁻¹ ∂r/∂θ, and the tip pose T(m0, θ) then changes by
dT/dθ = ∂T/∂θ + ∂T/∂m0 · dm0/dθ. The partial derivatives come from forward differences of single
integrations from the converged m0 (7 + nt + 3 integrations, no re-solving; the tip moment's
columns are exact, as it enters only the boundary residual), so a pose and its Jacobian cost
about as much as one cold solve.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from twin.rod import kernel
from twin.rod.model import RodModel
from twin.rod.solver import RodSolution, kernel_args, solve

__all__ = ["TipJacobian", "tip_jacobian", "solve_with_jacobian"]


@dataclasses.dataclass(frozen=True)
class TipJacobian:
    """d(tip pose)/d(inputs). Rotation rows are the world-frame rotation vector δφ (rad).

    Columns of :attr:`matrix` are (τ_1 … τ_nt, F_x, F_y, F_z, M_x, M_y, M_z) and its rows
    (p_x, p_y, p_z, δφ_x, δφ_y, δφ_z); units m/N, m/(N·m), rad/N, rad/(N·m).
    """

    matrix: np.ndarray
    tendon_count: int

    @property
    def position_wrt_tension(self) -> np.ndarray:
        """(3, nt) m/N."""
        return self.matrix[:3, : self.tendon_count]

    @property
    def rotation_wrt_tension(self) -> np.ndarray:
        """(3, nt) rad/N."""
        return self.matrix[3:, : self.tendon_count]

    @property
    def position_wrt_force(self) -> np.ndarray:
        """(3, 3) m/N."""
        return self.matrix[:3, self.tendon_count : self.tendon_count + 3]

    @property
    def rotation_wrt_force(self) -> np.ndarray:
        """(3, 3) rad/N."""
        return self.matrix[3:, self.tendon_count : self.tendon_count + 3]

    @property
    def position_wrt_moment(self) -> np.ndarray:
        """(3, 3) m/(N·m)."""
        return self.matrix[:3, self.tendon_count + 3 :]

    @property
    def rotation_wrt_moment(self) -> np.ndarray:
        """(3, 3) rad/(N·m)."""
        return self.matrix[3:, self.tendon_count + 3 :]


def _rotation_vector(delta: np.ndarray) -> np.ndarray:
    """Small-angle rotation vector of δR (world frame): vee of the skew part."""
    return 0.5 * np.array([delta[2, 1] - delta[1, 2], delta[0, 2] - delta[2, 0], delta[1, 0] - delta[0, 1]])


def tip_jacobian(model: RodModel, solution: RodSolution) -> TipJacobian:
    """The tip-pose Jacobian at a converged ``solution`` of ``model``.

    Raises:
        ValueError: the solution did not converge (there is no shape to differentiate).
    """
    if not solution.converged:
        raise ValueError(f"tip_jacobian needs a converged solution (status {solution.status!r})")
    load = solution.load
    nt = model.tendon_count
    k = model.stations
    states = np.empty((k, 15 + 2 * nt))
    strains = np.empty((k, 6))
    m0 = solution.base_moment_nm
    p_ref = solution.tip_position_m
    r_ref = solution.tip_rotation
    scale = model.moment_scale_nm

    # The kernel's arguments are built once; each perturbation is made in place and undone.
    args = list(kernel_args(model, load, states, strains))
    tendons = args[6]  # a copy of the model's tendon table with this load's tensions
    force = args[9] = load.tip_force_n.copy()
    column = kernel.T_TAU

    def run(m0_, tendon: int | None = None, force_axis: int | None = None, h: float = 0.0):
        if tendon is not None:
            tendons[tendon, column] += h
        if force_axis is not None:
            force[force_axis] += h
        ok, res = kernel.integrate(np.array(m0_, dtype=float), *args)
        if tendon is not None:
            tendons[tendon, column] = load.tensions_n[tendon]
        if force_axis is not None:
            force[force_axis] = load.tip_force_n[force_axis]
        if not ok:
            raise ValueError("tip_jacobian: a perturbed integration failed; the solution is on a singular branch")
        dpose = np.concatenate([states[-1, 0:3] - p_ref,
                                _rotation_vector(states[-1, 3:12].reshape(3, 3) @ r_ref.T)])
        return res.copy(), dpose

    # ∂r/∂m0 and ∂T/∂m0 by central differences: the implicit-function step amplifies their
    # error by the conditioning of ∂r/∂m0, so they get the second-order scheme.
    h_m = 1e-5 * scale
    dr_dm = np.empty((3, 3))
    dt_dm = np.empty((6, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = h_m
        res_p, pose_p = run(m0 + e)
        res_m, pose_m = run(m0 - e)
        dr_dm[:, j] = (res_p - res_m) / (2 * h_m)
        dt_dm[:, j] = (pose_p - pose_m) / (2 * h_m)
    # Forward differences are taken against an integration of the unperturbed case in this very
    # routine, so that no difference in how the reference was reached leaks in as O(eps/h).
    res_0, pose_0 = run(m0)
    ncol = nt + 6
    dr_dth = np.zeros((3, ncol))
    dt_dth = np.zeros((6, ncol))
    # The tip moment enters only the boundary residual r = m(L) − M_e (kernel.integrate): at a
    # fixed m0 the shape does not move, so ∂r/∂M_e = −I and ∂T/∂M_e = 0, exactly.
    dr_dth[:, nt + 3:] = -np.eye(3)
    h_tau = 1e-6 * max(1.0, float(np.max(load.tensions_n)))
    h_f = 1e-6 * max(0.1, float(np.max(np.abs(load.tip_force_n))))
    for j in range(nt + 3):
        if j < nt:
            h = h_tau
            res, dpose = run(m0, tendon=j, h=h)
        else:
            h = h_f
            res, dpose = run(m0, force_axis=j - nt, h=h)
        dr_dth[:, j] = (res - res_0) / h
        dt_dth[:, j] = (dpose - pose_0) / h
    dm0 = -np.linalg.solve(dr_dm, dr_dth)
    return TipJacobian(matrix=dt_dth + dt_dm @ dm0, tendon_count=nt)


def solve_with_jacobian(model: RodModel, tensions_n, **kwargs) -> tuple[RodSolution, TipJacobian]:
    """:func:`solve` then :func:`tip_jacobian`: the tip pose and its Jacobian in one call."""
    sol = solve(model, tensions_n, **kwargs)
    return sol, tip_jacobian(model, sol)
