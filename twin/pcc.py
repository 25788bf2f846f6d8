"""Piecewise-constant-curvature kinematics (thesis §2.2.1, §8.3).

A single segment bent at curvature κ (1/m) in plane φ (angle from the body x axis towards y)
over length L. The bending plane φ points towards the tendons that shorten.
"""

from __future__ import annotations

import numpy as np

from twin.params import Params

__all__ = [
    "GRID_KAPPA_PER_M",
    "GRID_PHI_DEG",
    "GRID_TIP_MASS_KG",
    "arc_tip_position_m",
    "tendon_length_changes_m",
    "validation_grid",
]

# Thesis §8.3 validation grid: 6 curvatures × 12 planes × 3 tip masses = 216 configurations.
GRID_KAPPA_PER_M = (0.0, 4.5, 8.7, 13.0, 17.5, 26.2)
GRID_PHI_DEG = tuple(float(a) for a in range(0, 360, 30))
GRID_TIP_MASS_KG = (0.0, 0.005, 0.010)


def tendon_length_changes_m(kappa_per_m: float, phi_deg: float, params: Params) -> np.ndarray:
    """Relative tendon lengths Δℓ_i = −r κ s_i cos(φ − α_i) (m; positive = paid out) that bend
    the whole backbone to κ in plane φ, thesis §2.2.1: s_i is the arc length where tendon i is
    anchored, L for a tendon that ends at the tip (:meth:`twin.params.Params.tendon_ends_m`)."""
    alpha = np.radians(np.asarray(params.tendons.angles_deg))
    anchored_m = np.asarray(params.tendon_ends_m()) if params.tendons.end_discs else params.backbone.length_m
    return -params.tendons.radius_m * kappa_per_m * anchored_m * np.cos(np.radians(phi_deg) - alpha)


def arc_tip_position_m(kappa_per_m: float, phi_deg: float, length_m: float) -> np.ndarray:
    """Tip of a constant-curvature arc in the base frame (body z along the straight backbone)."""
    phi = np.radians(phi_deg)
    if abs(kappa_per_m) < 1e-12:
        return np.array([0.0, 0.0, length_m])
    theta = kappa_per_m * length_m
    radial = (1.0 - np.cos(theta)) / kappa_per_m
    return np.array([radial * np.cos(phi), radial * np.sin(phi), np.sin(theta) / kappa_per_m])


def validation_grid():
    """The 216 (config, κ 1/m, φ deg, tip mass kg) tuples of thesis §8.3, in the thesis's order."""
    rows = []
    config = 0
    for kappa in GRID_KAPPA_PER_M:
        for phi in GRID_PHI_DEG:
            for mass in GRID_TIP_MASS_KG:
                rows.append((config, kappa, phi, mass))
                config += 1
    return rows
