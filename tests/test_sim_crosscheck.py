"""The twin against the predictor on a few configurations of the thesis grid (the full grid and
the cause studies are `twin crosscheck`, reports/crosscheck/)."""

import numpy as np
import pytest

from twin.cli import main
from twin.params import load_params
from twin.pose import UP
from twin.rod import RodModel, solve
from twin.rod.grid import pcc_tensions_n
from twin.sim import Plant
from twin.sim.crosscheck import (GOAL_MEDIAN_PCT, GOAL_WORST_PCT, QUICK_GRID, ROBOTS, crosscheck, crosscheck_status,
                                 robot_params, write_report)

# Both tendon planes and one between them, the largest curvature, with and without a tip mass.
CONFIGS = [(180, 26.2, 0.0, 0.0), (197, 26.2, 150.0, 0.01), (117, 13.0, 90.0, 0.0), (2, 0.0, 0.0, 0.01)]


def test_at_the_defaults_the_twin_agrees_with_the_predictor_well_under_a_percent_of_length():
    result = crosscheck(configs=CONFIGS)
    assert result.settled.all() and result.rod_converged.all()
    # The twin stands in for the rig in the discrepancy workflow, which must find nothing in
    # twin data with every effect off: half a percent of L is 0.3 mm, near the tracker noise.
    assert np.all(result.difference_m < 0.005 * result.length_m)


def test_disc_routing_bends_further_than_the_predictor_and_the_report_says_so(tmp_path):
    params = load_params()
    continuous = crosscheck(params, configs=CONFIGS[:1])
    discs = crosscheck(params, configs=CONFIGS[:1], tendon_sites="discs")
    # The pretensioned chords pull the tip further round the bend, away from the clamp axis.
    assert discs.difference_m[0] > 10 * continuous.difference_m[0]
    assert discs.twin_tip_m[0][0] < continuous.twin_tip_m[0][0]
    path = write_report(continuous, [("disc routing", False, discs)], tmp_path, params)
    text = path.read_text()
    assert "| disc routing |" in text and (tmp_path / "crosscheck.csv").read_text().count("\n") == 2


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_every_robot_meets_the_goal_on_the_reduced_grid(robot):
    # The largest curvature in every plane with the 10 g mass, where each robot's worst
    # configurations of the full grid lie (`twin crosscheck --robot all` runs that).
    result = crosscheck(robot_params(robot), configs=QUICK_GRID)
    assert result.settled.all() and result.rod_converged.all()
    summary = result.summary()
    assert summary["median_pct"] <= GOAL_MEDIAN_PCT and summary["worst_pct"] <= GOAL_WORST_PCT
    assert result.meets_goal


def test_without_the_tendons_second_order_length_the_soft_shear_robot_misses_the_goal():
    # With GA = 1.35 N the tendons' tension carries most of the shear stiffness; the fixed tendon
    # alone (first order) leaves it out.
    result = crosscheck(robot_params("endoscope-soft-g"), configs=QUICK_GRID, tendon_sites="linear")
    assert result.settled.all()
    assert not result.meets_goal and result.summary()["median_pct"] > 2 * GOAL_MEDIAN_PCT
    assert result.verdict().startswith("GOAL MISSED")


def test_under_helical_routing_the_pretension_twists_the_tip_as_in_the_predictor():
    # Half a turn of helix: each tendon's tangent leans by atan(ρω), so its tension twists the
    # rod, uz = −ΣT ρ²ω/|q| / (K_t + ΣT ρ²/|q|³), |q| = √(1 + ρ²ω²): −16.7° at the tip.
    params = robot_params("helical", {"environment.gravity_m_s2": 0.0})
    b, t = params.backbone, params.tendons
    tensions = np.full(t.count, t.pretension_n)
    plant = Plant(params, base_rotation=UP)
    plant.set_tensions(tensions)
    assert plant.settle(tol_m=1e-8).settled
    rod = solve(RodModel.from_params(params), tensions, base_rotation=UP)
    omega = 2 * np.pi * t.helix_turns / b.length_m
    q = np.hypot(1.0, t.radius_m * omega)
    total = tensions.sum()
    hand = -total * t.radius_m**2 * omega / q / (b.torsional_stiffness_nm2 + total * t.radius_m**2 / q**3) * b.length_m

    def twist_deg(rotation):
        return np.degrees(np.arctan2(rotation[1, 0], rotation[0, 0]))

    assert twist_deg(plant.tip_pose()[1]) == pytest.approx(twist_deg(rod.tip_rotation), abs=0.1)
    assert twist_deg(rod.tip_rotation) == pytest.approx(np.degrees(hand), abs=0.1)
    assert np.degrees(hand) < -15.0


def test_crosscheck_exits_nonzero_and_says_so_when_the_goal_is_missed(tmp_path, capsys):
    # The rig's chords between discs bend the rod further than the predictor's continuous routing.
    code = main(["crosscheck", "--quick", "--set", 'sim.tendon_routing="discs"', "--out", str(tmp_path)])
    assert code == 1
    assert "GOAL MISSED" in (tmp_path / "crosscheck.md").read_text()
    assert "goal missed" in capsys.readouterr().err
    assert main(["crosscheck", "--quick", "--robot", "helical", "--out", str(tmp_path / "helical")]) == 0
    assert "**Goal met**" in (tmp_path / "helical" / "crosscheck.md").read_text()


def test_the_status_of_a_twin_out_of_bounds_carries_a_warning():
    assert crosscheck_status().meets_goal and crosscheck_status().warning is None
    status = crosscheck_status(load_params(overrides=['sim.tendon_routing="discs"']))
    assert not status.meets_goal and status.worst_pct > GOAL_WORST_PCT
    assert "out of bounds" in status.warning and status.verdict in status.warning


def test_a_layout_that_cannot_bend_a_plane_leaves_it_out_and_says_so():
    # Two antagonistic tendons bend in one plane only: the grid's other planes are not run.
    two = load_params(overrides={"tendons.angles_deg": [0.0, 180.0], "effects.tension_gain_error": [0.0] * 2,
                                 "effects.tension_offset_error_n": [0.0] * 2,
                                 "sensors.loadcell_offset_counts": [0.0] * 2})
    result = crosscheck(two, configs=QUICK_GRID)
    planes = {row[2] for row in result.rows}
    assert planes <= {0.0, 180.0} and result.left_out
    assert all(row[2] not in (0.0, 180.0) and row[1] > 0 for row in result.left_out)
    assert result.summary()["left_out"] == len(result.left_out)
    assert "left out: the tendon layout cannot bend their planes" in result.verdict()


def test_tendons_anchored_at_a_middle_disc_bend_only_their_segment_in_both_models():
    from twin.robots import load_robot
    from twin.rod import RodModel, solve

    two = load_robot("two-segment")
    to_tip = two.replace({"tendons.end_discs": []})
    tips = {}
    for name, params in (("segments", two), ("to the tip", to_tip)):
        tensions = pcc_tensions_n(26.2, 0.0, params)  # the proximal tendon at 0 deg alone pulls
        plant = Plant(params)
        plant.set_tensions(tensions)
        assert plant.settle().settled
        rod = solve(RodModel.from_params(params), tensions, base_rotation=params.rig.base_rotation)
        tips[name] = plant.tip_pose()[0], rod.tip_position_m
    for twin_tip, rod_tip in tips.values():
        assert np.linalg.norm(twin_tip - rod_tip) < 0.003 * two.backbone.length_m
    # Anchored at the middle the pull bends half the robot: the tip ends elsewhere by centimetres.
    assert np.linalg.norm(tips["segments"][1] - tips["to the tip"][1]) > 0.01


def test_the_quick_zoo_cross_check_writes_every_robots_report(tmp_path, capsys):
    # The cause studies cover the whole grid: on the quick grid they are left out, not mismatched.
    code = main(["crosscheck", "--robot", "all", "--quick", "--out", str(tmp_path)])
    table = (tmp_path / "zoo.md").read_text()
    assert code == 0, capsys.readouterr().err
    assert all(f"| {name} |" in table for name in ROBOTS)
    assert all((tmp_path / name / "crosscheck.md").exists() for name in ROBOTS[1:])


def test_with_tendon_friction_the_predictor_given_the_twins_sliding_state_agrees_with_the_twin():
    # The twin's friction remembers how each tendon got where it is; the predictor, given that
    # state, computes the same capstan loss. All tendons taken as pulled (the old guess) misses.
    params = load_params().replace({"effects.tendon_friction_coeff": 0.15})
    result = crosscheck(params, configs=QUICK_GRID)
    assert result.meets_goal, result.verdict()
    plant = Plant(params)
    misses = []
    for _, kappa, phi, mass in QUICK_GRID:
        tensions = pcc_tensions_n(kappa, phi, params)
        plant.set_tensions(tensions)
        plant.set_tip_mass_kg(mass)
        plant.settle(tol_m=1e-6)
        sol = solve(RodModel.from_params(params), tensions, tip_force_n=(0.0, 0.0, -mass * params.environment.gravity_m_s2),
                    base_rotation=plant.base_rotation, friction_direction=np.ones(params.tendons.count))
        misses.append(np.linalg.norm(sol.tip_position_m - plant.tip_pose()[0]) / params.backbone.length_m * 100)
    assert max(misses) > GOAL_WORST_PCT


def test_the_report_names_the_clamp_pose_of_the_parameter_set(tmp_path):
    from twin.pose import matrix_to_quat, rot_y

    down = robot_params("endoscope").replace({"rig.base_quat": matrix_to_quat(rot_y(np.radians(120.0))).tolist()})
    result = crosscheck(down, configs=QUICK_GRID[:1])
    text = write_report(result, [], tmp_path, down).read_text()
    assert "Base clamped pointing 30° below the horizontal, gravity on" in text and "Endoscope horizontal" not in text
