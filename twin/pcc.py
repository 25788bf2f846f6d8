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
    "THESIS_LENGTH_M",
    "quick_grid",
    "arc_tip_position_m",
    "tendon_length_changes_m",
    "validation_grid",
]

# Thesis §8.3 validation grid: 6 curvatures × 12 planes × 3 tip masses = 216 configurations.
GRID_KAPPA_PER_M = (0.0, 4.5, 8.7, 13.0, 17.5, 26.2)
GRID_PHI_DEG = tuple(float(a) for a in range(0, 360, 30))
GRID_TIP_MASS_KG = (0.0, 0.005, 0.010)
# The thesis's bending segment (thesis §7.1: 60 mm), which GRID_KAPPA_PER_M bends by 0 … 90°.
THESIS_LENGTH_M = 0.06


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


def validation_grid(params: Params | None = None):
    """The 216 (config, κ 1/m, φ deg, tip mass kg) tuples of thesis §8.3, in the thesis's order.

    For a robot (``params``) of another length the curvatures scale so that it bends by the
    thesis's angles, κ·L = 0 … 90° (GRID_KAPPA_PER_M · THESIS_LENGTH_M / L): the thesis's own
    κ on a 60 mm robot, κ up to 10.5 1/m on a 150 mm one. Configurations the robot's tension
    limit cannot hold are for the caller to leave out (:func:`twin.experiments.protocols.unrealisable`).
    """
    scale = 1.0 if params is None else THESIS_LENGTH_M / params.backbone.length_m
    kappas = GRID_KAPPA_PER_M if scale == 1.0 else tuple(round(k * scale, 6) for k in GRID_KAPPA_PER_M)
    rows = []
    config = 0
    for kappa in kappas:
        for phi in GRID_PHI_DEG:
            for mass in GRID_TIP_MASS_KG:
                rows.append((config, kappa, phi, mass))
                config += 1
    return rows


def quick_grid(grid):
    """The quick look at a grid: its smallest, middle and largest curvature, the planes 0, 90,
    180 and 270° (all its planes when it has none of them), its lightest and heaviest tip mass;
    24 configurations of the thesis grid (κ 0/13/26.2 1/m, 0 and 10 g)."""
    kappas = sorted({row[1] for row in grid})
    phis = {row[2] for row in grid}
    masses = {row[3] for row in grid}
    keep_k = {kappas[0], kappas[len(kappas) // 2], kappas[-1]}
    keep_phi = {p for p in phis if p in (0.0, 90.0, 180.0, 270.0)} or phis
    keep_m = {min(masses), max(masses)}
    return [row for row in grid if row[1] in keep_k and row[2] in keep_phi and row[3] in keep_m]
