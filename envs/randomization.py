"""Domain randomisation of the endoscope env: parameters, effects, latency and tip loads, seeded.

Each episode draws a variation of the parameter set (the twin is rebuilt from it on ``sim://``;
on the rig it cannot change the hardware, so only the host-side latency and the tip-load schedule
apply) from the env's own generator, so ``reset(seed=...)`` repeats an episode exactly.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from twin.params import Params

__all__ = ["Randomization", "TipLoads"]


@dataclasses.dataclass(frozen=True)
class Randomization:
    """Ranges drawn uniformly per episode; ``(1.0, 1.0)`` / ``(0.0, 0.0)`` switch an item off.

    Attributes:
        stiffness_scale: factor on Young's and shear moduli.
        weight_scale: factor on the endoscope's mass.
        friction_coeff: capstan friction coefficient μ per radian (``effects.tendon_friction_coeff``);
            costs speed on the twin (the plant then steps in Python), so off by default.
        tension_gain_error: each load cell's relative gain error, drawn per channel in ±this.
        tension_offset_error_n: each load cell's offset error (N), per channel in ±this.
        tracker_noise_scale: factor on the tracker's position and angle noise.
        latency_steps: (min, max) whole env steps an action waits before it reaches the board.
    """

    stiffness_scale: tuple[float, float] = (1.0, 1.0)
    weight_scale: tuple[float, float] = (1.0, 1.0)
    friction_coeff: tuple[float, float] = (0.0, 0.0)
    tension_gain_error: float = 0.0
    tension_offset_error_n: float = 0.0
    tracker_noise_scale: tuple[float, float] = (1.0, 1.0)
    latency_steps: tuple[int, int] = (0, 0)

    def __post_init__(self):
        for field in ("stiffness_scale", "weight_scale", "friction_coeff", "tracker_noise_scale", "latency_steps"):
            low, high = getattr(self, field)
            if not 0 <= low <= high:
                raise ValueError(f"Randomization.{field} = {(low, high)!r}: need 0 <= low <= high")
        for field in ("tension_gain_error", "tension_offset_error_n"):
            if not getattr(self, field) >= 0:
                raise ValueError(f"Randomization.{field} = {getattr(self, field)!r}: must be >= 0")

    @classmethod
    def typical(cls) -> "Randomization":
        """Spreads of a rig against its nominal model: ±20 % stiffness, ±15 % weight, 3 % load-cell
        gain and 0.05 N offset errors, tracker noise ×0.5–2, 0–2 steps (0–50 ms) of latency;
        friction stays off for speed."""
        return cls(stiffness_scale=(0.8, 1.2), weight_scale=(0.85, 1.15), tension_gain_error=0.03,
                   tension_offset_error_n=0.05, tracker_noise_scale=(0.5, 2.0), latency_steps=(0, 2))

    @property
    def changes_params(self) -> bool:
        """True when episodes need a rebuilt twin (anything but latency is randomised)."""
        return dataclasses.replace(self, latency_steps=(0, 0)) != Randomization()

    def sample(self, params: Params, rng: np.random.Generator) -> tuple[Params, int]:
        """A randomised parameter set and the episode's latency (env steps)."""
        latency = int(rng.integers(self.latency_steps[0], self.latency_steps[1] + 1))
        if not self.changes_params:
            return params, latency
        b, s, n = params.backbone, params.sensors, params.tendons.count
        stiffness = rng.uniform(*self.stiffness_scale)
        noise = rng.uniform(*self.tracker_noise_scale)
        values: dict[str, Any] = {
            "backbone.youngs_modulus_pa": b.youngs_modulus_pa * stiffness,
            "backbone.shear_modulus_pa": b.shear_modulus_pa * stiffness,
            "backbone.mass_kg": b.mass_kg * rng.uniform(*self.weight_scale),
            "effects.tendon_friction_coeff": rng.uniform(*self.friction_coeff),
            "effects.tension_gain_error": rng.uniform(-1, 1, n) * self.tension_gain_error,
            "effects.tension_offset_error_n": rng.uniform(-1, 1, n) * self.tension_offset_error_n,
            "sensors.tracker_noise_m": s.tracker_noise_m * noise,
            "sensors.tracker_noise_rad": s.tracker_noise_rad * noise,
        }
        plain = {k: v.tolist() if isinstance(v, np.ndarray) else float(v) for k, v in values.items()}
        return params.replace(plain, source="randomised (twin.envs.randomization)"), latency


@dataclasses.dataclass(frozen=True)
class TipLoads:
    """Tip masses hung during an episode: one at reset, and possibly one change mid-episode.

    Attributes:
        masses_kg: the masses to choose from (kg), uniformly.
        change_probability: chance that the mass changes once during the episode.
        change_window_steps: (first, last) env step at which the change can happen.
    """

    masses_kg: tuple[float, ...] = (0.0, 0.005, 0.010)
    change_probability: float = 0.5
    change_window_steps: tuple[int, int] = (40, 160)

    def __post_init__(self):
        if not self.masses_kg or min(self.masses_kg) < 0:
            raise ValueError(f"TipLoads.masses_kg = {self.masses_kg!r}: need one or more masses >= 0")
        if not 0 <= self.change_probability <= 1:
            raise ValueError(f"TipLoads.change_probability = {self.change_probability!r}: must be in [0, 1]")
        first, last = self.change_window_steps
        if not 0 < first <= last:
            raise ValueError(f"TipLoads.change_window_steps = {self.change_window_steps!r}: need 0 < first <= last")

    @classmethod
    def none(cls) -> "TipLoads":
        """No tip load, ever."""
        return cls(masses_kg=(0.0,), change_probability=0.0)

    def sample(self, rng: np.random.Generator) -> tuple[float, int | None, float]:
        """(mass at reset kg, step of the change or None, mass after it kg)."""
        start = float(rng.choice(self.masses_kg))
        if rng.uniform() >= self.change_probability:
            return start, None, start
        step = int(rng.integers(self.change_window_steps[0], self.change_window_steps[1] + 1))
        return start, step, float(rng.choice(self.masses_kg))
