"""Tip force estimation on the predictor's ground truth (hidden forces, noisy sensors)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from twin.cli import main
from twin.force import estimate_tip_wrench
from twin.force.bench import COVERAGE_GOAL, POSES, accuracy_trials, pose_tensions_n, summarise
from twin.robots import load_robot
from twin.rod import RodModel, solve


def test_accuracy_and_coverage_on_hidden_forces():
    trials = accuracy_trials(["endoscope", "three-tendon", "long"], poses=POSES[:2], forces_per_pose=6, seed=3)
    assert all(t.converged for t in trials)
    for row in summarise(trials):
        assert row["median_error_over_goal"] <= 1.0, row
    # Coverage pooled: 36 trials, so one robot-pose cell of six is too few to judge on its own.
    assert np.mean([t.covered for t in trials]) >= COVERAGE_GOAL


def test_axial_force_of_a_straight_robot_is_reported_unobservable_not_zero():
    params = load_robot("endoscope")
    model = RodModel.from_params(params)
    tensions = pose_tensions_n(params, 0.0, 0.0)
    # An axial pull the tip pose barely shows (F L / EA) and a sideways push it shows clearly
    # (the horizontal clamp: the rod along world x, the push along world −z).
    axis = params.rig.base_rotation[:, 2]
    side = params.rig.base_rotation[:, 0]
    force = 0.2 * axis + 0.1 * side
    sol = solve(model, tensions, tip_force_n=force, base_rotation=params.rig.base_rotation)
    est = estimate_tip_wrench(params, tensions, sol.tip_position_m, sol.tip_rotation, model=model)
    assert est.converged
    # Not seen: the force along (nearly) the deflected tip's tangent, which only stretches the rod.
    tangent = sol.tip_rotation[:, 2]
    unseen = est.unobservable_force_directions
    assert unseen.shape == (1, 3) and abs(unseen[0] @ tangent) > 0.99
    seen = np.eye(3) - np.outer(unseen[0], unseen[0])
    assert np.allclose(est.force_observable_n, seen @ force, atol=2e-3)
    # The world axis along the rod is NaN with NaN covariance, never 0; the sideways one (y) is seen.
    assert not est.force_observable[0] and np.isnan(est.force_n[0]) and np.isnan(est.force_cov_n2[0]).all()
    assert est.force_observable[1] and abs(est.force_n[1]) < 2e-3
def test_cli_force_json_and_bad_input(capsys):
    params = load_robot("three-tendon")
    model = RodModel.from_params(params)
    tensions = pose_tensions_n(params, 45.0, 0.0)
    force = np.array([0.0, 0.1, -0.05])
    sol = solve(model, tensions, tip_force_n=force, base_rotation=params.rig.base_rotation)
    args = ["force", "--robot", "three-tendon", "--tensions", ",".join(map(str, tensions)),
            "--tip-position", ",".join(map(str, sol.tip_position_m)),
            "--tip-rotation", ",".join(map(str, sol.tip_rotation.ravel())), "--json"]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["converged"] is True and out["consistent"] is True
    got = np.array([np.nan if v is None else v for v in out["force_n"]])
    seen = np.array(out["observable"]["force"])
    assert np.allclose(got[seen], force[seen], atol=3e-3) and np.isnan(got[~seen]).all()
    unseen = np.array(out["observable"]["unobservable_force_directions"]).reshape(-1, 3)
    projector = np.eye(3) - unseen.T @ unseen
    assert unseen.shape[0] <= 1 and np.allclose(out["force_observable_n"], projector @ force, atol=3e-3)
    assert len(out["force_cov_n2"]) == 3
    assert main([*args[:4], "1,2", *args[5:]]) == 2
    assert "--tensions" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["force", "--tensions", "1,1,1", "--tip-position", "0,0", "--robot", "three-tendon"])
    assert main([*args[:4], "1,-2,1", *args[5:]]) == 2
    assert "tendons only pull" in capsys.readouterr().err
    assert main([*args[:-2], "1,0,0,0,1,0,0,0,2", "--json"]) == 2
    assert "--tip-rotation" in capsys.readouterr().err


def test_cli_force_on_a_dataset_finds_the_hung_masses(tmp_path, capsys):
    from twin import effects
    from twin.data.dataset import write_dataset
    from twin.pose import matrix_to_quat

    params = load_robot("endoscope")
    model = RodModel.from_params(params)
    rows = []
    for config, (bend, mass) in enumerate([(0.0, 0.005), (45.0, 0.010), (45.0, 0.0)]):
        tensions = pose_tensions_n(params, bend, 0.0)
        weight = effects.tip_force_n(params, mass)
        sol = solve(model, tensions, tip_force_n=weight, base_rotation=params.rig.base_rotation)
        tip = effects.tracked_point_m(params, sol.tip_position_m, sol.tip_rotation)
        row = {"config": config, "experiment": "stiffness", "repeat": 0, "kappa_cmd_per_m": 0.0, "phi_cmd_deg": 0.0,
               "tip_mass_kg": mass, "time_s": float(config), "tip_x_m": tip[0], "tip_y_m": tip[1], "tip_z_m": tip[2]}
        row.update({f"tip_q{c}": q for c, q in zip("wxyz", matrix_to_quat(sol.tip_rotation))})
        row.update({f"tension_{i + 1}_n": t for i, t in enumerate(tensions)})
        row.update({f"length_{i + 1}_m": 0.0 for i in range(tensions.size)})
        rows.append(row)
    write_dataset(tmp_path / "ds", rows, experiment="stiffness", device="synthetic", params=params,
                  base_rotation=params.rig.base_rotation, robot="endoscope")
    assert main(["force", str(tmp_path / "ds"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["converged"] and len(out["rows"]) == 3
    for row in out["rows"]:
        unseen = np.array(row["observable"]["unobservable_force_directions"]).reshape(-1, 3)
        projector = np.eye(3) - unseen.T @ unseen
        assert np.allclose(row["force_observable_n"], projector @ np.array(row["known_force_n"]), atol=2e-3)
    # The straight rod sees the 5 g weight whole (it is across the rod); nothing on the empty third row.
    assert abs(np.linalg.norm(out["rows"][0]["force_observable_n"]) - 0.005 * 9.81) < 2e-3
    assert np.linalg.norm(out["rows"][2]["force_observable_n"]) < 2e-3
    assert main(["force", str(tmp_path / "ds"), "--tensions", "1,1,1,1"]) == 2
    assert "not with a DATASET" in capsys.readouterr().err


def test_a_pose_no_tip_force_explains_is_flagged_inconsistent():
    params = load_robot("endoscope")
    model = RodModel.from_params(params)
    tensions = pose_tensions_n(params, 45.0, 0.0)
    force = np.array([0.0, 0.1, -0.05])
    results = []
    for moment in (None, np.array([0.0, 0.003, 0.0])):
        sol = solve(model, tensions, tip_force_n=force, tip_moment_nm=moment, base_rotation=params.rig.base_rotation)
        est = estimate_tip_wrench(params, tensions, sol.tip_position_m, sol.tip_rotation, model=model)
        results.append(est.consistent)
    assert results == [True, False]


def test_position_alone_sees_the_sideways_force():
    params = load_robot("two-segment")
    model = RodModel.from_params(params)
    tensions = pose_tensions_n(params, 0.0, 0.0)
    force = np.array([0.0, -0.08, 0.03])  # across the horizontal rod (along world x)
    sol = solve(model, tensions, tip_force_n=force, base_rotation=params.rig.base_rotation)
    est = estimate_tip_wrench(params, tensions, sol.tip_position_m, None, model=model)
    assert est.converged and est.consistent is None  # three measurements, three unknowns: nothing to spare
    seen = np.eye(3) - est.unobservable_force_directions.T @ est.unobservable_force_directions
    assert np.allclose(est.force_observable_n, seen @ force, atol=1e-3)
    assert np.linalg.norm(seen @ force) > 0.07


def test_a_warm_estimate_follows_a_changing_load_as_the_cold_one_does():
    params = load_robot("endoscope")
    model = RodModel.from_params(params)
    previous = None
    for k, force in enumerate(([0.05, 0.1, 0.0], [0.06, 0.1, 0.01], [0.08, 0.09, 0.02])):
        tensions = pose_tensions_n(params, 40.0 + 2.0 * k, 0.0)
        sol = solve(model, tensions, tip_force_n=force, base_rotation=params.rig.base_rotation)
        warm = estimate_tip_wrench(params, tensions, sol.tip_position_m, sol.tip_rotation, model=model,
                                   previous=previous)
        cold = estimate_tip_wrench(params, tensions, sol.tip_position_m, sol.tip_rotation, model=model)
        assert warm.converged and cold.converged
        assert np.allclose(warm.force_observable_n, cold.force_observable_n, atol=1e-4)
        assert np.allclose(warm.force_observable_cov_n2, cold.force_observable_cov_n2, rtol=1e-2, atol=1e-9)
        if previous is not None:
            # Started at the last load with its Jacobian: fewer steps than from no load.
            assert warm.iterations < cold.iterations
        previous = warm
