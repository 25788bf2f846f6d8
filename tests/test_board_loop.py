"""The emulated board's native tick loop gives the Python path's numbers to the bit."""

import shutil

import numpy as np
import pytest

from envs.reach import EndoscopeReachEnv
from twin import load_params
from twin.device import open_device
from twin.device.board_loop import Reason, available
from twin.data.dataset import read_dataset
from twin.experiments.protocols import nominal_calibration, run_validation
from twin.pcc import validation_grid

# Without g++ the board ticks in Python (with a warning); with it, a build that fails is a bug.
pytestmark = pytest.mark.skipif(shutil.which("g++") is None, reason="no g++ here to build the native loop")

MODEL = load_params()
# Straight and fully bent, three planes, with and without the 10 g mass: pretension with the
# calibration masses (held tensions), length moves, tip masses, tendons paid out to slack.
GRID = [g for g in validation_grid() if g[1] in (0.0, 26.2) and g[2] % 120 == 0 and g[3] in (0.0, 0.01)]


def test_the_native_tick_loop_is_available():
    assert available()


def _sweep(folder, native):
    with open_device(f"sim://?seed=3&native={native}", params=MODEL) as device:
        cal = nominal_calibration(MODEL)
        device.set_calibration(gain_counts_per_n=cal["gain_counts_per_n"], offset_counts=cal["offset_counts"])
        run_validation(device, folder, MODEL, grid=GRID, progress=False)
        board = device.transport.board
        loop = device.transport._loop
        ticks = round(board.plant.time_s / 0.005)
        return (board.plant.data.qpos.copy(), board.plant.data.qvel.copy(), read_dataset(folder), loop, ticks,
                board.plant.short_steps)


def test_a_sweep_is_the_same_with_the_native_loop_and_without(tmp_path):
    qpos, qvel, data, loop, ticks, short = _sweep(tmp_path / "native", 1)
    qpos_py, qvel_py, data_py, loop_py, ticks_py, short_py = _sweep(tmp_path / "python", 0)
    assert loop_py is None and ticks == ticks_py
    # Most ticks ran natively, short steps among them, and every way back to Python was taken.
    assert loop.native_ticks > 0.9 * ticks
    assert short == short_py > 0
    for reason in (Reason.KEEPALIVE, Reason.APPLY, Reason.TX, Reason.NOISE, Reason.DONE):
        assert loop.returns.get(reason, 0) > 0, (reason, loop.returns)
    assert np.array_equal(qpos, qpos_py) and np.array_equal(qvel, qvel_py)
    assert data.columns.keys() == data_py.columns.keys()
    for name, column in data.columns.items():
        assert np.array_equal(column, data_py.columns[name]), name


def test_env_episodes_are_the_same_with_the_native_loop_and_without():
    runs = []
    for native in (True, False):
        env = EndoscopeReachEnv(device_url=f"sim://?native={int(native)}", action_mode="lengths")
        rng = np.random.default_rng(5)
        observations = []
        try:
            for episode in range(2):  # the second reset power-cycles the board
                obs, _ = env.reset(seed=episode)
                observations.append(obs)
                for _ in range(60):
                    obs, reward, terminated, _, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
                    observations.append(np.append(obs, [reward, info["fault"]]))
                    if terminated:
                        break
        finally:
            env.close()
        runs.append(observations)
    assert len(runs[0]) == len(runs[1])
    assert all(np.array_equal(a, b) for a, b in zip(*runs))


def test_the_native_option_takes_zero_or_one():
    with pytest.raises(ValueError, match="native=2"):
        open_device("sim://?native=2")
