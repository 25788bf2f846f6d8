"""The discrepancy workflow on data the MuJoCo twin generates (issue 7, proof on hidden effects).

The sweeps run through the device interface (the real firmware on the twin, load-cell and
tracker noise on), with the effect hidden in the simulated rig only: the model recorded with the
dataset knows nothing of it.
"""

import numpy as np
import pytest

from twin import load_params
from twin.device import open_device
from twin.discrepancy import run_discrepancy
from twin.experiments.dataset import read_dataset
from twin.experiments.protocols import nominal_calibration, run_validation
from twin.pcc import validation_grid

MODEL = load_params()
# 48 configurations: 4 curvatures x 6 planes x (0, 10 g).
SMALL_GRID = [g for g in validation_grid()
              if g[1] in (0.0, 8.7, 17.5, 26.2) and g[2] in (0.0, 60.0, 120.0, 180.0, 240.0, 300.0) and g[3] != 0.005]


def twin_sweep(folder, hidden, grid, seed=3):
    truth = MODEL.replace(hidden, source="hidden") if hidden else MODEL
    with open_device(f"sim://?seed={seed}", params=truth) as device:
        cal = nominal_calibration(MODEL)
        device.set_calibration(gain_counts_per_n=cal["gain_counts_per_n"], offset_counts=cal["offset_counts"])
        run_validation(device, folder, MODEL, grid=grid, progress=False)
    return read_dataset(folder)


def test_no_hidden_effect_names_none(tmp_path):
    result = run_discrepancy(twin_sweep(tmp_path, {}, SMALL_GRID))
    assert result.effect == "none"
    assert result.rms_after_m == result.rms_before_m < 3e-4


def test_hidden_load_cell_gains_are_named_and_recovered(tmp_path):
    gains = [0.08, -0.06, 0.05, -0.07]
    result = run_discrepancy(twin_sweep(tmp_path, {"effects.tension_gain_error": gains}, SMALL_GRID))
    assert result.effect == "tension_gain"
    fitted = [result.parameters()[f"effects.tension_gain_error[{i}]"]["value"] for i in range(4)]
    assert np.allclose(fitted, gains, atol=0.01)
    assert result.rms_after_m < 0.3 * result.rms_before_m


@pytest.mark.slow
def test_hidden_friction_on_the_full_grid_is_named(tmp_path):
    result = run_discrepancy(twin_sweep(tmp_path, {"effects.tendon_friction_coeff": 0.15}, validation_grid()))
    assert result.effect == "tendon_friction"
    mu = result.parameters()["effects.tendon_friction_coeff"]
    assert abs(mu["value"] - 0.15) < 0.02
    assert result.rms_after_m < 0.5 * result.rms_before_m
