"""The controllers, the env and friction on robots other than the thesis endoscope: any tendon
count, any antagonistic pair, multi-segment robots."""

import numpy as np
import pytest

from twin.envs import EndoscopeReachEnv, TipLoads
from twin.envs.reach import default_curvature_range_per_m, default_max_length_m, default_tension_range_n
from twin.cli import main
from twin.control.cocontraction import antagonistic_pair, run_cocontraction_study
from twin.driver import open_device
from twin.robots import load_robot
from twin.tuning import TipTrackingController, tension_steps_n


@pytest.mark.parametrize("robot, pair", [("endoscope", (0, 2)), ("three-tendon", (0, 1)), ("two-segment", (0, 1)),
                                         ("long", (0, 2))])
def test_the_default_pair_is_the_two_tendons_furthest_apart_on_the_same_disc(robot, pair):
    params = load_robot(robot)
    assert antagonistic_pair(params) == pair
    steps = tension_steps_n(params)
    assert steps.shape == (6, params.tendons.count)
    # Only the pair steps; the others hold the pretension.
    others = [k for k in range(params.tendons.count) if k not in pair]
    assert np.allclose(steps[:, others], params.tendons.pretension_n)
    assert np.ptp(steps[:, pair[0]]) > 1.0 and np.ptp(steps[:, pair[1]]) > 1.0


def test_a_pair_that_does_not_oppose_is_refused_naming_it():
    params = load_robot("two-segment")  # 0, 120, 240° to the middle disc; 60, 180, 300° to the tip
    assert antagonistic_pair(params, (3, 4)) == (3, 4)  # 60° and 180°, both to the tip
    with pytest.raises(ValueError, match=r"pair = 1,4: .*same disc"):
        antagonistic_pair(params, (0, 3))  # 0° to the middle, 60° to the tip
    with pytest.raises(ValueError, match=r"pair = 1,7"):
        antagonistic_pair(params, (0, 6))
    endoscope = load_robot("endoscope")
    with pytest.raises(ValueError, match=r"pair = 1,2: .*more than 90 deg"):
        antagonistic_pair(endoscope, (0, 1))


def test_cocontraction_refuses_a_bad_pair_in_one_line(capsys):
    assert main(["cocontraction", "--pair", "1,2"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("twin cocontraction: --pair 1,2:") and "\n" not in err
    assert main(["cocontraction", "--pair", "one"]) == 2
    assert "--pair one: expected two tendon numbers" in capsys.readouterr().err


def test_cocontraction_runs_on_a_three_tendon_robot_with_its_own_pair():
    params = load_robot("three-tendon")
    with open_device("sim://?seed=1", params=params) as device:
        study = run_cocontraction_study(device, params, kappas_per_m=(10.0,), offsets_counts=(0, 40))
    s = study.summary()
    assert study.pair == (0, 1) and study.angles_deg == (0.0, 120.0)
    # The antagonists still fight in length mode under a common shortening, not in tension mode.
    assert s["lengths"]["pair_sum_rise_at_largest_offset_n"] > 0.3
    assert s["tensions"]["pair_tension_change_under_10g_n"] < s["lengths"]["pair_tension_change_under_10g_n"]
    assert "Antagonistic pair 1–2" in study.markdown()


def test_the_env_takes_its_ranges_from_the_robot():
    long = load_robot("long")  # 100 mm
    assert default_curvature_range_per_m(long) == pytest.approx((0.0, 12.0))
    assert default_curvature_range_per_m(load_robot("endoscope")) == pytest.approx((0.0, 20.0))
    assert default_tension_range_n(long.replace({"rig.tension_limit_n": 30.0, "sensors.loadcell_capacity_n": 49.0})) == pytest.approx((1.5, 25.0))
    env = EndoscopeReachEnv(params=long.replace({"rig.tension_limit_n": 30.0, "sensors.loadcell_capacity_n": 49.0}))
    assert env.tension_range_n == pytest.approx((1.5, 25.0))
    assert env.max_length_m == pytest.approx(default_max_length_m(long))
    with pytest.raises(ValueError, match="action_mode = 'pairs': the robot has 3 tendons"):
        EndoscopeReachEnv(params=load_robot("three-tendon"), action_mode="pairs")


@pytest.mark.parametrize("robot", ["three-tendon", "two-segment"])
def test_the_env_and_the_tracker_run_on_other_tendon_counts(robot):
    params = load_robot(robot)
    env = EndoscopeReachEnv(params=params, tip_loads=TipLoads(masses_kg=(0.005,), change_probability=0.0))
    try:
        obs, info = env.reset(seed=0)
        n = params.tendons.count
        assert env.action_space.shape == (n,) and obs.shape == (2 * n + 10 + n,)
        controller = TipTrackingController(params, gain=0.03, velocity_gain_s=0.15, base_rotation=env.device.base_rotation)
        action = env.action_for(controller.reset(env.target_m, info["tip_mass_kg"]))
        first = info["tip_error_m"]
        for _ in range(40):
            obs, _, terminated, _, info = env.step(action)
            assert not terminated
            action = env.action_for(controller.update(obs[env.tip_slice]))
        assert info["tip_error_m"] < max(0.5 * first, 2e-3)
    finally:
        env.close()


def test_twin_tune_and_bench_env_run_on_a_three_tendon_robot(capsys):
    from twin.envs.bench import bench_env
    from twin.tuning import tension_cost
    from twin.control.gains import TUNED_TENSION_GAINS

    params = load_robot("three-tendon")
    assert 0 < tension_cost(TUNED_TENSION_GAINS, params=params) < 2.0
    assert bench_env(params, steps=20)["steps_per_s"] > 0


def test_friction_on_a_two_segment_twin_agrees_with_the_predictor():
    """The twin's capstan friction on a robot whose proximal tendons end at the middle disc: it
    moves the tip by millimetres, and the predictor, given the twin's sliding state, follows it."""
    from twin import effects
    from twin.rod import RodModel, solve
    from twin.rod.grid import pcc_tensions_n
    from twin.sim.plant import Plant

    tips = {}
    for mu in (0.0, 0.3):
        params = load_robot("two-segment").replace({"effects.tendon_friction_coeff": mu})
        plant = Plant(params)
        plant.set_tensions(pcc_tensions_n(15.0, 0.0, params))
        plant.step_until(1.0)
        state = plant.sliding_state if mu > 0 else None
        sol = solve(RodModel.from_params(params), plant.true_tensions_n(), base_rotation=plant.base_rotation,
                    friction_direction=state, tip_force_n=effects.tip_force_n(params, 0.0))
        tips[mu] = plant.tip_pose()[0]
        assert np.linalg.norm(tips[mu] - sol.tip_position_m) < 2e-4
    assert np.linalg.norm(tips[0.3] - tips[0.0]) > 2e-3


@pytest.mark.parametrize("n", [5, 8])
def test_the_tension_step_rollout_runs_on_five_and_eight_tendons(n):
    from twin.control.gains import TUNED_TENSION_GAINS
    from twin.params import load_params
    from twin.tuning import tension_cost

    zeros = [0.0] * n
    params = load_params(overrides={"tendons.angles_deg": [360.0 * i / n for i in range(n)],
                                    "sensors.loadcell_offset_counts": zeros, "effects.tension_gain_error": zeros,
                                    "effects.tension_offset_error_n": zeros})
    assert antagonistic_pair(params) == ((0, 2) if n == 5 else (0, 4))
    assert 0 < tension_cost(TUNED_TENSION_GAINS, params=params) < 2.0
