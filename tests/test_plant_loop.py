"""The plant loop (twin/sim/native/loop.cpp) and its binding: the twin's numbers, pinned to 1e-12 of each value."""

import ctypes
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from twin import load_params
from twin.driver import open_device
from twin.sim import native_loop
from twin.effects.tendon_friction import FRICTION_MAX_STEP_S
from twin.sim.plant import Plant

sys.path.insert(0, str(Path(__file__).parent / "golden"))
import make_plant_golden  # noqa: E402

GOLDEN = np.load(make_plant_golden.GOLDEN)


def test_the_state_is_laid_out_from_the_loops_own_table():
    native_loop.load()
    fields = dict(native_loop.LoopState._fields_)
    assert ctypes.sizeof(native_loop.LoopState) == native_loop.load().lib.bl_state_size()
    # A few fields of each kind, as loop.cpp declares them.
    assert fields["step_s"] is ctypes.c_double and fields["channels"] is ctypes.c_int32
    assert fields["duty"]._length_ == native_loop.load().max_channels and fields["drive"]._type_ is ctypes.c_uint8


# How closely a run must reproduce its golden trajectory: 1e-12 of each value, and 1e-12 of its
# column's largest magnitude as a floor, so a quantity passing through zero (a velocity, an
# offset) is held at its own scale. Another CPU, BLAS or patch release of numpy or MuJoCo moves
# the last bit or two of a double (seen: 2-6e-16 relative); any change to what the loop does
# moves them by many orders more (a 1e-9 change to one input: ~1e-9, see the test below).
GOLDEN_RTOL = 1e-12


def golden_mismatch(actual: np.ndarray, golden: np.ndarray) -> str | None:
    """None when ``actual`` reproduces ``golden`` within :data:`GOLDEN_RTOL`, else what differs."""
    actual, golden = np.asarray(actual, dtype=float), np.asarray(golden, dtype=float)
    if actual.shape != golden.shape:
        return f"shape {actual.shape}, golden {golden.shape}"
    if not np.array_equal(np.isnan(actual), np.isnan(golden)):
        return "NaN in other places than the golden run's"
    scale = np.nanmax(np.abs(golden), axis=0, keepdims=True) if golden.ndim > 1 else np.nanmax(np.abs(golden))
    tolerance = GOLDEN_RTOL * (np.abs(golden) + scale)
    off = ~np.isnan(golden) & ~(np.abs(actual - golden) <= tolerance)
    if not off.any():
        return None
    worst = np.unravel_index(np.argmax(np.where(off, np.abs(actual - golden) / tolerance, 0)), golden.shape)
    return (f"{off.sum()} of {golden.size} values beyond {GOLDEN_RTOL:g} relative, the worst at {worst}: "
            f"{actual[worst]!r} against {golden[worst]!r}")


@pytest.mark.parametrize("case", sorted(make_plant_golden.CASES))
def test_the_twin_reproduces_its_golden_trajectories(case):
    # Every drive and fixture change, sensor samples, engagement short steps, a noise refill, the
    # board's ticks, friction's per-step hook, three tendons and a 2.5 ms step: any change to
    # the loop that moves a number fails here (regenerate with the script beside the file).
    assert golden_mismatch(make_plant_golden.CASES[case](), GOLDEN[case]) is None


def test_the_golden_tolerance_passes_rounding_and_catches_a_change():
    golden = GOLDEN["plant"]
    # The last bits of every double moved, as another machine's arithmetic moves them.
    rounding = golden * (1 + np.random.default_rng(0).choice([-4, 4], golden.shape) * np.finfo(float).eps)
    assert golden_mismatch(rounding, golden) is None
    # The same script with the pretension changed in its ninth digit: the loop's numbers move.
    params = load_params()
    moved = make_plant_golden.plant_script(Plant(params, seed=4), params.tendons.pretension_n * (1 + 1e-9))
    assert golden_mismatch(moved, golden) is not None
    assert golden_mismatch(golden[:-1], golden) is not None


def test_the_golden_runs_take_short_steps_and_refill_the_noise():
    # The pinned script exercises the engagement check and outlasts one noise buffer.
    record, params = GOLDEN["plant"], load_params()
    assert record[-1, -1] > 0
    draws_per_s = params.rig.loadcell_rate_hz * 4 + params.rig.tracker_rate_hz * 12
    assert record[-1, -2] > 4096 / draws_per_s


def test_friction_runs_inside_the_loop_at_the_twins_own_step():
    # No call back into Python per physics step (which made a friction twin several times slower
    # and swallowed Ctrl-C), and no shorter steps at the default 5 ms.
    plant = Plant(load_params().replace({"effects.tendon_friction_coeff": 0.1}))
    state = plant.loop.state
    assert not state.hook_fn and state.friction_coeff == 0.1 and state.friction_sites
    assert state.base_substeps == math.ceil(plant.timestep_s / FRICTION_MAX_STEP_S - 1e-9) == 1
    plant.set_tensions([3.0, 1.0, 0.5, 1.0])
    plant.step(0.2)
    assert plant.sliding_state[0] == 1.0 and plant.sliding_state[2] == -1.0
    # Continuous routing: the loss pulls the joints as the fixed tendon does (the axial slides by
    # ~0.4 N here); a frictionless plant applies nothing there.
    assert np.abs(plant.data.qfrc_applied).max() > 0.1
    free = Plant(load_params()).loop.state
    assert not free.hook_fn and free.friction_coeff == 0.0


def test_friction_set_to_zero_at_run_time_leaves_no_force_behind():
    # What twin.sim.events does to a running plant's μ: the loop keeps clearing what it applied.
    plant = Plant(load_params().replace({"effects.tendon_friction_coeff": 0.1}))
    plant.set_tensions([3.0, 1.0, 0.5, 1.0])
    plant.step(0.2)
    assert np.abs(plant.data.qfrc_applied).max() > 0.1
    plant.loop.state.friction_coeff = 0.0
    plant.step(0.05)
    assert np.abs(plant.data.qfrc_applied).max() < 1e-9


def test_a_plant_takes_any_tendon_count_the_loop_holds():
    params = load_params()
    n = native_loop.load().max_channels
    angles = list(np.linspace(0.0, 360.0, n, endpoint=False))
    many = params.replace({"tendons.angles_deg": angles, "effects.tension_gain_error": [0.0] * n,
                           "effects.tension_offset_error_n": [0.0] * n, "sensors.loadcell_offset_counts": [0.0] * n})
    plant = Plant(many)
    plant.set_tensions(np.full(n, 1.0))
    plant.step(0.1)
    assert plant.loadcell_sample().raw_counts.shape == (n,)
    assert np.all(plant.true_tensions_n() > 0.5)


def test_the_old_native_switch_is_an_unknown_option():
    with pytest.raises(ValueError, match="native"):
        open_device("sim://?native=0")


def test_the_peak_tension_is_the_largest_any_physics_step_saw():
    plant = Plant(load_params(), seed=1)
    plant.set_tensions([1.0, 1.0, 1.0, 1.0])
    plant.step(0.3)
    plant.set_motor_pwm([-0.03, 0.0, 0.0, 0.0])  # the motor winds tendon 1 in, then lets go
    seen = np.zeros(4)
    for k in range(60):
        if k == 30:
            plant.coast()
        plant.step(plant.timestep_s)
        seen = np.maximum(seen, plant.true_tensions_n())
    peak = plant.peak_tensions_n()
    assert np.all(peak >= seen) and np.allclose(peak, seen, rtol=0.2)
    assert peak[0] > 2 * plant.true_tensions_n()[0]
    plant.clear_peak_tensions()
    assert np.array_equal(plant.peak_tensions_n(), plant.true_tensions_n())
