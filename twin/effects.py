"""The effects vocabulary, shared by the twin (which makes them happen, :mod:`twin.sim`) and the
discrepancy workflow (which has to find them, :mod:`twin.discrepancy`).

Each effect names the parameter keys that carry it (all zero = off in ``models/endoscope.toml``)
and, here, how it enters a *prediction* from measured data: what the load cells report versus
what the tendons carry, where gravity points relative to the clamp, what the tracker sees. The
predictor (:mod:`twin.rod`) takes the rod-side effects (disc mass lumping, friction) from the
parameter set itself (:meth:`twin.rod.RodModel.from_params`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from twin.params import Params
from twin.pose import rot_x, rot_y

__all__ = [
    "Effect",
    "EFFECTS",
    "clamp_rotation",
    "true_tensions_n",
    "tip_force_n",
    "tracked_point_m",
    "friction_direction",
]


@dataclasses.dataclass(frozen=True)
class Effect:
    """A physical effect: its name, the parameter keys that carry it, and what it does."""

    name: str
    keys: tuple[str, ...]
    description: str


EFFECTS: dict[str, Effect] = {e.name: e for e in (
    Effect("tendon_friction", ("effects.tendon_friction_coeff", "effects.tendon_friction_direction"),
           "capstan friction at the disc holes: tension lost towards the tip while pulled, gained while released"),
    Effect("tendon_compliance", ("effects.tendon_compliance_m_per_n",),
           "tendon stretch per newton: encoder lengths differ from the path lengths"),
    Effect("tension_gain", ("effects.tension_gain_error",),
           "each load cell reads (1 + g_i) times the true tension"),
    Effect("tension_offset", ("effects.tension_offset_error_n",),
           "each load cell reads the true tension plus o_i newtons"),
    Effect("weight", ("backbone.mass_kg", "effects.disc_mass_fraction"),
           "the endoscope's weight, or how much of it sits at the discs, differs"),
    Effect("tip_load", ("effects.tip_load_error_fraction",),
           "the hung tip load weighs a fraction more than its nominal mass"),
    Effect("stiffness", ("backbone.youngs_modulus_pa", "backbone.shear_modulus_pa"),
           "Young's and shear moduli differ"),
    Effect("base_tilt", ("effects.base_tilt_deg",),
           "the clamp is tilted about world x, then y"),
    Effect("tracker_offset", ("effects.tracker_offset_m",),
           "the tracker's origin is offset from the tip, in the tip frame"),
)}


def clamp_rotation(params: Params, base_rotation) -> np.ndarray:
    """The clamp's actual orientation (3×3, body → world): the nominal one tilted by
    ``effects.base_tilt_deg`` about world x, then world y."""
    tilt_x, tilt_y = np.radians(params.effects.base_tilt_deg)
    return rot_y(tilt_y) @ rot_x(tilt_x) @ np.asarray(base_rotation, dtype=float)


def true_tensions_n(params: Params, reported_n) -> np.ndarray:
    """Tendon tensions (N) behind load-cell reports, undoing the gain and offset errors.

    The load cells report (1 + g) τ + o (:class:`twin.sim.sensors.LoadCells`).
    """
    e = params.effects
    return (np.asarray(reported_n, dtype=float) - np.asarray(e.tension_offset_error_n)) / (
        1.0 + np.asarray(e.tension_gain_error))


def tip_force_n(params: Params, tip_mass_kg: float) -> np.ndarray:
    """World-frame force (N) of a nominal tip mass, with ``effects.tip_load_error_fraction``."""
    weight = tip_mass_kg * (1.0 + params.effects.tip_load_error_fraction) * params.environment.gravity_m_s2
    return np.array([0.0, 0.0, -weight])


def tracked_point_m(params: Params, tip_position_m, tip_rotation) -> np.ndarray:
    """Where the tracker's origin is, given the tip pose: tip + R_tip · ``effects.tracker_offset_m``."""
    return np.asarray(tip_position_m) + np.asarray(tip_rotation) @ np.asarray(params.effects.tracker_offset_m)


def friction_direction(relative_lengths_m, sense: float = 1.0) -> np.ndarray:
    """Sliding direction per tendon for a static state reached from the pretensioned straight pose:
    +1 (tension lost towards the tip) for a tendon pulled in (shortened) to get there, −1 for one
    paid out — times ``sense`` (``effects.tendon_friction_direction``), −1 when a length controller
    settled by backing off past the presliding travel, which flips every tendon's last motion."""
    lengths = np.asarray(relative_lengths_m, dtype=float)
    return sense * np.where(lengths > 0, -1.0, 1.0)
