"""``twin predict`` and ``twin bench predictor`` command-line contracts."""

import json

import numpy as np
import pytest

from twin.cli import main


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_predict_json_has_the_contract_keys(capsys):
    code, out, _ = run(capsys, "predict", "--tensions", "1,0,0,0", "--pose", "up", "--json",
                       "--set", "environment.gravity_m_s2=0")
    assert code == 0
    data = json.loads(out)
    for key in ("tip_position_m", "tip_rotation", "converged", "residual", "iterations", "solve_time_s",
                "tendon_lengths_m", "backbone_positions_m"):
        assert key in data
    assert data["converged"] is True
    rot = np.array(data["tip_rotation"])
    assert rot.shape == (3, 3) and np.allclose(rot @ rot.T, np.eye(3), atol=1e-9)
    assert data["tip_position_m"][0] > 0.01  # tendon 1 (body +x) bends the tip towards +x


def test_horizontal_pose_maps_body_axes_as_the_thesis(capsys):
    _, out, _ = run(capsys, "predict", "--tensions", "0,0,0,0", "--pose", "horizontal", "--json",
                    "--set", "environment.gravity_m_s2=0")
    assert np.allclose(json.loads(out)["tip_position_m"], [0.06, 0, 0], atol=1e-12)
    _, out, _ = run(capsys, "predict", "--tensions", "1,0,0,0", "--pose", "horizontal", "--json",
                    "--set", "environment.gravity_m_s2=0")
    assert json.loads(out)["tip_position_m"][2] < -0.01  # body x → world −z


def test_base_quaternion_equals_named_pose(capsys):
    _, a, _ = run(capsys, "predict", "--tensions", "2,1,1,1", "--pose", "horizontal", "--json")
    _, b, _ = run(capsys, "predict", "--tensions", "2,1,1,1", "--base-quat", "0.7071067811865476,0,0.7071067811865476,0",
                  "--json")
    assert np.allclose(json.loads(a)["tip_position_m"], json.loads(b)["tip_position_m"], atol=1e-12)


def test_failed_solve_exits_non_zero_with_the_residual(capsys):
    code, _, err = run(capsys, "predict", "--tensions", "40,1,1,1", "--tip-force", "0,0,-0.3")
    assert code != 0 and "residual" in err


@pytest.mark.parametrize("argv, message", [
    (["--tensions", "1,0,0"], "4 tendons"),
    (["--tensions", "1,0,0,0", "--set", "backbone.youngs_modulus_pa=-3"], "backbone.youngs_modulus_pa"),
])
def test_bad_input_is_refused_with_a_message(capsys, argv, message):
    code, _, err = run(capsys, "predict", *argv)
    assert code == 2 and message in err


def test_negative_tension_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit):
        main(["predict", "--tensions=-1,0,0,0"])
    assert ">= 0" in capsys.readouterr().err


def test_bench_predictor_prints_its_figures(capsys):
    code = main(["bench", "predictor", "--json"])
    data = json.loads(capsys.readouterr().out)
    assert code == 0
    for key in ("cold_s", "warm_s", "jacobian_s"):
        assert data[key] > 0
    assert data["tip_error_m"] < 1e-6
