"""Experiments run through a device on the twin: calibration recovers the simulated load cells."""

import numpy as np

from twin import load_params
from twin.driver import open_device
from twin.experiments.protocols import calibrate_device


def test_calibration_on_the_twin_recovers_simulated_gain_and_offset():
    gain_error = [0.05, 0.0, -0.04, 0.02]
    offset_error_n = [0.0, 0.08, 0.0, -0.05]
    params = load_params(overrides={"effects.tension_gain_error": gain_error,
                                    "effects.tension_offset_error_n": offset_error_n})
    with open_device("sim://?seed=4", params=params) as device:
        cal = calibrate_device(device, params, samples_per_mass=6, progress=False)
    s = params.sensors
    true_gain = s.loadcell_gain_counts_per_n * (1 + np.array(gain_error))
    true_offset = np.array(s.loadcell_offset_counts) + s.loadcell_gain_counts_per_n * np.array(offset_error_n)
    for ch, g, o in zip(cal.channels, true_gain, true_offset):
        assert abs(ch.gain_counts_per_n - g) < 4 * ch.gain_se_counts_per_n + 1.0
        assert abs(ch.offset_counts - o) < 4 * ch.offset_se_counts + 1.0
    # The host applies it: raw counts of a 1.0 N true tension read back as 1.0 N.
    raw = true_offset + true_gain * 1.0
    assert np.allclose(cal.to_newtons(raw), 1.0, atol=0.005)


def test_calibrate_refit_reproduces_the_file(tmp_path, capsys):
    from twin.cli import main

    path = tmp_path / "cal.json"
    assert main(["calibrate", "--file", str(path), "--samples", "4"]) == 0
    assert main(["calibrate", "--file", str(path), "--refit"]) == 0
    from twin.calibration import load_calibration

    a, b = load_calibration(path), load_calibration(tmp_path / "cal.json")
    assert np.allclose(a.gain_counts_per_n, b.gain_counts_per_n)
    assert "gain counts/N" in capsys.readouterr().out


def test_calibrate_check_fails_a_wrong_calibration(tmp_path):
    from twin.cli import main

    path = tmp_path / "cal.json"
    assert main(["calibrate", "--file", str(path), "--samples", "4"]) == 0
    # The rig's channel 2 load cell drifted by 0.1 N since: the check must fail.
    assert main(["calibrate", "--file", str(path), "--check", "--samples", "4",
                 "--set", "effects.tension_offset_error_n=[0, 0.1, 0, 0]"]) == 5
    assert main(["calibrate", "--file", str(path), "--check", "--samples", "4"]) == 0
