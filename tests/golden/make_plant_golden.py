"""Regenerates ``plant_golden.npz``: the twin's trajectories the plant loop must reproduce (to 1e-12).

The file pins what the twin does — physics steps, engagement short steps, sensor samples and the
emulated board's ticks — so that a change to the loop that moves any number is seen. Regenerate
it (``python tests/golden/make_plant_golden.py``) only for a change meant to move the numbers,
and say so in the commit. The tests compare with a tolerance of 1e-12 relative
(``GOLDEN_RTOL`` in ``tests/test_plant_loop.py``): the last bits of a double differ between CPUs
and patch releases of numpy and MuJoCo; a change to the loop moves the numbers far more.

Cases: a plant driven through every drive and fixture change (four tendons, three tendons, with
tendon friction); a short validation sweep through ``sim://`` (default step, a 2.5 ms step, and
with friction); two env episodes with a power cycle between them.
"""

from __future__ import annotations

import csv
import sys
import tempfile
from pathlib import Path

import numpy as np

GOLDEN = Path(__file__).with_name("plant_golden.npz")


def plant_script(plant, pretension_n: float) -> np.ndarray:
    """Every drive and fixture change the device layer makes, with the state and samples after each."""
    n = plant.tendon_count
    record = []

    def mark():
        cells, frame = plant.loadcell_sample(), plant.tracker_probes()
        record.append(np.concatenate([plant.data.qpos, plant.data.qvel, cells.raw_counts, [cells.index, frame.index],
                                      frame.positions_m.ravel(), frame.axes.ravel(), [plant.time_s, plant.short_steps]]))

    def pattern(*values):
        return np.resize(np.array(values, dtype=float), n)

    plant.engage_holder()
    plant.set_tensions(np.full(n, pretension_n))
    plant.step(0.3)
    mark()
    plant.release_holder()
    assert plant.settle().settled
    mark()
    plant.set_motor_pwm(pattern(-0.02, 0.0, 0.01, 0.0))  # a slack tendon taken up
    plant.step(1.0)
    mark()
    plant.set_tip_mass_kg(0.01)
    plant.coast()
    plant.step(0.4)
    mark()
    plant.set_tendon_lengths(pattern(-0.002, 0.0, 0.002, 0.0))
    plant.step(0.75)  # a chunk that does not end on a sample
    mark()
    plant.set_motor_pwm(pattern(0.03, -0.03, 0.0, 0.0))
    for _ in range(40):  # single steps, as the board takes them
        plant.step(plant.timestep_s)
    mark()
    plant.step(6.0)  # beyond one noise buffer
    mark()
    return np.array(record)


def sweep(params, grid, url: str) -> np.ndarray:
    """A validation sweep on ``url``: the dataset's numeric columns, in file order."""
    from twin.driver import open_device
    from twin.experiments.protocols import nominal_calibration, run_validation

    with tempfile.TemporaryDirectory() as folder, open_device(url, params=params) as device:
        cal = nominal_calibration(params)
        device.set_calibration(gain_counts_per_n=cal["gain_counts_per_n"], offset_counts=cal["offset_counts"])
        run_validation(device, folder, params, grid=grid, progress=False)
        with open(Path(folder) / "measurements.csv") as f:
            rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    columns = [j for j, name in enumerate(header) if name != "experiment"]
    return np.array([[float(r[j]) for j in columns] for r in body])


def env_episodes() -> np.ndarray:
    from twin.envs.reach import EndoscopeReachEnv

    env = EndoscopeReachEnv(device_url="sim://", action_mode="lengths")
    rng = np.random.default_rng(5)
    observations = []
    try:
        for episode in range(2):  # the second reset power-cycles the board
            obs, _ = env.reset(seed=episode)
            observations.append(np.append(obs, [0.0, 0.0]))
            for _ in range(60):
                obs, reward, terminated, _, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
                observations.append(np.append(obs, [reward, info["fault"]]))
                if terminated:
                    break
    finally:
        env.close()
    return np.array(observations)


def _params():
    from twin import load_params

    return load_params()


def _friction():
    return _params().replace({"effects.tendon_friction_coeff": 0.1})


def _grid():
    from twin.pcc import validation_grid

    # Straight and fully bent, three planes, with and without the 10 g mass: pretension with the
    # calibration masses (held tensions), length moves, tip masses, tendons paid out to slack.
    return [g for g in validation_grid() if g[1] in (0.0, 26.2) and g[2] % 120 == 0 and g[3] in (0.0, 0.01)]


def _plant(params, seed: int) -> np.ndarray:
    from twin.sim.plant import Plant

    return plant_script(Plant(params, seed=seed), params.tendons.pretension_n)


def _three_tendons():
    return _params().replace({"tendons.angles_deg": [0.0, 120.0, 240.0], "effects.tension_gain_error": [0.0] * 3,
                              "effects.tension_offset_error_n": [0.0] * 3, "sensors.loadcell_offset_counts": [0.0] * 3})


CASES = {
    "plant": lambda: _plant(_params(), 4),
    "plant_three_tendons": lambda: _plant(_three_tendons(), 2),
    "plant_friction": lambda: _plant(_friction(), 1),
    "sweep": lambda: sweep(_params(), _grid(), "sim://?seed=3"),
    "sweep_step_2_5_ms": lambda: sweep(_params().replace({"sim.timestep_s": 0.0025}), _grid()[:4], "sim://?seed=3"),
    "sweep_friction": lambda: sweep(_friction(), _grid()[:2], "sim://?seed=3"),
    "env": env_episodes,
}


if __name__ == "__main__":
    np.savez_compressed(sys.argv[1] if len(sys.argv) > 1 else GOLDEN, **{name: case() for name, case in CASES.items()})
    print(f"wrote {sys.argv[1] if len(sys.argv) > 1 else GOLDEN}")
