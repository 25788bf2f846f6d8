"""Speed of the twin: steps per second and real-time factor on one core (``twin bench sim``).

Times are CPU time of this process (:class:`twin.stopwatch.Stopwatch`), the wall time beside
them under ``_wall`` names: a shared machine's wall clock would judge a healthy build slow.

The benchmark runs the plant as the device layer does: four spools driven by the DC-motor
model from PWM, tendons, load cells at 80 Hz and the tracker at 40 Hz, at the default time
step, on a pretensioned endoscope bent by one motor. Settling a static configuration (ideal
tensions, from straight) is timed as well, and the PWM run is repeated at twice and four times
the element count, each figure beside its element count.

The cost grows much faster than the element count (towards its cube), and no solver option
changes that, so the scaling is judged against that cost (``scaling_over_chain``, below): the backbone is one serial chain in joint coordinates, whose joint-space mass
matrix is dense (every dof is an ancestor of the dofs after it), and each MuJoCo step factors
a matrix of that pattern twice, in Σ depth² ≈ nv³/6 multiply-adds each: M itself
(``mj_factorM``, in the position stage) and the discrete integrator's backbone M + hD + h²K
with the joints' stiffness and damping on its diagonal. The tendons' rank-1 terms join by
preconditioned conjugate gradients, each iteration a solve with that factor (nv² multiply-adds).
``factor_s`` times one factorization: two of them at four times the elements already take longer
than four steps at the default count. Cutting the chain into shorter trees joined by weld
constraints does not help: the constraint solve then factors its Hessian, which the tendons'
terms make dense over all dofs, and a weld's stiffness scales with the masses it joins, so the
cut rod gives way at the cuts.
Nor do MuJoCo's 1D flex rods (discrete elastic rods, each vertex its own 3-dof tree): alone
they step in time linear in the elements, but with four stiff tendons along them the metric's
block preconditioner falls short and the step grows faster than the chain's (25× from 10 to 40
elements, against 19×); and their vertex frames do not turn with the rod, so the routing
through the discs would have to be rebuilt.

So the scaling goal is not a real-time factor kept at four times the elements (measured: 0.053 of
the default's, where a linear cost would keep 0.25), but that the step grow no faster than the
factorization the chain imposes: ``scaling_over_chain``, the growth of the time per step from
the fewest to the most elements over the growth of ``factor_s``, at most 1.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

from twin.params import Params, load_params
from twin.sim.plant import Plant
from twin.stopwatch import Stopwatch

__all__ = ["SCALING_FACTORS", "bench_sim"]

# Element counts of the scaling runs, as multiples of sim.elements.
SCALING_FACTORS = (1, 2, 4)


def bench_sim(params: Params | None = None, *, duration_s: float = 2.0, elements: int | None = None,
              scaling: bool = True) -> dict:
    """Time the default twin.

    Args:
        params: parameter set (default ``models/endoscope/endoscope.toml``).
        duration_s: simulated time per timed run (s); the best of five runs is kept.
        elements: override of ``sim.elements``.
        scaling: also time the PWM run at :data:`SCALING_FACTORS` × the element count.

    Returns:
        ``steps_per_s``, ``realtime_factor`` (simulated s per CPU s; the tendons of the braked
        spools sag to the slack edge and rest there) and ``realtime_factor_wall`` (per wall s),
        ``short_steps`` (physics steps of the timed runs taken as shorter ones,
        :data:`twin.sim.plant.ENGAGE_MAX_STEP_S`), ``taut_realtime_factor`` (the same after
        settling a bend held by tension sources, every tendon taut), ``timestep_s``,
        ``elements``, ``dofs``, ``factor_s`` (CPU time of one factorization of the mass matrix,
        of which each step takes two; see the module docstring), ``settle_s`` (CPU) and
        ``settle_wall_s``, ``settle_sim_s`` (a tension step from straight, to 1 µm), ``settled``;
        with ``scaling``, ``scaling``: one ``{"elements", "dofs", "realtime_factor",
        "steps_per_s", "factor_s"}`` per element count, and ``scaling_exponent``: d log(CPU time
        per step) / d log(elements) from the first to the last (1 is linear),
        ``scaling_realtime_ratio``: the real-time factor at the most elements over that at the
        fewest, and ``scaling_over_chain``: the growth of the time per step over the growth of
        ``factor_s`` between them (at most 1: the twin's step grows no faster than the
        factorization MuJoCo's serial chain imposes).
    """
    params = params if params is not None else load_params()
    plant = Plant(params, elements=elements)
    (best, best_wall), short = _pwm_realtime_factor(plant, duration_s)
    plant.reset()
    tensions = np.full(plant.tendon_count, params.tendons.pretension_n)
    tensions[0] += 1.0
    plant.set_tensions(tensions)
    with Stopwatch() as settle_watch:
        settle = plant.settle()
    # The same bend held by tension sources: every tendon taut, so every step is a full one.
    taut, _ = _best_realtime_factor(plant, duration_s)
    figures: dict[str, Any] = {
        "steps_per_s": best / plant.timestep_s,
        "realtime_factor": best,
        "realtime_factor_wall": best_wall,
        "short_steps": short,
        "timestep_s": plant.timestep_s,
        "elements": plant.layout.elements,
        "dofs": int(plant.model.nv),
        "factor_s": _factor_s(plant),
        "taut_realtime_factor": taut,
        "settle_s": settle_watch.cpu_s,
        "settle_wall_s": settle.wall_time_s,
        "settle_sim_s": settle.sim_time_s,
        "settled": settle.settled,
    }
    if scaling:
        runs = []
        for factor in SCALING_FACTORS:
            scaled = Plant(params, elements=factor * plant.layout.elements)
            rtf = best if factor == 1 else _pwm_realtime_factor(scaled, duration_s)[0][0]
            runs.append({"elements": scaled.layout.elements, "dofs": int(scaled.model.nv), "realtime_factor": rtf,
                         "steps_per_s": rtf / scaled.timestep_s,
                         "factor_s": figures["factor_s"] if factor == 1 else _factor_s(scaled)})
        figures["scaling"] = runs
        first, last = runs[0], runs[-1]
        figures["scaling_exponent"] = (math.log(first["realtime_factor"] / last["realtime_factor"])
                                       / math.log(last["elements"] / first["elements"]))
        figures["scaling_realtime_ratio"] = last["realtime_factor"] / first["realtime_factor"]
        figures["scaling_over_chain"] = ((first["steps_per_s"] / last["steps_per_s"])
                                         / (last["factor_s"] / first["factor_s"]))
    return figures


def _pwm_realtime_factor(plant: Plant, duration_s: float) -> tuple[tuple[float, float], int]:
    """((best real-time factor on CPU time, on wall time), short steps taken) of the device
    layer's drive: pretensioned, settled, then one motor pulling at 2% duty with the others braked."""
    plant.set_tensions(np.full(plant.tendon_count, plant.params.tendons.pretension_n))
    plant.settle()
    duty = np.zeros(plant.tendon_count)
    duty[0] = -0.02
    plant.set_motor_pwm(duty)
    short = plant.short_steps
    best = _best_realtime_factor(plant, duration_s)
    return best, plant.short_steps - short


def _best_realtime_factor(plant: Plant, duration_s: float, runs: int = 5) -> tuple[float, float]:
    """Simulated s per CPU s and per wall s of ``plant.step(duration_s)``, the best of ``runs`` each."""
    best = best_wall = 0.0
    for _ in range(runs):
        with Stopwatch() as watch:
            plant.step(duration_s)
        best = max(best, duration_s / watch.cpu_s)
        best_wall = max(best_wall, duration_s / watch.wall_s)
    return best, best_wall


def _factor_s(plant: Plant, repeats: int = 50, runs: int = 5) -> float:
    """CPU time of one ``mj_factorM`` of the plant's mass matrix as it stands (s), the best of
    ``runs`` averages over ``repeats``; the next step computes the factor afresh."""
    model, data = plant.model, plant.data
    best = math.inf
    for _ in range(runs):
        with Stopwatch() as watch:
            for _ in range(repeats):
                mujoco.mj_factorM(model, data)
        best = min(best, watch.cpu_s / repeats)
    return best
