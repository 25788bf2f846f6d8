"""What an effect is: the parameter keys that carry it and the hooks through which it acts.

An effect (:class:`Effect`) is one module of :mod:`twin.effects`. It declares the ``[effects]``
keys it owns (:class:`Key`: shape, the value that leaves it off, what values are allowed) and
overrides only the hooks it acts through; every other hook leaves its input as it is:

=====================  ==========================================  =================================
hook                   what it changes                             who calls it (composed in
                                                                   :mod:`twin.effects`)
=====================  ==========================================  =================================
``clamp_rotation``     the clamp's orientation (3×3, body → world)  twin model, prediction
``loadcell_response``  each load cell's gain and offset (N)         twin sensors, prediction
``tracker_offset_m``   the probe cap's origin in the tip frame (m)  twin sensors, prediction
``true_tip_mass_kg``   what a hung tip mass weighs (kg)             twin plant, prediction
``body_spec``          masses, tendon compliance and friction       twin model, predictor model
                       (:class:`BodySpec`)
``step_hook``          forces applied before every physics step     twin plant
                       (:class:`StepHook`)
``plant_dynamics``     the plant loop's dynamic imperfections       twin plant
                       (:class:`PlantDynamics`)
``candidate``          what the discrepancy workflow fits           :mod:`twin.discrepancy`
                       (:class:`Candidate`)
``dynamic_candidate``  what the dynamic calibration fits            :mod:`twin.dynamics`
                       (:class:`FitParameter`)
=====================  ==========================================  =================================

This package sits below the parameter set (:mod:`twin.params` builds its ``[effects]`` section
from the keys declared here) and below everything that uses the effects, so it imports neither:
hooks take the parameter set as an argument, and the twin's compiled model by its element names.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, Protocol

import numpy as np

__all__ = ["DYNAMIC_ONLY", "PER_TENDON", "DynamicEffect", "Key", "BodySpec", "PlantDynamics", "StepHook",
           "FitParameter", "Candidate", "Effect", "EFFECTS"]

# The parameter set, twin.params.Params (not imported: twin.params imports this package).
Params = Any

# Key.size of a list with one entry per tendon (its length is checked against tendons.angles_deg).
PER_TENDON = "per tendon"

# Effect.untestable of an effect that shows only while the rig moves (its dynamic_candidate).
DYNAMIC_ONLY = "acts only while the rig moves: twin dynamics calibrate tests it on time series"


@dataclasses.dataclass(frozen=True)
class Key:
    """One ``[effects]`` parameter an effect owns, and the values it takes.

    Attributes:
        name: the key within ``[effects]``, its unit in the name.
        off: the value that leaves the effect off, the default in ``models/endoscope/endoscope.toml``
            (for a list: every entry).
        size: None for a number; an int for a list of that many numbers; :data:`PER_TENDON`
            for a list with one number per tendon.
        nonnegative: refuse values below zero.
        choices: the only values allowed; empty for any finite number.
    """

    name: str
    off: float = 0.0
    size: int | str | None = None
    nonnegative: bool = False
    choices: tuple[float, ...] = ()

    @property
    def key(self) -> str:
        """``"effects.<name>"``, as in :meth:`twin.params.Params.get`."""
        return f"effects.{self.name}"


@dataclasses.dataclass(frozen=True)
class BodySpec:
    """What the twin (:mod:`twin.sim.model`) and the predictor (:class:`twin.rod.RodModel`) build
    the endoscope's body from, besides its geometry and moduli.

    Attributes:
        line_mass_kg_per_m: weight spread uniformly along the backbone.
        disc_mass_kg: point mass at each disc.
        tendon_compliance_m_per_n: each tendon's stretch per newton over its length (0: as stiff
            as the twin makes an inextensible line).
        friction_coeff: capstan coefficient μ per radian of tendon wrap at the disc holes
            (0: frictionless). The predictor uses it; the twin applies friction as a
            :class:`StepHook` instead.
    """

    line_mass_kg_per_m: float
    disc_mass_kg: float
    tendon_compliance_m_per_n: float = 0.0
    friction_coeff: float = 0.0

    @classmethod
    def nominal(cls, params: Params) -> "BodySpec":
        """The body without any effect: ``backbone.mass_kg`` uniform, ``discs.lumped_mass_kg``
        at each disc, inextensible frictionless tendons."""
        b = params.backbone
        return cls(line_mass_kg_per_m=b.mass_kg / b.length_m, disc_mass_kg=params.discs.lumped_mass_kg)


@dataclasses.dataclass(frozen=True)
class PlantDynamics:
    """The rig's dynamic imperfections the twin's plant loop (``twin/sim/native/loop.cpp``) and
    plant (:mod:`twin.sim.plant`) make happen; the defaults leave the twin as without them.

    Attributes:
        actuation_latency_s: delay from the firmware's motor outputs to the motors (s).
        loadcell_lag_s: time constant of a first-order low-pass before each load cell (s).
        spool_backlash_m: play between each spool and its motor encoder, as tendon travel (m).
        motor_friction_n: Coulomb friction of each motor and gearbox, as force at the tendon (N).
        damping_scale: factor on the backbone joints' damping (1: ``sim.damping_time_s`` as it is).
    """

    actuation_latency_s: float = 0.0
    loadcell_lag_s: float = 0.0
    spool_backlash_m: float = 0.0
    motor_friction_n: float = 0.0
    damping_scale: float = 1.0


class StepHook(Protocol):
    """What an effect that acts every physics step hands the twin's plant.

    Attributes:
        max_step_s: the longest physics step (s) the hook is stable at; ``math.inf`` when any.
    """

    max_step_s: float

    def reset(self) -> None:
        """Forget the state of the last run (the plant is back at t = 0)."""

    def before_step(self, model, data, spool_tensions_n: np.ndarray) -> None:
        """Act on ``data`` (a ``mujoco.MjData`` of ``model``) before the next physics step,
        given each spool's tension (N)."""


@dataclasses.dataclass(frozen=True)
class FitParameter:
    """One fitted scalar: ``key`` (``section.name``) and, for list-valued keys, its ``index``.

    Attributes:
        log: fit log(value) (for positive quantities spanning decades).
        scale: typical size, for conditioning and the finite-difference step.
        bounds: (low, high) the physically possible values, in the parameter's unit; a fit that
            ends on one is not determined by the data.
        follows: (key, slope) of other scalar keys that move with this one: ``key`` changes by
            slope times the change of the value (a modulus carries the axial stiffness with it).
    """

    key: str
    index: int | None = None
    log: bool = False
    scale: float = 1.0
    bounds: tuple[float, float] = (-math.inf, math.inf)
    follows: tuple[tuple[str, float], ...] = ()

    @property
    def label(self) -> str:
        return self.key if self.index is None else f"{self.key}[{self.index}]"


@dataclasses.dataclass(frozen=True)
class Candidate:
    """One candidate effect: its name in :data:`EFFECTS` and what is fitted
    (:func:`twin.data.fitting.fit_parameters`) to find it in a dataset.

    Attributes:
        effect: the effect's name.
        parameters: the fitted scalars.
        start: ``label → value`` where the current value cannot start a fit (log of zero).
        applies: whether a dataset (:class:`twin.data.dataset.Dataset`) can show the effect at
            all (e.g. tip loads hung).
        variants: discrete settings (``key → value``) to try, each fitted; the best training fit
            is kept and the choice counts as one more parameter (friction's sliding direction).
    """

    effect: str
    parameters: tuple[FitParameter, ...]
    start: dict[str, float] = dataclasses.field(default_factory=dict)
    applies: Callable[[Any], bool] = lambda dataset: True
    variants: tuple[dict, ...] = ()

    def __post_init__(self):
        keys = set(EFFECTS[self.effect].keys)
        stray = [p.key for p in self.parameters if p.key not in keys]
        if stray:
            raise ValueError(f"candidate {self.effect!r} fits {stray}, outside its effect's keys {sorted(keys)}")

    def x0(self, params: Params) -> list[float]:
        """Starting values: the parameter set's, unless :attr:`start` overrides one."""
        out = []
        for p in self.parameters:
            value = params.get(p.key)
            value = float(value if p.index is None else value[p.index])
            if p.log and value <= 0 and p.label in self.start:
                value = self.start[p.label]
            out.append(value)
        return out


class Effect:
    """A physical effect of real rigs: its keys and its hooks (see the module table).

    A subclass sets the class attributes and overrides the hooks its effect acts through; its
    module makes one instance, ``EFFECT``, which :mod:`twin.effects` registers.

    Attributes:
        name: the effect's name, e.g. ``"tension_gain"``.
        description: one line: what the effect is.
        parameters: the ``[effects]`` keys the effect owns.
        uses: keys of other sections that carry it too (``backbone.mass_kg`` for the weight).
        untestable: why the discrepancy workflow cannot test the effect; empty when it can.
        deciding_experiments: the experiments that tell this effect apart from the others when
            static data leave them tied (names in :data:`twin.discrepancy.decide.DESIGNS`).
    """

    name: str = ""
    description: str = ""
    parameters: tuple[Key, ...] = ()
    uses: tuple[str, ...] = ()
    untestable: str = ""
    deciding_experiments: tuple[str, ...] = ()

    @property
    def keys(self) -> tuple[str, ...]:
        """Every parameter key that carries the effect (``section.name``)."""
        return self.uses + tuple(k.key for k in self.parameters)

    def clamp_rotation(self, params: Params, rotation: np.ndarray) -> np.ndarray:
        """The clamp's orientation (3×3, body → world) with this effect, from ``rotation``."""
        return rotation

    def loadcell_response(self, params: Params, gain: np.ndarray,
                          offset_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each load cell's (gain (n,), offset (n,) N) with this effect: it reports gain · T + offset."""
        return gain, offset_n

    def tracker_offset_m(self, params: Params, offset_m: np.ndarray) -> np.ndarray:
        """The probe cap's origin relative to the tip, in the tip frame (3,) m, with this effect."""
        return offset_m

    def true_tip_mass_kg(self, params: Params, mass_kg: float) -> float:
        """What a hung tip mass weighs (kg) with this effect."""
        return mass_kg

    def body_spec(self, params: Params, spec: BodySpec) -> BodySpec:
        """The endoscope's body with this effect."""
        return spec

    def step_hook(self, params: Params, model) -> StepHook | None:
        """What the twin's plant calls before each physics step of the compiled ``model``
        (``mujoco.MjModel``, elements named as :mod:`twin.sim.model` names them); None when the
        effect does not act per step or is off."""
        return None

    def plant_dynamics(self, params: Params, dynamics: PlantDynamics) -> PlantDynamics:
        """The plant loop's dynamic imperfections with this effect."""
        return dynamics

    def candidate(self, params: Params) -> Candidate | None:
        """What the discrepancy workflow fits to find the effect; None when it cannot test it."""
        return None

    def dynamic_candidate(self, params: Params) -> FitParameter | None:
        """The one scalar the dynamic calibration (:mod:`twin.dynamics`) fits through twin replays
        to find the effect in time series; None for an effect that only changes statics."""
        return None


class DynamicEffect(Effect):
    """An effect of one scalar key that the plant loop makes happen (a :class:`PlantDynamics`
    field) and only time series show: the dynamic calibration fits the key on log scale.

    Attributes:
        field: the :class:`PlantDynamics` field the key sets.
        fit_scale: typical size of the key, in its unit.
        fit_bounds: (low, high) the values the dynamic calibration searches, in its unit (> 0).
    """

    untestable = DYNAMIC_ONLY
    field: str = ""
    fit_scale: float = 1.0
    fit_bounds: tuple[float, float] = (1e-3, 1.0)

    def plant_dynamics(self, params: Params, dynamics: PlantDynamics) -> PlantDynamics:
        return dataclasses.replace(dynamics, **{self.field: params.get(self.parameters[0].key)})

    def dynamic_candidate(self, params: Params) -> FitParameter:
        return FitParameter(self.parameters[0].key, log=True, scale=self.fit_scale, bounds=self.fit_bounds)


# Effects by name, in the order they are tried and written (filled by twin.effects).
EFFECTS: dict[str, Effect] = {}
