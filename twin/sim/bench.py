"""Speed of the twin: steps per second and real-time factor on one core (``twin bench sim``).

The benchmark runs the plant as the device layer does: four spools driven by the DC-motor
model from PWM, tendons, load cells at 80 Hz and the tracker at 40 Hz, at the default time
step, on a pretensioned endoscope bent by one motor. Settling a static configuration (ideal
tensions, from straight) is timed as well.
"""

from __future__ import annotations

import time

import numpy as np

from twin.params import Params, load_params
from twin.sim.plant import Plant

__all__ = ["bench_sim"]


def bench_sim(params: Params | None = None, *, duration_s: float = 2.0, elements: int | None = None) -> dict:
    """Time the default twin.

    Args:
        params: parameter set (default ``models/endoscope.toml``).
        duration_s: simulated time per timed run (s); the best of five runs is kept (shared
            machines vary by ±30% from one second to the next).
        elements: override of ``sim.elements``.

    Returns:
        ``steps_per_s``, ``realtime_factor`` (simulated s per wall s; the tendons of the braked
        spools sag to the slack edge and rest there), ``short_steps`` (physics steps of the timed
        runs taken as shorter ones, :data:`twin.sim.plant.ENGAGE_MAX_STEP_S`),
        ``taut_realtime_factor`` (the same after settling a bend held by tension sources, every
        tendon taut), ``timestep_s``,
        ``elements``, ``dofs``, ``settle_wall_s`` and ``settle_sim_s`` (a tension step from
        straight, to 1 µm), ``settled``.
    """
    params = params if params is not None else load_params()
    plant = Plant(params, elements=elements)
    plant.set_tensions(np.full(plant.tendon_count, params.tendons.pretension_n))
    plant.settle()
    duty = np.zeros(plant.tendon_count)
    duty[0] = -0.02
    plant.set_motor_pwm(duty)
    short = plant.short_steps
    best = _best_realtime_factor(plant, duration_s)
    short = plant.short_steps - short
    plant.reset()
    tensions = np.full(plant.tendon_count, params.tendons.pretension_n)
    tensions[0] += 1.0
    plant.set_tensions(tensions)
    settle = plant.settle()
    # The same bend held by tension sources: every tendon taut, so every step is a full one.
    taut = _best_realtime_factor(plant, duration_s)
    return {
        "steps_per_s": best / plant.timestep_s,
        "realtime_factor": best,
        "short_steps": short,
        "timestep_s": plant.timestep_s,
        "elements": plant.layout.elements,
        "dofs": int(plant.model.nv),
        "taut_realtime_factor": taut,
        "settle_wall_s": settle.wall_time_s,
        "settle_sim_s": settle.sim_time_s,
        "settled": settle.settled,
    }


def _best_realtime_factor(plant: Plant, duration_s: float, runs: int = 5) -> float:
    """Simulated s per wall s of ``plant.step(duration_s)``, the best of ``runs``."""
    best = 0.0
    for _ in range(runs):
        start = time.perf_counter()
        plant.step(duration_s)
        best = max(best, duration_s / (time.perf_counter() - start))
    return best
