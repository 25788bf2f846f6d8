"""Tendon friction remembers how a static state was reached: the host follows each tendon's
sliding state from its encoder the way the twin's friction follows its spool, every validation
row records it, and an approach from the other side leaves other states (and shapes)."""

import numpy as np
import pytest

from twin.data.dataset import read_dataset
from twin.device import open_device
from twin.effects import SlidingState
from twin.effects.tendon_friction import PRESLIDING_M, slide
from twin.experiments import protocols
from twin.params import load_params

GRID = [(0, 13.0, 0.0, 0.0), (1, 13.0, 0.0, 0.01), (2, 13.0, 120.0, 0.0), (3, 0.0, 0.0, 0.0)]


class _Sample:
    def __init__(self, counts):
        self.encoder_counts = np.asarray(counts)


def test_the_sliding_state_moves_over_the_presliding_travel_and_holds_when_the_tendon_stands():
    state = SlidingState(tendon_m_per_count=PRESLIDING_M / 10)
    assert state.follow([_Sample([0, 0])]).tolist() == [0.0, 0.0]
    # Tendon 1 paid out 5 counts (half the presliding travel), tendon 2 pulled in 30.
    assert state.follow([_Sample([5, -15]), _Sample([5, -30])]).tolist() == pytest.approx([-0.5, 1.0])
    assert state.follow([_Sample([5, -30])] * 3).tolist() == pytest.approx([-0.5, 1.0])
    assert slide([1.0, -1.0], [-PRESLIDING_M, 3 * PRESLIDING_M]).tolist() == pytest.approx([0.0, 1.0])


def _sweep(tmp_path, **options):
    params = load_params()
    twin = params.replace({"effects.tendon_friction_coeff": 0.15})
    truth = []
    measure = protocols.measure
    with open_device("sim://", params=twin) as device:
        plant = device.twin._board.plant

        def measured(dev, **kw):
            m = measure(dev, **kw)
            truth.append(plant.sliding_state)
            return m

        try:
            protocols.measure = measured
            protocols.run_validation(device, tmp_path, params, grid=GRID, progress=False, **options)
        finally:
            protocols.measure = measure
    return read_dataset(tmp_path), np.array(truth)


def test_every_row_records_the_sliding_state_the_twins_friction_is_in(tmp_path):
    data, truth = _sweep(tmp_path / "d")
    assert np.isfinite(data.sliding_state).all()
    # The host sees the encoders at 40 Hz; the spool's dither between samples (a few µm, which
    # the twin's friction integrates at every physics step) it cannot see.
    assert np.median(np.abs(data.sliding_state - truth)) < 0.1
    assert np.abs(data.sliding_state - truth).max() < 0.5
    # The old guess (+1 for a shortened tendon) is not the state: the length controller settles
    # by backing off some µm, which turns part of the friction round.
    bent = data["kappa_cmd_per_m"] > 0
    assert np.any(np.abs(data.sliding_state[bent]) < 0.9)


def test_approaching_from_the_other_side_turns_the_sliding_states_and_the_shape(tmp_path):
    straight, _ = _sweep(tmp_path / "a")
    over, truth = _sweep(tmp_path / "b", overshoot=0.25, min_overshoot_m=2e-4)
    assert np.median(np.abs(over.sliding_state - truth)) < 0.1
    bent = (straight["kappa_cmd_per_m"] > 0) & (straight["tip_mass_kg"] == 0)
    moved = np.abs(straight.lengths_m[bent]) > 1e-4
    assert moved.sum() >= 4
    # The last motions differ (the length controller's own settling, tens of µm, decides the
    # rest): the same setpoints leave the friction in other states.
    turned = np.abs(over.sliding_state[bent] - straight.sliding_state[bent])[moved]
    assert np.count_nonzero(turned > 0.5) >= moved.sum() // 2
    # Same setpoints, another history: another shape (friction), beyond even one tracker frame's
    # noise (a row averages about ten).
    shift = np.linalg.norm(over.tip_positions_m[bent] - straight.tip_positions_m[bent], axis=1)
    assert shift.min() > load_params().sensors.tracker_noise_m
