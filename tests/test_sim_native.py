"""Plant.step in native code gives the Python path's numbers to the bit."""

import shutil

import numpy as np
import pytest

from twin import load_params
from twin.sim import native_loop
from twin.sim.plant import Plant

# Without g++ the twin steps in Python (with a warning); with it, a build that fails is a bug.
pytestmark = pytest.mark.skipif(shutil.which("g++") is None, reason="no g++ here to build the native loop")

PARAMS = load_params()


def _script(plant):
    """Every drive and fixture change the device layer makes, with the samples after each."""
    pre = PARAMS.tendons.pretension_n
    record = []

    def mark():
        cells, frame = plant.loadcell_sample(), plant.tracker_probes()
        record.append(np.concatenate([plant.data.qpos, plant.data.qvel, cells.raw_counts, [cells.index, frame.index],
                                      frame.positions_m.ravel(), frame.axes.ravel(), [plant.time_s, plant.short_steps]]))

    plant.engage_holder()
    plant.set_tensions(np.full(4, pre))
    plant.step(0.3)
    mark()
    plant.release_holder()
    assert plant.settle().settled
    mark()
    plant.set_motor_pwm([-0.02, 0.0, 0.01, 0.0])  # the sim bench's drive, and a slack tendon taken up
    plant.step(1.0)
    mark()
    plant.set_tip_mass_kg(0.01)
    plant.coast()
    plant.step(0.4)
    mark()
    plant.set_tendon_lengths([-0.002, 0.0, 0.002, 0.0])
    plant.step(0.75)  # a chunk that does not end on a sample
    mark()
    plant.set_motor_pwm([0.03, -0.03, 0.0, 0.0])
    for _ in range(40):  # single steps, as the board takes them
        plant.step(plant.timestep_s)
    mark()
    plant.step(6.0)  # beyond one noise buffer: the loop hands back for a refill
    mark()
    return np.array(record)


def test_the_native_loop_builds():
    assert native_loop.available()


def test_plant_steps_are_the_same_in_native_code_and_in_python():
    native, python = Plant(PARAMS, seed=4), Plant(PARAMS, seed=4, native=False)
    assert native._native is not None and python._native is None
    a, b = _script(native), _script(python)
    assert np.array_equal(a, b)
    assert a[-1, -1] > 0  # short steps were taken
    # Every way back to Python was taken, and most steps ran natively.
    assert native._native.returns.get(native_loop.Reason.NOISE, 0) > 0
    assert native._native.returns.get(native_loop.Reason.DONE, 0) > 0


def test_a_plant_with_friction_steps_in_python():
    # Friction is updated from Python between steps.
    assert Plant(PARAMS.replace({"effects.tendon_friction_coeff": 0.1}))._native is None
