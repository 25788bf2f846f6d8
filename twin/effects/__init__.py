"""The effects real rigs have, one module each: the vocabulary shared by the parameter set, the
twin (which makes them happen, :mod:`twin.sim`), the predictions from measured data
(:mod:`twin.data.prediction`, :class:`twin.rod.RodModel`) and the discrepancy workflow (which has
to find them, :mod:`twin.discrepancy`).

Each module of this package but :mod:`twin.effects.base` holds one effect (``EFFECT``, a
:class:`Effect`): the ``[effects]`` keys that carry it with their schema (all off in
``models/endoscope/endoscope.toml``), how the twin makes it happen, how it enters a prediction and what
the discrepancy workflow fits to find it. :data:`EFFECTS` registers every such module, in the
order of the module names, and :mod:`twin.params` builds its ``[effects]`` section from their
keys; a parameter file that does not mention a key has its effect off. So a new effect is a
new module here, nothing else.

The functions below compose the effects' hooks (:mod:`twin.effects.base`): the rest of the code
calls these, never an effect's keys.

Adding an effect that acts through the existing hooks touches:

* ``twin/effects/<name>.py``: an :class:`Effect` subclass and its ``EFFECT`` (keys with their
  schema, description, hooks, candidate; the docstring says what is fitted and why);
* ``models/endoscope/endoscope.toml``, where every key is documented: its keys under
  ``[effects]``, off, with their source (the other robots' files leave them out: off);
* ``models/endoscope/README.md``: regenerated (``python -m twin.sim.modelfiles``).
"""

from __future__ import annotations

import importlib
import pkgutil

import numpy as np

from twin.effects.base import (EFFECTS, PER_TENDON, BodySpec, Candidate, Effect, FitParameter, Key, Params,
                               PlantDynamics, StepHook)
from twin.effects.tendon_friction import SlidingState, friction_direction

__all__ = [
    "PER_TENDON",
    "BodySpec",
    "Candidate",
    "Effect",
    "EFFECTS",
    "FitParameter",
    "Key",
    "PlantDynamics",
    "SlidingState",
    "StepHook",
    "body_spec",
    "candidates",
    "clamp_rotation",
    "dynamic_candidates",
    "friction_direction",
    "loadcell_response",
    "parameter_keys",
    "plant_dynamics",
    "step_hooks",
    "tip_force_n",
    "tracked_point_m",
    "tracker_offset_m",
    "true_tensions_n",
    "true_tip_mass_kg",
]

for _module in sorted(m.name for m in pkgutil.iter_modules(__path__) if m.name != "base"):
    _effect = importlib.import_module(f"{__name__}.{_module}").EFFECT
    EFFECTS[_effect.name] = _effect


def parameter_keys() -> tuple[Key, ...]:
    """The ``[effects]`` keys of the registered effects, in registry order.

    Raises:
        ValueError: two effects declare the same key.
    """
    owner: dict[str, str] = {}
    keys = []
    for effect in EFFECTS.values():
        for key in effect.parameters:
            if key.name in owner:
                raise ValueError(f"effects.{key.name} is declared by both {owner[key.name]!r} and {effect.name!r}")
            owner[key.name] = effect.name
            keys.append(key)
    return tuple(keys)


def clamp_rotation(params: Params, base_rotation) -> np.ndarray:
    """The clamp's actual orientation (3×3, body → world), from the nominal ``base_rotation``."""
    rotation = np.asarray(base_rotation, dtype=float)
    for effect in EFFECTS.values():
        rotation = effect.clamp_rotation(params, rotation)
    return rotation


def loadcell_response(params: Params) -> tuple[np.ndarray, np.ndarray]:
    """(gain (n,), offset (n,) N) of the load cells: cell i reports gain_i · T_i + offset_i for a
    true tension T_i (before noise and the counts' calibration, :class:`twin.sim.sensors.LoadCells`)."""
    n = params.tendons.count
    gain, offset_n = np.ones(n), np.zeros(n)
    for effect in EFFECTS.values():
        gain, offset_n = effect.loadcell_response(params, gain, offset_n)
    return gain, offset_n


def true_tensions_n(params: Params, reported_n) -> np.ndarray:
    """Tendon tensions (N) behind load-cell reports (N; (n,) or (rows, n)): the inverse of
    :func:`loadcell_response`."""
    gain, offset_n = loadcell_response(params)
    return (np.asarray(reported_n, dtype=float) - offset_n) / gain


def tracker_offset_m(params: Params) -> np.ndarray:
    """The probe cap's origin relative to the tip, in the tip frame (3,) m."""
    offset_m = np.zeros(3)
    for effect in EFFECTS.values():
        offset_m = effect.tracker_offset_m(params, offset_m)
    return offset_m


def tracked_point_m(params: Params, tip_position_m, tip_rotation) -> np.ndarray:
    """Where the tracker's origin is, given the tip pose: tip + R_tip · :func:`tracker_offset_m`."""
    return np.asarray(tip_position_m) + np.asarray(tip_rotation) @ tracker_offset_m(params)


def true_tip_mass_kg(params: Params, nominal_kg: float) -> float:
    """What a tip mass of ``nominal_kg`` hung on the rig weighs (kg)."""
    mass_kg = nominal_kg
    for effect in EFFECTS.values():
        mass_kg = effect.true_tip_mass_kg(params, mass_kg)
    return mass_kg


def tip_force_n(params: Params, tip_mass_kg: float) -> np.ndarray:
    """World-frame force (N) of a nominal tip mass (kg): its :func:`true_tip_mass_kg` under gravity."""
    return np.array([0.0, 0.0, -true_tip_mass_kg(params, tip_mass_kg) * params.environment.gravity_m_s2])


def body_spec(params: Params) -> BodySpec:
    """The endoscope's body with every effect (:meth:`BodySpec.nominal` is the one without)."""
    spec = BodySpec.nominal(params)
    for effect in EFFECTS.values():
        spec = effect.body_spec(params, spec)
    return spec


def step_hooks(params: Params, model) -> list[StepHook]:
    """What the twin's plant calls before every physics step of its compiled ``model``
    (``mujoco.MjModel`` built by :mod:`twin.sim.model`), one per effect that acts per step."""
    hooks = (effect.step_hook(params, model) for effect in EFFECTS.values())
    return [hook for hook in hooks if hook is not None]


def candidates(params: Params) -> dict[str, Candidate]:
    """What the discrepancy workflow fits, by effect name, for an endoscope (its tendon count and
    layout); effects it cannot test (:attr:`Effect.untestable`) have none."""
    found = ((effect.name, effect.candidate(params)) for effect in EFFECTS.values())
    return {name: candidate for name, candidate in found if candidate is not None}


def plant_dynamics(params: Params) -> PlantDynamics:
    """The plant loop's dynamic imperfections with every effect (``PlantDynamics()`` without)."""
    dynamics = PlantDynamics()
    for effect in EFFECTS.values():
        dynamics = effect.plant_dynamics(params, dynamics)
    return dynamics


def dynamic_candidates(params: Params) -> dict[str, FitParameter]:
    """What the dynamic calibration (:mod:`twin.dynamics`) fits, by effect name: one scalar per
    effect that shows in time series."""
    found = ((effect.name, effect.dynamic_candidate(params)) for effect in EFFECTS.values())
    return {name: parameter for name, parameter in found if parameter is not None}
