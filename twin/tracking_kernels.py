"""The tracker fusion's Numba kernels (:func:`twin.tracking.fuse`): Wahba's problem and the tip
pose from two 5-DOF probes. Apart from :mod:`twin.tracking` so that the tracker's data types, and
the rig driver that uses them, load without Numba; the first fusion imports this.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from twin.resources import announce_kernel_compile

announce_kernel_compile(__file__, "the tracker fusion's kernels")

__all__ = ["angle_between_rad", "fuse_geometry"]


@numba.njit(cache=True)
def angle_between_rad(u: np.ndarray, v: np.ndarray) -> float:
    """The angle between two vectors (rad): atan2 of |u×v| and u·v stays accurate near 0 and π,
    where arccos of the dot product does not."""
    return math.atan2(np.linalg.norm(np.cross(u, v)), np.dot(u, v))


@numba.njit(cache=True)
def _wahba(b: np.ndarray) -> np.ndarray:
    """Rotation R (body → world) minimising Σ w_i |world_i − R body_i|², from
    B = Σ w_i world_i body_iᵀ (3, 3).

    R = U diag(1, 1, det U det V) Vᵀ for B = U Σ Vᵀ (Markley 1988), taken from the two leading
    eigenvectors v₁, v₂ of BᵀB (Horn, Hilden & Negahdaripour 1988): u_k = B v_k / σ_k and
    R = u₁v₁ᵀ + u₂v₂ᵀ + (u₁×u₂)(v₁×v₂)ᵀ, a proper rotation by construction. Any orthonormal
    pair spanning a repeated eigenvalue's space gives the same R.

    Falls back to the SVD when the directions are all (nearly) parallel (σ₂ < 10⁻⁶ σ₁), where
    u₂ would be rounding error and R is not determined anyway.
    """
    eigval, eigvec = np.linalg.eigh(b.T @ b)  # ascending
    if not eigval[1] > 1e-12 * eigval[2]:
        u, _, vt = np.linalg.svd(b)
        if np.linalg.det(u) * np.linalg.det(vt) < 0:
            u[:, 2] = -u[:, 2]
        return u @ vt
    v1, v2 = eigvec[:, 2].copy(), eigvec[:, 1].copy()
    u1, u2 = b @ v1, b @ v2
    # u₁ ⟂ u₂ exactly; re-orthonormalising removes the rounding a small σ₂ amplifies.
    u1 /= np.linalg.norm(u1)
    u2 -= np.dot(u1, u2) * u1
    u2 /= np.linalg.norm(u2)
    return np.outer(u1, v1) + np.outer(u2, v2) + np.outer(np.cross(u1, u2), np.cross(v1, v2))


@numba.njit(cache=True)
def fuse_geometry(pa, pb, axis_a, axis_b, body, probe_sum_m, weights):
    """The pose of :func:`fuse` from probe positions (m) and axes (world frame), with the cap's
    body directions, c_A + c_B and the directions' weights: (position (3,) m, rotation (3, 3),
    probe distance m, inter-axis angle rad)."""
    axis_a, axis_b = axis_a / np.linalg.norm(axis_a), axis_b / np.linalg.norm(axis_b)
    baseline = pb - pa
    distance_m = np.linalg.norm(baseline)
    world = np.empty((3, 3))
    world[0], world[1], world[2] = axis_a, axis_b, baseline / distance_m
    # B = Σ w_i world_i body_iᵀ, the matrix whose SVD solves Wahba's problem.
    rotation = _wahba((world.T * weights) @ body)
    # The mean over both probes of p_i − R c_i.
    position_m = 0.5 * (pa + pb - rotation @ probe_sum_m)
    return position_m, rotation, distance_m, angle_between_rad(axis_a, axis_b)
