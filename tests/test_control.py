"""Load compensation, the length-vs-tension study and the tuning example, on the predictor and the twin."""

import numpy as np
import pytest

from twin import load_params
from twin.robots import load_robot
from twin.control.cocontraction import run_cocontraction_study
from twin.control.compensation import (MIN_RESPONSE_GAIN, compensate_tensions, correct_tensions, hold_tensions,
                                       response_gain)
from twin.control.compensation_trial import (GOAL_REDUCTION_PCT, CompensationTrial, _correction, _Miss,
                                             compensation_grid,
                                             resolvably_larger, run_compensation_trial, swing_limit_n,
                                             tension_ceiling_n, within_reach)
from twin.control import compensation_trial
from twin.control.gains import DEFAULT_TENSION_GAINS, PROPORTIONAL_LOOP_GAIN, TUNED_TENSION_GAINS, tension_gains_for
from twin.tuning import tension_cost
from twin.driver import open_device
from twin.experiments.protocols import NotAtRestError
from twin.pose import HORIZONTAL
from twin.rod import RodModel, solve
from twin.pcc import validation_grid

PARAMS = load_params()
MODEL = RodModel.from_params(PARAMS)
WEIGHT_10G = np.array([0.0, 0.0, -0.010 * PARAMS.environment.gravity_m_s2])


def test_compensated_tensions_put_the_predicted_loaded_tip_on_target():
    target = solve(MODEL, [2.0, 1.35, 1.0, 1.35], base_rotation=HORIZONTAL).tip_position_m
    plan = compensate_tensions(MODEL, target, tip_force_n=WEIGHT_10G, base_rotation=HORIZONTAL,
                               reference_tensions_n=[2.0, 1.35, 1.0, 1.35], floor_n=0.5, limit_n=5.0)
    loaded = solve(MODEL, plan.tensions_n, tip_force_n=WEIGHT_10G, base_rotation=HORIZONTAL).tip_position_m
    assert plan.reached and np.linalg.norm(loaded - target) < 1e-4
    assert np.all(plan.tensions_n >= 0.5) and np.all(plan.tensions_n <= 5.0)
    # Uncompensated, the same 10 g moves the predicted tip by millimetres.
    sagged = solve(MODEL, [2.0, 1.35, 1.0, 1.35], tip_force_n=WEIGHT_10G, base_rotation=HORIZONTAL).tip_position_m
    assert np.linalg.norm(sagged - target) > 2e-3


def test_an_unreachable_target_is_reported_not_hidden():
    plan = compensate_tensions(MODEL, [0.0, 0.0, 0.1], base_rotation=HORIZONTAL, floor_n=0.5, limit_n=2.0)
    assert not plan.reached and plan.residual_m > 0.01 and plan.at_bounds.any()
    with pytest.raises(ValueError, match="floor_n = 3"):
        compensate_tensions(MODEL, [0.06, 0, 0], floor_n=3.0, limit_n=2.0)


def test_hold_tensions_without_a_load_keeps_tensions_already_within_bounds():
    plan = hold_tensions(MODEL, [2.0, 1.35, 1.2, 1.35], np.zeros(3), base_rotation=HORIZONTAL, floor_n=1.0)
    np.testing.assert_allclose(plan.tensions_n, [2.0, 1.35, 1.2, 1.35], atol=0.02)


def test_a_correction_removes_a_load_error_the_feedforward_did_not_know():
    # The "device" is the predictor itself with 10 % more tip load than the plan compensated.
    unloaded = [2.0, 1.35, 1.0, 1.35]
    bounds = dict(base_rotation=HORIZONTAL, floor_n=0.3, limit_n=5.0)
    plan = hold_tensions(MODEL, unloaded, WEIGHT_10G, **bounds)

    def miss(tensions):
        return solve(MODEL, tensions, tip_force_n=1.1 * WEIGHT_10G, base_rotation=HORIZONTAL).tip_position_m - plan.target_m

    first = correct_tensions(MODEL, plan, plan.target_m, miss(plan.tensions_n), tip_force_n=WEIGHT_10G, **bounds)
    second = correct_tensions(MODEL, first, plan.target_m, miss(first.tensions_n), tip_force_n=WEIGHT_10G, **bounds)
    before, after = np.linalg.norm(miss(plan.tensions_n)), np.linalg.norm(miss(first.tensions_n))
    assert before > 5e-4 and after < 0.2 * before
    assert np.linalg.norm(miss(second.tensions_n)) <= after + 1e-6
    assert np.all(first.tensions_n >= 0.3) and np.all(first.tensions_n <= 5.0)


def test_a_correction_in_the_measured_sliding_state_lands_where_the_friction_model_says():
    # The "device" is a predictor with tendon friction whose loop left two tendons paid out (σ = −1)
    # where the plan assumed every tendon pulled: told σ, the correction takes that for no model error.
    model = RodModel.from_params(PARAMS.replace({"effects.tendon_friction_coeff": 0.3}))
    bounds = dict(base_rotation=HORIZONTAL, floor_n=0.3, limit_n=5.0)
    plan = hold_tensions(model, [2.0, 1.35, 1.0, 1.35], WEIGHT_10G, **bounds)
    flipped = np.array([1.0, -1.0, -1.0, 1.0])

    def miss(tensions):
        return solve(model, tensions, tip_force_n=WEIGHT_10G, base_rotation=HORIZONTAL,
                     friction_direction=flipped).tip_position_m - plan.target_m

    told = correct_tensions(model, plan, plan.target_m, miss(plan.tensions_n), tip_force_n=WEIGHT_10G,
                            friction_direction=flipped, **bounds)
    blind = correct_tensions(model, plan, plan.target_m, miss(plan.tensions_n), tip_force_n=WEIGHT_10G, **bounds)
    assert np.linalg.norm(miss(plan.tensions_n)) > 2e-3
    # Told σ, the device misses by just what the predictor expects (its pull towards the applied tensions).
    assert abs(np.linalg.norm(miss(told.tensions_n)) - told.residual_m) < 1e-6
    assert np.linalg.norm(miss(told.tensions_n)) < 0.5 * np.linalg.norm(miss(blind.tensions_n))


def test_a_miss_the_predictor_expected_is_not_corrected():
    # Out of reach within the bounds: the tracker seeing exactly the predicted miss is no model error.
    goal = solve(MODEL, [0.0, 0.0, 3.0, 0.0], base_rotation=HORIZONTAL).tip_position_m
    bounds = dict(base_rotation=HORIZONTAL, floor_n=0.5, limit_n=2.0)
    plan = compensate_tensions(MODEL, goal, tip_force_n=WEIGHT_10G, **bounds)
    assert not plan.reached
    again = correct_tensions(MODEL, plan, goal, plan.predicted_tip_m - goal, tip_force_n=WEIGHT_10G, **bounds)
    np.testing.assert_allclose(again.tensions_n, plan.tensions_n, atol=2e-3)
    # Nor is it taken over a device's share of the predicted moves: only the unexpected part is.
    halved = correct_tensions(MODEL, plan, goal, plan.predicted_tip_m - goal, tip_force_n=WEIGHT_10G,
                              response_gain=0.5, **bounds)
    np.testing.assert_allclose(halved.tensions_n, plan.tensions_n, atol=2e-3)


def test_the_response_gain_is_the_share_of_the_predicted_move_made_along_it():
    assert response_gain([1e-3, 0, 0], [0.7e-3, 0.2e-3, 0], noise_m=1e-5) == pytest.approx(0.7)
    # Bounded: at most the whole move, and at least the share that keeps every step a contraction.
    assert response_gain([1e-3, 0, 0], [1.5e-3, 0, 0], noise_m=1e-5) == 1.0
    assert response_gain([1e-3, 0, 0], [0.2e-3, 0, 0], noise_m=1e-5) == MIN_RESPONSE_GAIN
    assert response_gain([1e-3, 0, 0], [-1e-3, 0, 0], noise_m=1e-5) == MIN_RESPONSE_GAIN
    # A predicted move within a few noise levels tells nothing.
    assert response_gain([1e-4, 0, 0], [0.5e-4, 0, 0], noise_m=5e-5) is None
    with pytest.raises(ValueError, match="response_gain"):
        correct_tensions(MODEL, hold_tensions(MODEL, [2.0, 1.35, 1.0, 1.35], WEIGHT_10G, base_rotation=HORIZONTAL),
                         np.zeros(3), np.zeros(3), response_gain=0.0)


def test_a_correction_over_the_share_the_device_made_lands_where_a_full_step_falls_short():
    # The "device" is the predictor under 10 % more load than planned whose tip makes half of each
    # move the tension changes ask for, as a tendon friction the model lacks holds the rest back.
    bounds = dict(base_rotation=HORIZONTAL, floor_n=0.3, limit_n=5.0)
    plan = hold_tensions(MODEL, [2.0, 1.35, 1.0, 1.35], WEIGHT_10G, **bounds)

    def loaded(tensions):
        return solve(MODEL, tensions, tip_force_n=1.1 * WEIGHT_10G, base_rotation=HORIZONTAL).tip_position_m

    start = loaded(plan.tensions_n)

    def miss(tensions):
        return start + 0.5 * (loaded(tensions) - start) - plan.target_m

    first = correct_tensions(MODEL, plan, plan.target_m, miss(plan.tensions_n), tip_force_n=WEIGHT_10G, **bounds)
    share = response_gain(first.predicted_tip_m - plan.predicted_tip_m, miss(first.tensions_n) - miss(plan.tensions_n),
                          noise_m=1e-6)
    assert share == pytest.approx(0.5, abs=0.05)
    full = correct_tensions(MODEL, first, plan.target_m, miss(first.tensions_n), tip_force_n=WEIGHT_10G, **bounds)
    scaled = correct_tensions(MODEL, first, plan.target_m, miss(first.tensions_n), tip_force_n=WEIGHT_10G,
                              response_gain=share, **bounds)
    assert np.linalg.norm(miss(full.tensions_n)) > 0.2 * np.linalg.norm(miss(plan.tensions_n))
    assert np.linalg.norm(miss(scaled.tensions_n)) < 0.25 * np.linalg.norm(miss(full.tensions_n))


def test_a_trial_correction_is_taken_over_the_share_only_beyond_the_noise_and_short_of_the_ceiling():
    bounds = dict(base_rotation=HORIZONTAL, floor_n=0.3, limit_n=5.0)
    plan = hold_tensions(MODEL, [2.0, 1.35, 1.0, 1.35], WEIGHT_10G, **bounds)
    # A device whose load is 30 % lighter than planned: the correction pulls tendon 1, the highest, harder.
    vector = solve(MODEL, plan.tensions_n, tip_force_n=0.7 * WEIGHT_10G, base_rotation=HORIZONTAL).tip_position_m \
        - plan.target_m
    size_mm = float(np.linalg.norm(vector)) * 1e3

    def corrected(sem_mm, gain, limit_n=5.0):
        return _correction(MODEL, plan, plan.target_m, _Miss(vector, size_mm, sem_mm), WEIGHT_10G,
                           dict(bounds, limit_n=limit_n), gain).tensions_n

    full = correct_tensions(MODEL, plan, plan.target_m, vector, tip_force_n=WEIGHT_10G, **bounds)
    over = correct_tensions(MODEL, plan, plan.target_m, vector, tip_force_n=WEIGHT_10G, response_gain=0.5, **bounds)
    assert np.abs(over.tensions_n - full.tensions_n).max() > 0.01
    np.testing.assert_allclose(corrected(0.01 * size_mm, 0.5), over.tensions_n, atol=1e-9)
    # The same miss within four standard errors: a full-share step.
    np.testing.assert_allclose(corrected(0.5 * size_mm, 0.5), full.tensions_n, atol=1e-9)
    # A ceiling the full step stays under but the step over the share would reach: the full step.
    ceiling = float(full.tensions_n.max()) + 0.002
    assert over.tensions_n.max() > ceiling
    capped = correct_tensions(MODEL, plan, plan.target_m, vector, tip_force_n=WEIGHT_10G, **dict(bounds, limit_n=ceiling))
    assert not capped.at_bounds[capped.tensions_n > 2.0].any()
    np.testing.assert_allclose(corrected(0.01 * size_mm, 0.5, ceiling), capped.tensions_n, atol=1e-9)


def test_the_tension_ceiling_is_what_the_clamped_loop_can_hold():
    # 0.035 duty of the 153.8 N stall force is 5.38 N; the ceiling keeps 5 % of it in hand.
    assert tension_ceiling_n(PARAMS, TUNED_TENSION_GAINS) == pytest.approx(0.95 * 0.035 * 0.5 / 0.00325)
    assert tension_ceiling_n(PARAMS, {"output_limit": 1.0}) == PARAMS.rig.tension_limit_n - 0.5


@pytest.fixture(scope="module")
def twin():
    with open_device("sim://?seed=4", params=PARAMS) as device:
        yield device


def test_compensation_on_the_twin_misses_by_little_more_than_the_predictor_expects():
    # κ 26.2 φ 0 is the hard one: a slack tendon to take up, and tensions at the ceiling under 10 g
    # (it tripped the 6 N limit with a 1 N floor and stepped setpoints). A twin of its own: the
    # trial's minute of twin time would change the noise the co-contraction test below sees.
    with open_device("sim://?seed=4", params=PARAMS) as device:
        trial = run_compensation_trial(device, PARAMS, configs=[(13.0, 90.0), (26.2, 0.0)])
    assert trial.summary()["all"]["faulted"] == 0 and len(trial.rows) == 4
    ceiling = tension_ceiling_n(PARAMS, TUNED_TENSION_GAINS)
    for row in trial.rows:
        assert row["uncompensated_mm"] > 0.5
        # What the device adds to the predictor's own miss (settling, tension tracking, tracker
        # noise on both means) is a fraction of a tenth of a millimetre.
        assert row["feedforward_mm"] < row["model_residual_mm"] + 0.1
        assert row["corrected_mm"] < row["model_residual_mm"] + 0.1
        if row["reached"]:
            assert row["feedforward_reduction_pct"] >= GOAL_REDUCTION_PCT
            assert row["corrected_reduction_pct"] >= GOAL_REDUCTION_PCT
        # Tensions are reported to 0.1 mN.
        assert max(row["tensions_n"]) <= ceiling + 1e-4 and min(row["tensions_n"]) >= trial.floor_n - 1e-4


def test_tracker_corrections_remove_a_load_cell_error_the_feedforward_cannot_see():
    # Load cells 5 % off, alternately high and low: the board holds the wrong tensions and the
    # predictor does not know it. Only the tracker does.
    hidden = PARAMS.replace({"effects.tension_gain_error": [0.05, -0.05, 0.05, -0.05]})
    with open_device("sim://?seed=4", params=hidden) as device:
        trial = run_compensation_trial(device, PARAMS, configs=[(13.0, 90.0)], masses_kg=(0.010,))
    (row,) = trial.rows
    assert not row["fault"] and row["corrections"] >= 1
    assert row["feedforward_mm"] > row["model_residual_mm"] + 0.2
    assert row["corrected_mm"] < 0.5 * row["feedforward_mm"]
    assert row["corrected_reduction_pct"] >= GOAL_REDUCTION_PCT


@pytest.mark.parametrize("mu", [0.1, 0.3])
def test_compensation_reaches_the_goal_under_a_tendon_friction_the_model_does_not_know(mu):
    # Friction hidden on the twin: in tension mode the loop swung by newtons while the friction
    # held the tip still, and the tension criterion of rest faulted every row. The tip is at
    # rest, and the tracker corrections remove what the frictionless model gets wrong.
    hidden = PARAMS.replace({"effects.tendon_friction_coeff": mu})
    with open_device("sim://?seed=4", params=hidden) as device:
        trial = run_compensation_trial(device, PARAMS, configs=[(8.7, 0.0)], masses_kg=(0.010,))
    (row,) = trial.rows
    assert not row["fault"] and not trial.left_out
    assert row["corrected_reduction_pct"] >= GOAL_REDUCTION_PCT
    assert trial.verdict() == (True, [])


def test_where_friction_holds_the_loaded_tip_closer_than_tension_mode_the_trial_keeps_the_pcc_lengths():
    # κ 26.2 φ 0 under 10 g at a hidden μ = 0.1: the friction holds the tip in length mode a
    # tenth of a millimetre from the target, and the tension loop leaves it ~0.25 mm off after
    # four corrections. The trial goes back to the best command it measured and measures it again.
    hidden = PARAMS.replace({"effects.tendon_friction_coeff": 0.1})
    with open_device("sim://?seed=0", params=hidden) as device:
        trial = run_compensation_trial(device, PARAMS, configs=[(26.2, 0.0)])
    heavy = trial.rows[-1]
    assert heavy["mass_g"] == 10.0 and not heavy["fault"] and heavy["uncompensated_mm"] < 0.2
    assert heavy["kept"] == "PCC lengths"
    # Measured afresh, not the reading it was picked by; as close as the tracker can tell.
    assert not resolvably_larger(heavy["corrected_mm"], heavy["corrected_sem_mm"], heavy["uncompensated_mm"],
                                 heavy["uncompensated_sem_mm"])
    assert trial.worse_rows() == []
    for row in trial.rows:
        assert 0.01 < row["uncompensated_sem_mm"] < 0.1 and 0.01 < row["corrected_sem_mm"] < 0.1


def test_a_tension_command_the_loop_swings_under_is_neither_corrected_nor_kept(monkeypatch):
    # Every reading above zero counts as a swing here: the feed-forward is then a command the
    # loop does not hold, so no correction follows it and the row ends back at the PCC lengths,
    # measured afresh. The threshold itself sits over the ceiling, under the board's limit.
    ceiling = tension_ceiling_n(PARAMS, TUNED_TENSION_GAINS)
    assert ceiling < swing_limit_n(PARAMS, ceiling) < PARAMS.rig.tension_limit_n
    monkeypatch.setattr(compensation_trial, "swing_limit_n", lambda params, limit_n: 0.0)
    with open_device("sim://?seed=4") as device:
        trial = run_compensation_trial(device, PARAMS, configs=[(13.0, 90.0)], masses_kg=(0.010,))
    (row,) = trial.rows
    assert not row["fault"] and row["swung"] and row["peak_tension_n"] > 0.0
    assert row["corrections"] == 0 and row["kept"] == "PCC lengths"
    assert np.isfinite(row["feedforward_mm"]) and np.isfinite(row["corrected_mm"])


@pytest.mark.parametrize("moving", ["feed-forward", "correction"])
def test_a_tension_command_the_tip_does_not_rest_under_ends_the_corrections_not_the_row(monkeypatch, moving):
    # The wait for rest of the feed-forward (the third of the configuration: target, loaded,
    # feed-forward) or of the first correction times out: the row goes on without that command,
    # as after a swing, instead of faulting.
    waits = []
    settle = compensation_trial._wait_for_tip_rest

    def wait(device, timeout_s):
        waits.append(timeout_s)
        if len(waits) == {"feed-forward": 3, "correction": 4}[moving]:
            raise NotAtRestError("the robot did not come to rest")
        settle(device, timeout_s)

    monkeypatch.setattr(compensation_trial, "_wait_for_tip_rest", wait)
    hidden = PARAMS.replace({"effects.tendon_friction_coeff": 0.1})
    with open_device("sim://?seed=4", params=hidden) as device:
        trial = run_compensation_trial(device, PARAMS, configs=[(8.7, 0.0)], masses_kg=(0.010,))
    (row,) = trial.rows
    assert not row["fault"] and row["unsettled"] and not row["swung"]
    assert row["corrections"] == {"feed-forward": 0, "correction": 1}[moving]
    # Never kept: the row ends on a command measured at rest, measured afresh.
    assert row["kept"] == ("PCC lengths" if moving == "feed-forward" else "feed-forward")
    assert np.isfinite(row["feedforward_mm"]) and np.isfinite(row["corrected_mm"])
    assert len(waits) == {"feed-forward": 4, "correction": 5}[moving]


def test_a_rest_is_left_as_soon_as_the_tension_loop_swings():
    class Clock:
        def __init__(self):
            self.waited_s = 0.0

        def wait(self, duration_s):
            self.waited_s += duration_s

    clock = Clock()
    assert compensation_trial._rest(clock, 2.5, swinging=lambda: False)
    assert clock.waited_s == pytest.approx(2.5)
    clock = Clock()
    assert not compensation_trial._rest(clock, 2.5, swinging=lambda: clock.waited_s > 0.6)
    assert 0.6 < clock.waited_s <= 0.6 + compensation_trial._SWING_CHECK_S


def test_a_row_is_worse_only_by_more_than_the_tracker_can_tell():
    # Two standard errors of the difference: 0.045 mm each puts the line at 0.127 mm.
    assert not resolvably_larger(0.20, 0.045, 0.08, 0.045)
    assert resolvably_larger(0.26, 0.045, 0.06, 0.045)
    # Without standard errors every excess counts.
    assert resolvably_larger(0.061, float("nan"), 0.06, float("nan"))
    row = {"kappa_per_m": 26.2, "phi_deg": 0.0, "mass_g": 10.0, "uncompensated_mm": 0.06, "feedforward_mm": 0.5,
           "corrected_mm": 0.10, "feedforward_reduction_pct": -733.0, "corrected_reduction_pct": -66.7, "fault": "",
           "uncompensated_sem_mm": 0.045, "corrected_sem_mm": 0.045}
    far = dict(row, corrected_mm=0.26, corrected_reduction_pct=-333.0)
    assert CompensationTrial(rows=[row], device="sim://", floor_n=0.3, limit_n=5.0, corrections=4,
                             timing_s={}).worse_rows() == []
    trial = CompensationTrial(rows=[far], device="sim://", floor_n=0.3, limit_n=5.0, corrections=4, timing_s={})
    met, problems = trial.verdict()
    assert not met and trial.worse_rows() == [far]
    assert any("WORSE" in p and "standard errors 0.045 / 0.045 mm" in p for p in problems)


def test_a_high_curvature_bend_rests_in_tension_mode_under_strong_hidden_friction():
    # κ 17.5 φ 0 is one of the bends where the compensation faulted at μ = 0.3: the friction's
    # sliding state, following the spool through a lag, cycled with the tension loop at ~11 Hz.
    hidden = PARAMS.replace({"effects.tendon_friction_coeff": 0.3})
    with open_device("sim://?seed=0", params=hidden) as device:
        trial = run_compensation_trial(device, PARAMS, configs=[(17.5, 0.0)], masses_kg=(0.005,))
    (row,) = trial.rows
    assert not row["fault"], row["fault"]


STIFF = load_robot("stiff-long")


def test_other_motors_get_gains_asking_the_same_pull_per_newton():
    # Twice the stall torque: a duty pulls twice as hard, so the gains halve and the clamp too
    # (the clamped pull stays 0.9 of the limit).
    strong = PARAMS.replace({"rig.motor_stall_torque_nm": 2 * PARAMS.rig.motor_stall_torque_nm})
    mine, theirs = tension_gains_for(PARAMS), tension_gains_for(strong)
    for key in ("kp", "ki", "output_limit"):
        assert theirs[key] == pytest.approx(mine[key] / 2), key
    # The tuned rig keeps its tuned integral and clamp; its kp is the friction-safe loop gain per
    # newton of its stall pull, not the tuned one that rang on a stuck tendon.
    assert {k: mine[k] for k in ("ki", "kd", "output_limit")} == pytest.approx(
        {k: TUNED_TENSION_GAINS[k] for k in ("ki", "kd", "output_limit")})
    assert mine["kp"] * PARAMS.rig.motor_stall_force_n == pytest.approx(PROPORTIONAL_LOOP_GAIN)


def test_a_stiff_robot_gets_a_grid_and_a_ceiling_its_tensions_can_hold():
    gains = tension_gains_for(STIFF)
    ceiling = tension_ceiling_n(STIFF, gains)
    # The endoscope keeps the tuned clamp and the thesis grid; the 30 N rig may pull ~25 N.
    assert tension_gains_for(PARAMS)["output_limit"] == pytest.approx(TUNED_TENSION_GAINS["output_limit"])
    assert compensation_grid(PARAMS, tension_ceiling_n(PARAMS, TUNED_TENSION_GAINS)) == compensation_grid(
        PARAMS, 1e3)
    assert 20.0 < ceiling < STIFF.rig.tension_limit_n
    grid = compensation_grid(STIFF, ceiling)
    kept, left_out = within_reach(STIFF, grid, limit_n=ceiling)
    # Bent by the thesis's angles at its length, as the validation grid is (not by the 60 mm endoscope's κ).
    assert len(kept) == 60 and not left_out
    assert {k for k, _ in grid} == {row[1] for row in validation_grid(STIFF)} - {0.0}
    # The thesis's curvatures need several times the ceiling of the tuned clamp: each is named.
    kept, left_out = within_reach(STIFF, [(26.2, 0.0), (4.5, 90.0)], limit_n=5.0)
    assert not kept and all("above the 5.00 N ceiling" in item["reason"] for item in left_out)


def test_compensation_on_a_stiff_robot_is_no_worse_than_on_the_endoscope():
    # Before, the 5.1 N ceiling of the endoscope's clamp let the tip end 17-290x worse than uncompensated.
    with open_device("sim://?seed=4", params=STIFF) as device:
        grid = compensation_grid(STIFF, tension_ceiling_n(STIFF, tension_gains_for(STIFF)))
        trial = run_compensation_trial(device, STIFF, configs=[grid[-1]], masses_kg=(0.010,))
    (row,) = trial.rows
    assert not row["fault"] and row["uncompensated_mm"] > 3.0
    assert row["corrected_reduction_pct"] >= GOAL_REDUCTION_PCT
    assert max(row["tensions_n"]) > 6.0


def test_a_load_the_bounds_cannot_hold_is_left_out_and_named_not_run():
    # 1.2–1.95 N cannot bend the endoscope up against 5 g at κ 4.5 (the PCC pull is 1.9 N).
    with open_device("sim://?seed=4", params=PARAMS) as device:
        trial = run_compensation_trial(device, PARAMS, configs=[(4.5, 180.0)], masses_kg=(0.005,), floor_n=1.2,
                                       limit_n=1.95)
    assert trial.rows == [] and len(trial.left_out) == 1
    assert trial.left_out[0]["mass_g"] == 5.0 and "sag" in trial.left_out[0]["reason"]
    assert trial.verdict() == (False, ["no row ran to the end"])


def test_a_compensation_worse_than_none_is_never_an_ordinary_result():
    row = {"kappa_per_m": 8.7, "phi_deg": 0.0, "mass_g": 10.0, "uncompensated_mm": 1.8, "feedforward_mm": 30.7,
           "corrected_mm": 27.9, "feedforward_reduction_pct": -1600.0, "corrected_reduction_pct": -1450.0,
           "fault": ""}
    good = dict(row, feedforward_mm=0.1, corrected_mm=0.1, feedforward_reduction_pct=94.4,
                corrected_reduction_pct=94.4)
    trial = CompensationTrial(rows=[good, good, row], device="sim://", floor_n=0.3, limit_n=5.0, corrections=2,
                              timing_s={})
    met, problems = trial.verdict()
    assert not met and trial.worse_rows() == [row]
    assert any("WORSE" in p and "27.90" in p for p in problems)
    # The median (94.4 %) alone would have passed.
    assert trial.summary()["all"]["corrected_median_reduction_pct"] >= GOAL_REDUCTION_PCT


def test_length_control_lets_the_pair_fight_tension_control_holds_it(twin):
    # The whole study, as `twin cocontraction` runs it: at 20 counts after the five bends the two
    # length loops hunt against each other, and settling to the default 0.01 N never ended.
    study = run_cocontraction_study(twin, PARAMS)
    lengths, tensions = study.summary()["lengths"], study.summary()["tensions"]
    # 40 encoder counts (38 µm) of common pair shortening: the antagonists fight.
    assert lengths["max_cocontraction_with_mismatch_n"] > 0.3 and lengths["pair_sum_rise_at_largest_offset_n"] > 0.5
    # Hanging 10 g shifts the held pair's tensions in length mode; tension mode keeps its setpoints.
    assert lengths["pair_tension_change_under_10g_n"] > 0.1
    assert tensions["pair_tension_change_under_10g_n"] < 0.03


def test_tuned_tension_gains_beat_the_firmware_defaults_on_the_step_rollout():
    assert tension_cost(TUNED_TENSION_GAINS) < tension_cost(DEFAULT_TENSION_GAINS)


def test_tip_tracker_integral_action_removes_a_model_error_feedforward_keeps():
    """The tracking controller on a stand-in plant: the predictor with tendon 1's load cell 8% off.
    Feed-forward alone (gain 0) keeps the miss; the Jacobian integral action removes most of it."""
    from twin.tuning import TipTrackingController
    from twin.pcc import arc_tip_position_m
    from twin.rod.grid import GRAVITY_TIP_FORCE_N

    target = HORIZONTAL @ arc_tip_position_m(10.0, 30.0, PARAMS.backbone.length_m)
    force = GRAVITY_TIP_FORCE_N(0.005, PARAMS.environment.gravity_m_s2)

    def plant_tip(tensions):
        actual = np.asarray(tensions) * np.array([0.92, 1.0, 1.0, 1.0])
        return solve(MODEL, actual, tip_force_n=force, base_rotation=HORIZONTAL).tip_position_m

    misses = {}
    for gain in (0.0, 0.3):
        tracker = TipTrackingController(PARAMS, gain=gain)
        tensions = tracker.reset(target, 0.005)
        for _ in range(15):
            tensions = tracker.update(plant_tip(tensions))
        misses[gain] = np.linalg.norm(plant_tip(tensions) - target)
    assert misses[0.0] > 3e-4
    assert misses[0.3] < 0.2 * misses[0.0]


def test_swing_damping_lets_the_integral_hold_the_tip_on_a_twin_unlike_the_model():
    """On a twin with the spreads of a real rig (stiffness, weight, load-cell errors, latency),
    feed-forward alone misses by millimetres; the integral alone leaves the tip swinging in
    tension mode, still a millimetre off; with the swing damped the integral holds the tip within
    half a millimetre."""
    from twin.tuning import tracking_cost

    def cost(gain, velocity_gain_s):
        return tracking_cost({"gain": gain, "velocity_gain_s": velocity_gain_s}, seeds=(1,))

    feedforward, integral, damped = cost(0.0, 0.0), cost(0.03, 0.0), cost(0.03, 0.15)
    assert feedforward > 1.0
    assert integral > 1.0
    assert damped < 0.3 * feedforward and damped < 0.5 * integral


def test_the_tracking_stage_retunes_the_tension_integral_the_step_rollout_starves():
    """The PID stage's step rollout picks a slow tension integral (ki ~0.05); under the tip tracker
    that costs millimetres, so the tracking stage tunes ki alongside its own two gains."""
    from twin.tuning import tracking_cost, tune_tracking_gains

    tracker = {"gain": 0.0165, "velocity_gain_s": 0.16}
    slow = dict(TUNED_TENSION_GAINS, kp=0.0077, output_limit=0.030, ki=0.045)  # what `twin tune --quick` finds
    faster = dict(slow, ki=0.15)
    assert tracking_cost(tracker, tension_gains=faster, seeds=(2, 3)) < 0.5 * tracking_cost(tracker, tension_gains=slow,
                                                                                          seeds=(2, 3))
    result = tune_tracking_gains(tension_gains=slow, evaluations=6, seeds=(1,))
    assert set(result.after) == {"gain", "velocity_gain_s", "tension_ki"}
    assert result.after["tension_ki"] > slow["ki"]
    assert result.cost_after < 0.5 * result.cost_before


@pytest.mark.parametrize("friction", [0.0, 0.3])
def test_the_target_and_sags_of_one_batch_are_the_separate_solves(friction):
    from twin.control.compensation import unloaded_tips
    from twin.rod.grid import GRAVITY_TIP_FORCE_N, pcc_tensions_n

    model = RodModel.from_params(PARAMS.replace({"effects.tendon_friction_coeff": friction}))
    tensions = pcc_tensions_n(13.0, 60.0, PARAMS)
    loads = [GRAVITY_TIP_FORCE_N(m, 9.81) for m in (0.005, 0.010)]
    sigma = np.array([1.0, -1.0, 0.5, 1.0]) if friction else None
    target, sags = unloaded_tips(model, tensions, loads, base_rotation=HORIZONTAL, unloaded_friction_direction=sigma)
    alone = solve(model, tensions, base_rotation=HORIZONTAL, friction_direction=sigma).tip_position_m
    free = solve(model, tensions, base_rotation=HORIZONTAL).tip_position_m
    assert np.allclose(target, alone, atol=1e-9)
    for load, sag in zip(loads, sags):
        loaded = solve(model, tensions, tip_force_n=load, base_rotation=HORIZONTAL).tip_position_m
        assert sag == pytest.approx(np.linalg.norm(loaded - free), abs=1e-9)
    assert 0 < sags[0] < sags[1]
    # The plan aimed at the batch's target is the plan that solves its own.
    own = hold_tensions(model, tensions, loads[1], base_rotation=HORIZONTAL, unloaded_friction_direction=sigma)
    given = hold_tensions(model, tensions, loads[1], base_rotation=HORIZONTAL, unloaded_friction_direction=sigma,
                          target_m=target)
    assert np.allclose(own.tensions_n, given.tensions_n, atol=1e-6)


def test_an_unknown_load_and_an_untold_sideways_push_are_compensated_from_the_tip_force_estimate():
    # Nothing is told but which rows to run: the feed-forward plans for the force the estimate
    # finds in the loaded, uncompensated tip (weight and a 50 mN sideways push), not the mass's weight.
    with open_device("sim://?seed=4", params=PARAMS) as device:
        unknown = run_compensation_trial(device, PARAMS, configs=[(13.0, 90.0)], unknown_load=True,
                                         side_force_n=0.05, corrections=0)
        told = run_compensation_trial(device, PARAMS, configs=[(13.0, 90.0)], side_force_n=0.05, corrections=0)
    assert [r["load"] for r in unknown.rows] == ["estimated", "estimated"] and not unknown.left_out
    for row, known in zip(unknown.rows, told.rows):
        assert not row["fault"] and not known["fault"]
        weight = row["mass_g"] * 1e-3 * PARAMS.environment.gravity_m_s2
        truth = np.array([0.0, 0.0, -weight]) + np.array(row["side_force_n"])
        assert np.linalg.norm(row["side_force_n"]) == pytest.approx(0.05)
        # Across the clamp's axis (world y, z with the horizontal clamp) the estimate finds the load.
        assert np.linalg.norm(np.array(row["estimated_force_n"])[1:] - truth[1:]) < 0.02
        assert row["feedforward_reduction_pct"] >= GOAL_REDUCTION_PCT
        # Told only the mass, the feed-forward misses the push it was not told about.
        assert known["feedforward_mm"] > 3 * row["feedforward_mm"]
