"""Sensitivities of the tip pose to tendon tensions and tip loads, at a solved shape.

With the boundary residual r(m0, θ) = m(L) − M_e = 0 at the solution, the implicit function
theorem gives dm0/dθ = −(∂r/∂m0)⁻¹ ∂r/∂θ, and the tip pose T(m0, θ) then changes by
dT/dθ = ∂T/∂θ + ∂T/∂m0 · dm0/dθ. The partial derivatives come from forward differences of single
integrations from the converged m0 (4 + nt + 3 integrations, no re-solving; the tip moment's
columns are exact, as it enters only the boundary residual), so a pose and its Jacobian cost
about as much as one cold solve.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from twin.rod import kernel
from twin.rod.model import RodModel
from twin.rod.solver import RodSolution, rod_inputs, solve

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


def tip_jacobian(model: RodModel, solution: RodSolution) -> TipJacobian:
    """The tip-pose Jacobian at a converged ``solution`` of ``model``.

    Raises:
        ValueError: the solution did not converge (there is no shape to differentiate).
    """
    if not solution.converged:
        raise ValueError(f"tip_jacobian needs a converged solution (status {solution.status.label!r})")
    load = solution.load
    nt = model.tendon_count
    k = model.stations
    states = np.empty((k, 15 + 2 * nt))
    strains = np.empty((k, 6))
    strains[0] = solution.strains[0]  # the base strains to start from (kernel.integrate)
    m0 = solution.base_moment_nm
    p_ref = solution.tip_position_m
    r_ref = solution.tip_rotation
    scale = model.moment_scale_nm

    # The kernel perturbs the tendon table and the tip force in place: both are copies here
    # (rod_inputs builds its own tendon table).
    rod = rod_inputs(model, load)._replace(tip_force_n=load.tip_force_n.copy())
    # Every partial derivative is a forward difference against an integration of the unperturbed
    # case in the same call, so that no difference in how the reference was reached leaks in as
    # O(eps/h). Forward rather than central differences for ∂r/∂m0 and ∂T/∂m0, although the
    # implicit-function step amplifies their error by the conditioning of ∂r/∂m0: over the zoo's
    # robots and the thesis grid the Jacobian moves by at most 2.4e-5 of its column's largest
    # entry, for three integrations fewer.
    h_m = 1e-5 * scale
    # Maxima of a few numbers as Python floats: numpy's reductions cost more than they do.
    h_tau = 1e-6 * max(1.0, *load.tensions_n.tolist())
    h_f = 1e-6 * max(0.1, *map(abs, load.tip_force_n.tolist()))
    ncol = nt + 6
    dr_dm = np.empty((3, 3))
    dt_dm = np.empty((6, 3))
    dr_dth = np.zeros((3, ncol))
    dt_dth = np.zeros((6, ncol))
    # The tip moment enters only the boundary residual r = m(L) − M_e (kernel.integrate): at a
    # fixed m0 the shape does not move, so ∂r/∂M_e = −I and ∂T/∂M_e = 0, exactly.
    dr_dth[:, nt + 3:] = _MINUS_IDENTITY
    # All 4 + nt + 3 integrations in one compiled call.
    if not kernel.tip_sensitivities(np.asarray(m0, dtype=float), h_m, h_tau, h_f, np.asarray(p_ref, dtype=float),
                                    np.asarray(r_ref, dtype=float), rod, states, strains, dr_dm, dt_dm, dr_dth, dt_dth):
        raise ValueError("tip_jacobian: a perturbed integration failed; the solution is on a singular branch")
    dm0 = -(_inverse_3x3(dr_dm) @ dr_dth)
    return TipJacobian(matrix=dt_dth + dt_dm @ dm0, tendon_count=nt)


_MINUS_IDENTITY = -np.eye(3)


def _inverse_3x3(a: np.ndarray) -> np.ndarray:
    """The inverse of a 3×3 matrix by its adjugate, in Python floats: ``np.linalg.solve``'s
    argument handling costs ~10 µs on a Jacobian of ~300 µs. A singular or non-finite matrix goes
    to ``np.linalg.inv``, which raises as the solve did."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a.tolist()
    c00, c01, c02 = a11 * a22 - a12 * a21, a12 * a20 - a10 * a22, a10 * a21 - a11 * a20
    det = a00 * c00 + a01 * c01 + a02 * c02
    if not (math.isfinite(det) and det != 0.0):
        return np.linalg.inv(a)
    return np.array([[c00, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11],
                     [c01, a00 * a22 - a02 * a20, a02 * a10 - a00 * a12],
                     [c02, a01 * a20 - a00 * a21, a00 * a11 - a01 * a10]]) / det


def solve_with_jacobian(model: RodModel, tensions_n, **kwargs) -> tuple[RodSolution, TipJacobian]:
    """:func:`solve` then :func:`tip_jacobian`: the tip pose and its Jacobian in one call."""
    sol = solve(model, tensions_n, **kwargs)
    return sol, tip_jacobian(model, sol)
