"""The candidate library: each effect of :data:`twin.effects.EFFECTS` as a model extension with few
parameters, fitted with :func:`twin.data.fitting.fit_parameters`.

What is fitted, and why no more than that:

==================  =========================================================================
tendon_friction     μ (log; starts at 0.02 when off): one coefficient for all holes, fitted for
                    both sliding directions at rest (pulled / backed off), the better kept.
tension_gain        g_1 … g_4: one relative gain error per load cell.
tension_offset      o_1, o_2 with o_3 = o_4 held: an offset common to an antagonist pair adds
                    equal tension on opposite sides of the backbone and bends nothing, so only
                    o_i − o_(i+2) can be seen; the fitted o_1, o_2 are those differences.
weight              the endoscope's mass (log). Its split between backbone and discs
                    (``effects.disc_mass_fraction``) moves the centre of mass by a twentieth of
                    the length and is indistinguishable from the mass on a tip-position sweep.
tip_load            the relative error of the hung tip loads (needs rows with a tip mass).
stiffness           E and G (log).
base_tilt           the clamp's tilt about world x and y (deg).
tracker_offset      the tracker origin's offset from the tip, tip frame (3, m).
==================  =========================================================================

``tendon_compliance`` is in the vocabulary but not a candidate here: a prediction from the
measured tensions does not use the tendon lengths (beyond the sliding direction), so a tendon's
stretch cannot change it.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from twin.effects import EFFECTS
from twin.data.dataset import Dataset
from twin.data.fitting import FitParameter
from twin.params import Params

__all__ = ["Candidate", "candidate_library", "UNTESTABLE_EFFECTS"]

# Starting value of a log-fitted parameter that is off (0) in the parameter set.
_FRICTION_START = 0.02
UNTESTABLE_EFFECTS = {"tendon_compliance": "tension-driven predictions do not depend on tendon stretch"}


@dataclasses.dataclass(frozen=True)
class Candidate:
    """One candidate effect: its name in :data:`twin.effects.EFFECTS` and what is fitted.

    Attributes:
        effect: the effect's name.
        parameters: the fitted scalars.
        start: ``label → value`` where the current value cannot start a fit (log of zero).
        applies: whether the dataset can show the effect at all (e.g. tip loads hung).
        variants: discrete settings (``key → value``) to try, each fitted; the best training fit
            is kept and the choice counts as one more parameter (friction's sliding direction).
    """

    effect: str
    parameters: tuple[FitParameter, ...]
    start: dict[str, float] = dataclasses.field(default_factory=dict)
    applies: Callable[[Dataset], bool] = lambda dataset: True
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


def _antagonist_representatives(angles_deg) -> list[int]:
    """Indices with one per antagonist pair (tendons 180° apart), and every unpaired tendon."""
    angles = np.mod(np.asarray(angles_deg, dtype=float), 360.0)
    chosen, paired = [], set()
    for i, a in enumerate(angles):
        if i in paired:
            continue
        chosen.append(i)
        for j in range(i + 1, len(angles)):
            if j not in paired and abs(np.mod(angles[j] - a, 360.0) - 180.0) < 1e-6:
                paired.add(j)
                break
    return chosen


def candidate_library(params: Params) -> dict[str, Candidate]:
    """The candidates for an endoscope (its tendon count and layout), by effect name."""
    n = params.tendons.count
    friction = FitParameter("effects.tendon_friction_coeff", log=True)
    return {c.effect: c for c in (
        Candidate("tendon_friction", (friction,), start={friction.label: _FRICTION_START},
                  variants=({"effects.tendon_friction_direction": 1.0}, {"effects.tendon_friction_direction": -1.0})),
        Candidate("tension_gain", tuple(FitParameter("effects.tension_gain_error", i, scale=0.05) for i in range(n))),
        Candidate("tension_offset", tuple(FitParameter("effects.tension_offset_error_n", i, scale=0.05)
                                          for i in _antagonist_representatives(params.tendons.angles_deg))),
        Candidate("weight", (FitParameter("backbone.mass_kg", log=True),)),
        Candidate("tip_load", (FitParameter("effects.tip_load_error_fraction", scale=0.1),),
                  applies=lambda dataset: bool(np.any(dataset["tip_mass_kg"] > 0))),
        Candidate("stiffness", (FitParameter("backbone.youngs_modulus_pa", log=True),
                                FitParameter("backbone.shear_modulus_pa", log=True))),
        Candidate("base_tilt", tuple(FitParameter("effects.base_tilt_deg", i, scale=1.0) for i in range(2))),
        Candidate("tracker_offset", tuple(FitParameter("effects.tracker_offset_m", i, scale=1e-3) for i in range(3))),
    )}
