"""Load cases of the thesis validation grid for the predictor (thesis §8.3).

Until measured tensions exist, each PCC configuration is realised by the tensions that bend
the unloaded, weightless model to curvature κ in plane φ on top of the pretension:
τ_i = τ_pre + (EI κ / r) · max(0, cos(φ − α_i)) — one tendon (or two neighbours) carry the
bending moment EI κ, the antagonists keep the pretension.
"""

from __future__ import annotations

import numpy as np

from twin.params import Params

__all__ = ["pcc_tensions_n", "GRAVITY_TIP_FORCE_N"]


def GRAVITY_TIP_FORCE_N(mass_kg: float, gravity_m_s2: float) -> np.ndarray:
    """World-frame tip force (N) of a mass hung at the tip: m g along −z."""
    return np.array([0.0, 0.0, -mass_kg * gravity_m_s2])


def pcc_tensions_n(kappa_per_m: float, phi_deg: float, params: Params, pretension_n: float | None = None) -> np.ndarray:
    """Tendon tensions (N) that bend the unloaded model to (κ, φ) on top of the pretension."""
    pre = params.tendons.pretension_n if pretension_n is None else pretension_n
    alpha = np.radians(np.asarray(params.tendons.angles_deg))
    bend = params.backbone.bending_stiffness_nm2 * kappa_per_m / params.tendons.radius_m
    return pre + bend * np.maximum(0.0, np.cos(np.radians(phi_deg) - alpha))
