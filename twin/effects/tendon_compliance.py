"""Tendon stretch: ``effects.tendon_compliance_m_per_n``, metres per newton over a tendon's
full length (0 = off: practically inextensible).

Twin: each tendon's dead-band spring (:mod:`twin.sim.model`) is that much softer than the
inextensible default; the encoders see the spool, not the stretch.

Prediction and discrepancy: none. A prediction from the measured tensions does not use the
tendon lengths (beyond the sliding direction), so a tendon's stretch cannot change it, and the
discrepancy workflow cannot test the effect (:attr:`TendonComplianceEffect.untestable`).
"""

from __future__ import annotations

import dataclasses

from twin.effects.base import BodySpec, Effect, Key, Params

__all__ = ["EFFECT"]


class TendonComplianceEffect(Effect):
    name = "tendon_compliance"
    description = "tendon stretch per newton: encoder lengths differ from the path lengths"
    deciding_experiments = ("pretension",)
    parameters = (Key("tendon_compliance_m_per_n", nonnegative=True),)
    untestable = "tension-driven predictions do not depend on tendon stretch"

    def body_spec(self, params: Params, spec: BodySpec) -> BodySpec:
        return dataclasses.replace(spec, tendon_compliance_m_per_n=params.effects.tendon_compliance_m_per_n)


EFFECT = TendonComplianceEffect()
