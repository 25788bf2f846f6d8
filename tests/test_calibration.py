"""Load-cell calibration: fits recover known lines, the file round-trips and refuses bad content."""

import json

import numpy as np
import pytest

from twin.calibration import (
    TABLE2_MASSES_G,
    Calibration,
    CalibrationFileError,
    check,
    fit_all,
    fit_channel,
    load_calibration,
    run_calibration,
    tensions_from_masses_n,
)
from twin.params import load_params

PARAMS = load_params()
GAIN = PARAMS.sensors.loadcell_gain_counts_per_n
OFFSETS = np.asarray(PARAMS.sensors.loadcell_offset_counts)
NOISE_N = PARAMS.sensors.loadcell_noise_n
G = PARAMS.environment.gravity_m_s2


class FakeHX711:
    """Four load cells as the twin simulates them: integer counts, gain, offset, Gaussian noise."""

    def __init__(self, gains, offsets, noise_n, seed):
        self.gains = np.asarray(gains, dtype=float)
        self.offsets = np.asarray(offsets, dtype=float)
        self.noise_n = noise_n
        self.tension_n = np.zeros(len(self.offsets))
        self.rng = np.random.default_rng(seed)
        self.hung = []

    def hang_mass(self, mass_g, channels):
        self.hung.append((mass_g, channels))
        self.tension_n[:] = 0.0
        self.tension_n[list(channels)] = tensions_from_masses_n(mass_g, G)

    def read_raw_counts(self):
        tension = self.tension_n + self.rng.normal(scale=self.noise_n, size=self.tension_n.shape)
        return np.round(self.offsets + self.gains * tension)


def test_table2_masses_span_the_thesis_tensions():
    tensions = tensions_from_masses_n(TABLE2_MASSES_G, G)
    assert len(TABLE2_MASSES_G) == 12
    assert tensions[0] == 0.0 and tensions[-1] == pytest.approx(2.45, abs=0.01)


def test_fit_is_exact_on_a_noise_free_line():
    tensions = tensions_from_masses_n(TABLE2_MASSES_G, G)
    fit = fit_channel(1234.0 - 40000.0 * tensions, tensions)  # negative gain: reversed wiring
    assert fit.gain_counts_per_n == pytest.approx(-40000.0)
    assert fit.offset_counts == pytest.approx(1234.0)
    assert fit.r_squared == pytest.approx(1.0)
    assert fit.max_residual_n == pytest.approx(0.0, abs=1e-9)


def test_fit_standard_errors_match_the_textbook_formula_and_the_spread_of_repeats():
    rng = np.random.default_rng(10)
    tensions = tensions_from_masses_n(TABLE2_MASSES_G, G)
    noise_counts = 200.0
    gains, ses = [], []
    for _ in range(400):
        fit = fit_channel(500.0 + 45000.0 * tensions + rng.normal(scale=noise_counts, size=12), tensions)
        gains.append(fit.gain_counts_per_n)
        ses.append(fit.gain_se_counts_per_n)
    # σ/sqrt(Sxx) is the true standard deviation of the OLS slope.
    expected_sd = noise_counts / np.sqrt(np.sum((tensions - tensions.mean()) ** 2))
    assert np.std(gains) == pytest.approx(expected_sd, rel=0.1)
    assert np.mean(ses) == pytest.approx(expected_sd, rel=0.1)


def test_guided_run_recovers_the_twins_gain_and_offset_within_their_uncertainty():
    gains = GAIN * np.array([1.0, 0.97, 1.04, -1.0])
    fake = FakeHX711(gains, OFFSETS, NOISE_N, seed=11)
    run = run_calibration(fake.read_raw_counts, fake.hang_mass, samples_per_mass=20, gravity_m_s2=G, device="sim://")
    assert [m for m, _ in fake.hung] == list(TABLE2_MASSES_G)
    assert all(ch == (0, 1, 2, 3) for _, ch in fake.hung)
    cal = run.calibration
    for c, fit in enumerate(run.fits):
        assert abs(fit.gain_counts_per_n - gains[c]) < 3 * fit.gain_se_counts_per_n
        assert abs(fit.offset_counts - OFFSETS[c]) < 3 * fit.offset_se_counts
        # 20 averaged samples: residual RMS ≈ noise/sqrt(20) ≈ 1 mN; with 10 degrees of freedom
        # it scatters ±22 % (1σ) around 0.91 of that, hence the wide band.
        assert 0.3 < fit.rms_residual_n / (NOISE_N / np.sqrt(20)) < 1.6
        assert fit.r_squared > 0.99999
    # the sample scatter per mass is the simulated noise
    assert np.median(np.abs(run.raw_std_counts / gains)) == pytest.approx(NOISE_N, rel=0.2)
    assert cal.device == "sim://" and cal.samples_per_mass == 20
    np.testing.assert_allclose(cal.to_newtons(OFFSETS + gains * 1.5), 1.5, atol=0.003)


def test_guided_run_one_channel_at_a_time_loads_only_that_channel():
    fake = FakeHX711([GAIN] * 4, OFFSETS, NOISE_N, seed=12)
    masses = (0.0, 50.0, 100.0, 200.0)
    run = run_calibration(fake.read_raw_counts, fake.hang_mass, masses_g=masses, gravity_m_s2=G,
                          samples_per_mass=5, one_at_a_time=True)
    assert fake.hung == [(m, (c,)) for c in range(4) for m in masses]
    np.testing.assert_allclose(run.calibration.gain_counts_per_n, GAIN, rtol=0.01)


def test_guided_run_refuses_a_bad_reading_naming_it():
    with pytest.raises(ValueError, match="expected 4 finite counts"):
        run_calibration(lambda: np.zeros(3), lambda m, c: None, samples_per_mass=2, gravity_m_s2=G)
    with pytest.raises(ValueError, match=r"\[1.0, nan, 3.0, 4.0\]"):
        run_calibration(lambda: [1.0, np.nan, 3.0, 4.0], lambda m, c: None, gravity_m_s2=G)


def _calibration(seed=13):
    fake = FakeHX711([GAIN] * 4, OFFSETS, NOISE_N, seed=seed)
    return run_calibration(fake.read_raw_counts, fake.hang_mass, samples_per_mass=5, gravity_m_s2=G,
                           device="serial:///dev/ttyACM0").calibration


def test_file_round_trip(tmp_path):
    cal = _calibration()
    path = cal.save(tmp_path / "loadcells.json")
    again = load_calibration(path)
    assert again == cal
    raw = OFFSETS + GAIN * np.array([[0.1, 0.2, 0.3, 0.4], [1.0, 1.1, 1.2, 1.3]])
    np.testing.assert_array_equal(again.to_newtons(raw), cal.to_newtons(raw))
    # the stored points allow a refit that gives back the stored lines
    refit = fit_all(again.raw_counts, again.tensions_n)
    np.testing.assert_allclose([f.gain_counts_per_n for f in refit], again.gain_counts_per_n)


@pytest.mark.parametrize(
    "mutate, words",
    [
        (lambda d: d.pop("masses_g"), "missing field(s) masses_g"),
        (lambda d: d.update(format="something-else"), "format = 'something-else'"),
        (lambda d: d.update(version=2), "version = 2"),
        (lambda d: d.update(date="yesterday"), "date = 'yesterday'"),
        (lambda d: d.update(gravity_m_s2=-9.8), "gravity_m_s2 = -9.8"),
        (lambda d: d.update(samples_per_mass=0), "samples_per_mass = 0"),
        (lambda d: d.update(extra=1), "unknown field(s) extra"),
        (lambda d: d["channels"][2].update(gain_counts_per_n="45000"), "channels[2].gain_counts_per_n = '45000'"),
        (lambda d: d["channels"][1].update(gain_counts_per_n=0), "channels[1].gain_counts_per_n = 0.0"),
        (lambda d: d["channels"][3].pop("offset_counts"), "channels[3] is missing field(s) offset_counts"),
        (lambda d: d["masses_g"].__setitem__(4, -5), "masses_g[4] = -5"),
        (lambda d: d["raw_counts"][0].pop(), "raw_counts[0]"),
        (lambda d: d["raw_counts"].pop(), "one per mass"),
    ],
)
def test_malformed_files_are_refused_naming_the_field(tmp_path, mutate, words):
    data = _calibration().to_dict()
    mutate(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CalibrationFileError) as info:
        load_calibration(path)
    assert words in str(info.value) and str(path) in str(info.value)


def test_non_json_and_nan_are_refused(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text("{not json")
    with pytest.raises(CalibrationFileError, match="not valid JSON"):
        load_calibration(path)
    data = _calibration().to_dict()
    data["channels"][0]["offset_counts"] = float("nan")  # json writes it as NaN, which it also reads
    path.write_text(json.dumps(data))
    with pytest.raises(CalibrationFileError, match=r"channels\[0\].offset_counts = nan"):
        load_calibration(path)


def test_check_passes_a_good_calibration_and_fails_a_shifted_one():
    cal = _calibration()
    fake = FakeHX711([GAIN] * 4, OFFSETS, NOISE_N, seed=14)
    masses = (0.0, 20.0, 100.0, 250.0)
    raw = []
    for m in masses:
        fake.hang_mass(m, (0, 1, 2, 3))
        raw.append(np.mean([fake.read_raw_counts() for _ in range(20)], axis=0))
    raw = np.array(raw)
    tensions = tensions_from_masses_n(masses, G)
    good = check(cal, raw, tensions)
    assert good.passed and good.channel_passed.all()
    assert np.all(good.max_abs_error_n < 0.005)
    # channel 2's offset drifted by 0.05 N worth of counts (e.g. the load cell was re-clamped)
    raw[:, 2] += 0.05 * GAIN
    bad = check(cal, raw, tensions)
    assert not bad.passed
    assert bad.channel_passed.tolist() == [True, True, False, True]
    assert bad.max_abs_error_n[2] == pytest.approx(0.05, abs=0.005)


def test_to_newtons_is_vectorised_and_refuses_the_wrong_channel_count():
    cal = _calibration()
    raw = np.broadcast_to(OFFSETS, (5, 7, 4))
    assert cal.to_newtons(raw).shape == (5, 7, 4)
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        cal.to_newtons(np.zeros(3))


def test_fit_refuses_degenerate_input():
    with pytest.raises(ValueError, match="at least 3"):
        fit_channel([1.0, 2.0], [0.0, 1.0])
    with pytest.raises(ValueError, match="two distinct tensions"):
        fit_channel([1.0, 2.0, 3.0], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="zero slope"):
        fit_channel([5.0, 5.0, 5.0], [0.0, 1.0, 2.0])
    with pytest.raises(ValueError, match="raw_counts"):
        fit_channel([1.0, np.nan, 3.0], [0.0, 1.0, 2.0])
    with pytest.raises(CalibrationFileError, match="missing field"):
        Calibration.from_dict({"format": "twin.loadcell-calibration"})
