"""The candidate library: each effect of :data:`twin.effects.EFFECTS` as a model extension with few
parameters, fitted with :func:`twin.data.fitting.fit_parameters`.

What each effect fits, and why no more than that, is in its module's docstring
(:mod:`twin.effects.tension_offset`, ...); an effect the workflow cannot test says why in
:attr:`twin.effects.Effect.untestable` (tendon compliance: a prediction from the measured
tensions does not use the tendon lengths beyond the sliding direction).
"""

from __future__ import annotations

from twin import effects
from twin.effects import EFFECTS, Candidate
from twin.params import Params

__all__ = ["Candidate", "candidate_library", "UNTESTABLE_EFFECTS"]

# Effect name → why the workflow cannot test it.
UNTESTABLE_EFFECTS = {e.name: e.untestable for e in EFFECTS.values() if e.untestable}


def candidate_library(params: Params) -> dict[str, Candidate]:
    """The candidates for an endoscope (its tendon count and layout), by effect name."""
    return effects.candidates(params)
