"""User mistakes end in one line naming the argument and the value, with a non-zero exit.

Each row is a mistake a new user makes; the command must neither print a traceback nor leave a
run folder behind, and must not exit 0.
"""

import json

import pytest

from twin.cli import main


MISTAKES = [
    # (argv, exit code, words the one line must hold)
    (["predict", "--params", "/no/such.toml", "--tensions", "1,1,1,1"], 2, ["--params", "/no/such.toml"]),
    (["predict", "--tensions", "-1,1,1,1"], 2, ["--tensions", "-1,1,1,1"]),
    (["predict", "--tensions", "1,1"], 2, ["--tensions", "2 values"]),
    (["sim", "--tensions", "1,1,1,1", "--tip-mass-kg", "-1"], 2, ["--tip-mass-kg", "-1"]),
    (["sim", "--tensions", "1,1,1,1", "--timeout-s", "-3"], 2, ["--timeout-s", "-3"]),
    (["sim", "--tensions", "1,1,1,1", "--tip-force", "0,nan,0"], 2, ["--tip-force", "0,nan,0"]),
    (["sim", "--tensions", "1,1,1,1", "--set", "sim.elements=1e300"], 2, ["sim.elements", "1e+300"]),
    (["validate", "--quick", "--device", "sim://?sede=3"], 2, ["--device", "sede"]),
    (["validate", "--quick", "--device", "bogus://x"], 2, ["--device", "bogus"]),
    (["validate", "--quick", "--device", "serial:///dev/nonexistent"], 4, ["/dev/nonexistent"]),
    (["validate", "--quick", "--calibration", "/no/such.json"], 2, ["--calibration", "/no/such.json"]),
    (["validate", "--resume", "runs/validate-typo"], 2, ["--resume", "validate-typo", "not a run folder"]),
    (["compensate", "--device", "sim://?seed=x"], 2, ["--device", "seed", "'x'"]),
    (["stiffness", "--device", "sim://?pose=sideways"], 2, ["--device", "pose", "sideways"]),
    (["discrepancy", "/no/such/dataset"], 2, ["/no/such/dataset"]),
    (["crosscheck", "--quick", "--elements", "-3"], 2, ["elements", "-3"]),
    (["emulate", "--seed", "abc"], 2, ["--seed", "abc"]),
    (["no-such-command"], 2, ["no-such-command"]),
    (["sim", "--tensions", "1,1,1,1", "--seed", "-5"], 2, ["--seed", "-5"]),
    (["compensate", "--quick", "--corrections", "-1"], 2, ["--corrections", "-1"]),
    (["compensate", "--quick", "--device", "serial:///dev/null", "--twin-set", "effects.tendon_friction_coeff=0.1"],
     2, ["--twin-set", "sim://"]),
    (["compensate", "--quick", "--twin-set", "effects.no_such=1"], 2, ["--twin-set", "effects.no_such"]),
    (["validate", "--quick", "--twin-set", "effects.loadcell_lag_s=-1"], 2, ["--twin-set", "loadcell_lag_s", "-1"]),
    (["stiffness", "--twin-set", "effects.no_such=1"], 2, ["--twin-set", "effects.no_such"]),
    (["dynamics", "record", "--quick", "--twin-set", "effects.loadcell_lag_s=-1"], 2, ["--twin-set", "loadcell_lag_s"]),
    (["compensate", "--quick", "--ceiling", "28"], 2, ["--ceiling 28", "5.38 N"]),
    (["compensate", "--quick", "--robot", "stiff-long", "--ceiling", "5"], 2,
     ["within reach", "above the 5.00 N ceiling"]),
    (["calibrate", "--refit", "--file", "/no/such.json"], 1, ["--file", "/no/such.json"]),
    (["emulate", "--link", "/no/such/dir/port"], 1, ["--link", "/no/such/dir/port"]),
    (["validate", "--quick", "--out", "/proc/no-such"], 1, ["--out", "/proc/no-such"]),
]


def _run(argv) -> int:
    """The exit code of ``twin argv``, whether the command returns it or argparse exits."""
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


@pytest.mark.parametrize("argv, code, words", MISTAKES, ids=[" ".join(m[0])[:60] for m in MISTAKES])
def test_a_user_mistake_is_one_line_naming_argument_and_value(tmp_path, monkeypatch, capsys, argv, code, words):
    monkeypatch.chdir(tmp_path)
    result = _run(argv)
    err = capsys.readouterr().err
    assert result == code, err
    assert "Traceback" not in err
    problem = [line for line in err.splitlines() if all(word in line for word in words)]
    assert problem, err
    # A run that measured nothing leaves no folder behind.
    runs = tmp_path / "runs"
    assert not runs.exists() or not any(runs.iterdir()), list(runs.iterdir())


def test_negative_numbers_parse_as_values(capsys):
    assert main(["predict", "--tensions", "1,0,1,0", "--tip-force", "0,-0.05,0", "--json"]) == 0
    pushed = json.loads(capsys.readouterr().out)["tip_position_m"]
    assert main(["predict", "--tensions", "1,0,1,0", "--json"]) == 0
    free = json.loads(capsys.readouterr().out)["tip_position_m"]
    assert pushed[1] < free[1] - 1e-3


def test_commands_write_under_runs_by_default(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["crosscheck", "--quick"]) == 0
    (folder,) = (tmp_path / "runs").iterdir()
    assert folder.name.startswith("crosscheck-") and (folder / "crosscheck.md").exists()
    assert str(folder.relative_to(tmp_path)) in capsys.readouterr().out


def test_twin_sim_takes_one_value_per_tendon_of_the_robot(capsys):
    assert main(["sim", "--robot", "three-tendon", "--tensions", "2,1,1", "--json"]) == 0
    tip = json.loads(capsys.readouterr().out)["tip_position_m"]
    assert tip[2] < -0.005  # tendon 1 at 0 deg bends the horizontal robot down
    assert _run(["sim", "--robot", "three-tendon", "--tensions", "2,1,1,1"]) == 2
    assert "--tensions has 4 values; the robot has 3 tendons" in capsys.readouterr().err


def test_without_a_compiler_validate_says_so_in_one_line_and_leaves_no_folder(tmp_path):
    import os
    import subprocess
    import sys

    env = dict(os.environ, TWIN_CACHE_DIR=str(tmp_path / "cache"), CXX="no-such-compiler-g++")
    done = subprocess.run([sys.executable, "-m", "twin.cli", "validate", "--quick", "--out", str(tmp_path / "runs")],
                          env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr and "no-such-compiler-g++" in done.stderr
    assert not any((tmp_path / "runs").iterdir())


@pytest.fixture(scope="module")
def four_channel_calibration(tmp_path_factory):
    path = tmp_path_factory.mktemp("cal") / "four.json"
    assert main(["calibrate", "--file", str(path)]) == 0
    return path


@pytest.mark.parametrize("command", [["validate", "--quick"], ["stiffness"], ["dynamics", "record", "--quick"]])
def test_a_calibration_of_another_channel_count_is_refused_before_a_run_folder(tmp_path, monkeypatch, capsys,
                                                                               four_channel_calibration, command):
    monkeypatch.chdir(tmp_path)
    result = _run([*command, "--robot", "three-tendon", "--calibration", str(four_channel_calibration)])
    err = capsys.readouterr().err
    assert result == 2, err
    assert [line for line in err.splitlines() if "4 channels" in line and "3 tendons" in line], err
    assert "Traceback" not in err and not (tmp_path / "runs").exists()
