"""Env throughput on one core (``twin bench env``): steps of the default env per CPU second
(:class:`twin.stopwatch.Stopwatch`; per wall second beside it, under ``_wall`` names).

One step is one 40 Hz control period, 25 ms of device time: on ``sim://`` five 5 ms firmware
ticks of the MuJoCo twin (run by the plant loop, ``twin/sim/native/loop.cpp``), so the figure is bounded by the twin's real-time factor × 40. The bench also times those
25 ms of device time alone, so the env's own share is visible.
"""

from __future__ import annotations

import numpy as np

from twin.envs.reach import EndoscopeReachEnv
from twin.control.cocontraction import antagonistic_pair
from twin.params import Params, load_params
from twin.stopwatch import Stopwatch

__all__ = ["bench_env"]

# Amplitude of the sway as a fraction of the pretension: 0.5 N of the thesis endoscope's 1.35 N.
_SWAY_OF_PRETENSION = 0.37


def bench_env(params: Params | None = None, *, steps: int = 400, seed: int = 0) -> dict:
    """Time the default env (tension actions, tip loads) on ``sim://``, the best of three runs.

    The actions sway the robot's antagonistic pair's tensions
    (:func:`twin.control.cocontraction.antagonistic_pair`) in opposition by 0.37 × the pretension
    (±0.5 N on the thesis endoscope) at 1 Hz, a motion that neither faults the board nor leaves the
    twin at rest.

    Returns:
        ``steps_per_s`` (env steps per CPU second), ``realtime_factor`` (device s per CPU s),
        ``device_period_ms`` (CPU time of 25 ms of device time with no env around it),
        ``env_overhead_ms`` (the env's own CPU time per step), ``reset_s`` (CPU time of a reset);
        ``steps_per_s_wall``, ``realtime_factor_wall``, ``reset_wall_s`` on the wall clock.
    """
    params = params if params is not None else load_params()
    env = EndoscopeReachEnv(params=params)
    try:
        with Stopwatch() as reset:
            env.reset(seed=seed)
        pretension = params.tendons.pretension_n
        a, b = antagonistic_pair(params)
        sway = np.zeros(params.tendons.count)
        sway[a], sway[b] = 1.0, -1.0
        actions = [env.action_for(pretension * (1.0 + _SWAY_OF_PRETENSION * np.sin(w) * sway))
                   for w in 2 * np.pi * np.arange(steps) / 40.0]
        device = env.device
        period_s = device.info.telemetry_period_s
        step_s = step_wall_s = device_s = float("inf")
        # The best of three runs.
        for _ in range(3):
            with Stopwatch() as run:
                for action in actions:
                    env.step(action)
            step_s = min(step_s, run.cpu_s / steps)
            step_wall_s = min(step_wall_s, run.wall_s / steps)
            with Stopwatch() as run:
                for _ in range(steps):
                    device.wait(period_s)
            device_s = min(device_s, run.cpu_s / steps)
    finally:
        env.close()
    return {
        "steps_per_s": 1.0 / step_s,
        "realtime_factor": period_s / step_s,
        "device_period_ms": device_s * 1e3,
        "env_overhead_ms": (step_s - device_s) * 1e3,
        "reset_s": reset.cpu_s,
        "steps_per_s_wall": 1.0 / step_wall_s,
        "realtime_factor_wall": period_s / step_wall_s,
        "reset_wall_s": reset.wall_s,
        "steps": steps,
    }
