"""Load cases of the thesis validation grid for the predictor (thesis §8.3).

Until measured tensions exist, each PCC configuration is realised by the tensions that bend
the unloaded, weightless model to curvature κ in plane φ on top of the pretension: the two
tendons whose angles bracket φ (one, if a tendon sits at φ) carry the bending moment EI κ
towards φ, split so that their moments add up to it exactly, τ_a = τ_pre + (EI κ / r)·sin(b − φ)/sin(b − a)
and τ_b = τ_pre + (EI κ / r)·sin(φ − a)/sin(b − a) for neighbours at a ≤ φ ≤ b; the others keep
the pretension. With four tendons at 90° this is (EI κ / r)·max(0, cos(φ − α_i)); with any
layout whose neighbours are less than 180° apart, every plane can be bent. A plane between two
tendons 180° or more apart cannot be: :func:`pcc_realisable` says so. A layout whose tendons do
not balance (their unit vectors do not sum to zero) bends under the pretension alone; that
moment is cancelled with the rest.
"""

from __future__ import annotations

import numpy as np

from twin.params import Params

__all__ = ["GRAVITY_TIP_FORCE_N", "holding_tensions_n", "pcc_realisable", "pcc_tensions_n"]


def GRAVITY_TIP_FORCE_N(mass_kg: float, gravity_m_s2: float) -> np.ndarray:
    """World-frame tip force (N) of a mass hung at the tip: m g along −z."""
    return np.array([0.0, 0.0, -mass_kg * gravity_m_s2])


def _bracketing_weights(phi_deg: float, angles_deg) -> np.ndarray | None:
    """Per tendon, the share of the bending moment towards φ (None if no pair < 180° apart brackets φ)."""
    alpha = np.mod(np.asarray(angles_deg, dtype=float), 360.0)
    phi = float(np.mod(phi_deg, 360.0))
    weights = np.zeros(alpha.size)
    order = np.argsort(alpha, kind="stable")
    for k in range(alpha.size):
        i, j = order[k], order[(k + 1) % alpha.size]
        a, gap = alpha[i], np.mod(alpha[j] - alpha[i], 360.0) or 360.0
        offset = np.mod(phi - a, 360.0)
        if offset == 0.0:
            weights[i] = 1.0
            return weights
        if offset < gap:
            if gap >= 180.0:
                return None
            g, x = np.radians(gap), np.radians(offset)
            weights[i], weights[j] = np.sin(g - x) / np.sin(g), np.sin(x) / np.sin(g)
            return weights
    return None


def pcc_realisable(phi_deg: float, params: Params) -> bool:
    """Whether the tendon layout can bend the unloaded model in plane φ (see the module; for an
    uneven layout, whether it can at small curvatures)."""
    return _bracketing_weights(phi_deg, params.tendons.angles_deg) is not None


def pcc_tensions_n(kappa_per_m: float, phi_deg: float, params: Params, pretension_n: float | None = None) -> np.ndarray:
    """Tendon tensions (N) that bend the unloaded model to (κ, φ) on top of the pretension.

    Raises:
        ValueError: no two tendons less than 180° apart bracket φ, so no pull bends towards it.
    """
    pre = params.tendons.pretension_n if pretension_n is None else pretension_n
    bend = params.backbone.bending_stiffness_nm2 * kappa_per_m / params.tendons.radius_m
    target = bend * np.array([np.cos(np.radians(phi_deg)), np.sin(np.radians(phi_deg))])
    return _pulls(target, phi_deg, params, pre)


def _pulls(target: np.ndarray, phi_deg: float, params: Params, pre: float) -> np.ndarray:
    """Tensions (N) whose pull, on top of ``pre`` each, is ``target`` (N, towards the body x and
    y axes, the bending moment over the tendon radius); ``phi_deg`` is the plane it bends in."""
    alpha = np.radians(np.asarray(params.tendons.angles_deg, dtype=float))
    # An uneven layout bends the rod under the pretension alone: that moment is taken out too.
    residual = pre * np.array([np.cos(alpha).sum(), np.sin(alpha).sum()])
    if np.linalg.norm(residual) < 1e-9 * max(pre, 1.0):
        residual = np.zeros(2)
    target = target - residual
    size = float(np.linalg.norm(target))
    if size == 0.0:
        return np.full(alpha.size, float(pre))
    direction = phi_deg if not residual.any() else float(np.degrees(np.arctan2(target[1], target[0])))
    weights = _bracketing_weights(direction, params.tendons.angles_deg)
    if weights is None:
        raise ValueError(f"phi = {phi_deg!r} deg: tendons.angles_deg = {list(params.tendons.angles_deg)} cannot bend "
                         "towards it (no two neighbours less than 180 deg apart bracket it)")
    return pre + size * weights


def holding_tensions_n(kappa_per_m: float, phi_deg: float, tip_mass_kg: float, params: Params,
                       base_rotation=None, pretension_n: float | None = None) -> np.ndarray:
    """Tendon tensions (N) that hold the arc (κ, φ) with ``tip_mass_kg`` at the tip, in the clamp
    pose ``base_rotation`` (default ``rig.base_rotation``): an estimate at the base, where the
    load's moment is largest. The backbone must bend by EI κ towards φ; the weight of the arc
    (backbone, discs, tip mass, as the arc places them) bends it by its moment about the base,
    and the tendons pull for the difference, split as :func:`pcc_tensions_n` splits it.

    Raises:
        ValueError: the tendons cannot pull towards the plane that difference lies in.
    """
    from twin.pcc import arc_tip_position_m

    b, d = params.backbone, params.discs
    rotation = params.rig.base_rotation if base_rotation is None else np.asarray(base_rotation, dtype=float)
    pre = params.tendons.pretension_n if pretension_n is None else pretension_n
    gravity = rotation.T @ np.array([0.0, 0.0, -params.environment.gravity_m_s2])
    pieces = 4 * d.count
    at_m = [(k + 0.5) * b.length_m / pieces for k in range(pieces)]
    masses = [b.mass_kg / pieces] * pieces
    at_m += [b.length_m * (k + 1) / d.count for k in range(d.count)] + [b.length_m]
    masses += [d.lumped_mass_kg] * d.count + [tip_mass_kg]
    moment = np.zeros(3)
    for s, m in zip(at_m, masses):
        moment += np.cross(arc_tip_position_m(kappa_per_m, phi_deg, s), m * gravity)
    # A moment about body x and y bends the backbone towards (M_y, −M_x).
    weight_bend = np.array([moment[1], -moment[0]])
    elastic = b.bending_stiffness_nm2 * kappa_per_m * np.array([np.cos(np.radians(phi_deg)), np.sin(np.radians(phi_deg))])
    target = (elastic - weight_bend) / params.tendons.radius_m
    plane = float(np.degrees(np.arctan2(target[1], target[0]))) if np.linalg.norm(target) > 0 else phi_deg
    return _pulls(target, plane, params, pre)
