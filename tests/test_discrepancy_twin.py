"""The discrepancy workflow on data the MuJoCo twin generates: the proof on hidden effects.

The sweeps run through the device interface (the real firmware on the twin, load-cell and
tracker noise on), with the effect hidden in the simulated rig only: the model recorded with the
dataset knows nothing of it. The twin differs from the predictor by its own discretisation
(reports/crosscheck: 0.04 mm median), so the tolerances are a little wider than on the
predictor-made data of tests/test_discrepancy.py, with the same values hidden.
"""

import numpy as np
import pytest

from twin import load_params
from twin.driver import open_device
from twin.discrepancy import candidate_library, find_discrepancy, run_discrepancy
from twin.data.dataset import read_dataset
from twin.experiments.protocols import nominal_calibration, run_validation
from twin.pcc import validation_grid

MODEL = load_params()
# A sixth of the thesis grid (κ 0/13/26.2 1/m, every other plane, 0 and 10 g): 36 configurations.
GRID = [g for g in validation_grid() if g[1] in (0.0, 13.0, 26.2) and g[2] % 60 == 0 and g[3] in (0.0, 0.01)]

# effect → (hidden values in the twin, what the fit should find, tolerance).
HIDDEN = {
    "tension_gain": ({"effects.tension_gain_error": [0.08, -0.06, 0.05, -0.07]}, [0.08, -0.06, 0.05, -0.07], 0.015),
    # Only the antagonist differences o1 − o3, o2 − o4 bend the endoscope (twin/effects/tension_offset.py).
    "tension_offset": ({"effects.tension_offset_error_n": [0.08, -0.06, -0.05, 0.07]}, [0.13, -0.13], 0.02),
    "weight": ({"backbone.mass_kg": 0.0078}, [0.0078], 0.0006),
    "tip_load": ({"effects.tip_load_error_fraction": 0.15}, [0.15], 0.03),
    "stiffness": ({"backbone.youngs_modulus_pa": 0.8 * 8.2414e6}, [0.8 * 8.2414e6], 0.04 * 8.2414e6),
    "base_tilt": ({"effects.base_tilt_deg": [1.5, -1.0]}, [1.5, -1.0], 0.25),
    "tracker_offset": ({"effects.tracker_offset_m": [0.0015, -0.001, 0.002]}, [0.0015, -0.001, 0.002], 4e-4),
}


def twin_sweep(folder, hidden, grid, seed=3):
    truth = MODEL.replace(hidden, source="hidden") if hidden else MODEL
    with open_device(f"sim://?seed={seed}", params=truth) as device:
        cal = nominal_calibration(MODEL)
        device.set_calibration(gain_counts_per_n=cal["gain_counts_per_n"], offset_counts=cal["offset_counts"])
        run_validation(device, folder, MODEL, grid=grid, progress=False)
    return read_dataset(folder)


def test_no_hidden_effect_names_none(tmp_path):
    result = run_discrepancy(twin_sweep(tmp_path, {}, GRID))
    assert result.effect == "none", [r.to_dict()["ranking"][:3] for r in result.rounds]
    assert result.rms_after_m == result.rms_before_m < 3e-4


# Every candidate of the library but friction, whose own test is below (a new one fails here until
# HIDDEN hides it).
@pytest.mark.parametrize("effect", sorted(set(candidate_library(MODEL)) - {"tendon_friction"}))
def test_a_hidden_effect_in_the_twin_is_named_and_the_gap_shrinks(tmp_path, effect):
    hidden, truth, tol = HIDDEN[effect]
    result = run_discrepancy(twin_sweep(tmp_path, hidden, GRID))
    assert result.named[:1] == (effect,), [r.to_dict()["ranking"][:3] for r in result.rounds]
    # The effect's own fit, as named in the first round. A later round may add what the twin's
    # model-form difference leaves: on the offsets' data a 2 % gain on one load cell takes the
    # held-out RMS from 0.38 to 0.24 mm and moves the joint refit's o_1 to 0.106.
    first = result.rounds[0].winner.fit.values
    assert np.allclose(first[:len(truth)], truth, atol=tol), (first, truth)
    assert result.rms_after_m < 0.5 * result.rms_before_m


# A third of the grid (κ 0/8.7/17.5/26.2 1/m, every other plane, all three masses): on a sixth,
# a stiffer backbone explains the twin's friction almost as well (scores −84 vs −80).
FRICTION_GRID = [g for g in validation_grid() if g[1] in (0.0, 8.7, 17.5, 26.2) and g[2] % 60 == 0]


@pytest.mark.slow
def test_hidden_friction_is_named_and_its_y_signature_removed(tmp_path):
    result = run_discrepancy(twin_sweep(tmp_path, {"effects.tendon_friction_coeff": 0.15}, FRICTION_GRID))
    if result.tied:
        # The twin's friction (a Dahl state per tendon) is not the predictor's (a sign per
        # tendon), and on this third of the grid the load-cell gains explain it about as well
        # (scores -120 vs -108): the honest answer is the tie, which must then include friction.
        assert result.verdict in ("ambiguous", "unexplained") and result.named == ()
        assert "tendon_friction" in {s.effect for s in result.tied}, result.statement()
        return
    assert result.effect == "tendon_friction", [r.to_dict()["ranking"][:3] for r in result.rounds]
    mu = result.parameters()["effects.tendon_friction_coeff"]
    assert abs(mu["value"] - 0.15) < 0.02
    # The twin's friction is the predictor's at the joints (half a joint's turn either side): μ
    # within its honest interval, not 10-13 % high outside it.
    assert mu["ci95"][0] < 0.15 < mu["ci95"][1], mu
    assert result.rms_after_m < 0.5 * result.rms_before_m
    # The thesis's y pattern (Fig. 20): e_y a sine over the bending plane, most of a millimetre,
    # and gone once friction is added. Its sign follows the tendons' last sliding direction: the
    # thesis's controller settled by backing off (an inverted sine); the firmware ramps length
    # setpoints, so the twin's tendons arrive without backing off and the sine is upright. Its z
    # pattern (always positive) is not what the twin's friction gives (z errors of both signs, the
    # largest negative), so it is not asserted.
    before = result.residuals.signature()
    after = find_discrepancy(result.dataset, result.params_after).signature()
    assert abs(before["corr_y_minus_sin_phi"]) > 0.5
    assert abs(before["y_sine_amplitude_m"]) > 5e-4
    assert abs(after["y_sine_amplitude_m"]) < 0.3 * abs(before["y_sine_amplitude_m"])


@pytest.mark.slow
def test_friction_whose_tendons_last_backed_off_is_named_alone_within_its_interval(tmp_path):
    """Every configuration approached from the other side (each tendon past its setpoint by a
    third of its move, then back): each tendon's last motion is against its move, so its sliding
    state is the reverse of a direct approach's, and friction alone still explains the data — no
    load-cell offset added beside it."""
    truth = MODEL.replace({"effects.tendon_friction_coeff": 0.2}, source="hidden")
    with open_device("sim://?seed=11", params=truth) as device:
        cal = nominal_calibration(MODEL)
        device.set_calibration(gain_counts_per_n=cal["gain_counts_per_n"], offset_counts=cal["offset_counts"])
        run_validation(device, tmp_path, MODEL, grid=GRID, progress=False, overshoot=0.3)
    data = read_dataset(tmp_path)
    result = run_discrepancy(data)
    assert result.verdict == "effect" and result.named == ("tendon_friction",), result.statement()
    mu = result.parameters()["effects.tendon_friction_coeff"]
    assert mu["ci95"][0] < 0.2 < mu["ci95"][1] and mu["ci95"][1] - mu["ci95"][0] < 0.03, mu
