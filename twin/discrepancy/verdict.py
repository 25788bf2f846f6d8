"""The discrepancy workflow's answer, static (:mod:`twin.discrepancy.workflow`) and dynamic
(:mod:`twin.dynamics.calibrate`) alike; a module of its own so that the commands' parsers and
their exit codes need none of the workflow's numerics."""

from __future__ import annotations

import enum

__all__ = ["Verdict"]


class Verdict(enum.StrEnum):
    """What the workflow concluded; the value is what the JSON, the report and the statement spell.

    ``none``: no structured disagreement beyond noise, or none that matters, and nothing named;
    the error is at the noise (and model-form) level.
    ``effect``: the named effects leave residuals consistent with noise, at the noise (and
    model-form) level.
    ``ambiguous``: two or more candidates explain the data equally well; none is named for it.
    ``unexplained``: structure beyond noise remains that no candidate (nor a pair) removes, or
    an error beyond the noise level that is no function of the configuration.
    """

    NONE = "none"
    EFFECT = "effect"
    AMBIGUOUS = "ambiguous"
    UNEXPLAINED = "unexplained"
