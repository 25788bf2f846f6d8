"""Causes outside the effect library: the workflow never names a library effect for them.

Each dataset hides a cause no parameter carries (a turned tracker frame, a curved backbone, a
tilt with an offset cap), at sizes and seeds the workflow was not tuned on; the answer must not
be ``effect``, must list what was fitted as candidates only, and must say which experiment
would tell the explanations apart.
"""

import json

import numpy as np
import pytest

from twin import load_params
from twin.cli import main
from twin.discrepancy import run_discrepancy, synthetic_validation_dataset
from twin.pcc import validation_grid
from twin.rod import RodModel, solve

NOMINAL = load_params()
# A sixth of the thesis grid (κ 0/13/26.2 1/m, every other plane, 0 and 10 g), as tests/test_discrepancy.py.
GRID = [g for g in validation_grid() if g[1] in (0.0, 13.0, 26.2) and g[2] % 60 == 0 and g[3] in (0.0, 0.01)]


def test_an_intrinsic_curvature_is_the_unloaded_rods_arc():
    model = RodModel.from_params(NOMINAL).replace(precurvature_per_m=(0.0, -7.0, 0.0), gravity_m_s2=1e-12)
    tip = solve(model, np.zeros(4)).tip_position_m
    length, kappa = model.length_m, 7.0
    # u = (0, −7, 0) bends the rod towards −x (R' = R û), in a circle of radius 1/7 m.
    assert tip == pytest.approx([-(1 - np.cos(kappa * length)) / kappa, 0.0, np.sin(kappa * length) / kappa], abs=1e-7)
    assert np.allclose(solve(model.replace(precurvature_per_m=(0.0, 0.0, 0.0)), np.zeros(4)).tip_position_m,
                       [0.0, 0.0, length], atol=1e-9)


def test_a_turned_tracker_frame_is_not_named_and_its_rotation_is_found(tmp_path):
    data = synthetic_validation_dataset(tmp_path, NOMINAL, NOMINAL, grid=GRID, seed=11,
                                        tracker_rotation_deg=(0.0, 0.0, -0.8))
    result = run_discrepancy(data, seed=2)
    assert result.verdict in ("ambiguous", "unexplained") and result.named == (), result.statement()
    assert result.params_after == result.params_before and result.parameters() == {}
    probe = {s.effect: s for s in result.outside}["tracker_rotation"]
    assert probe.fit.values[2] == pytest.approx(-0.8, abs=0.1)
    assert "tracker_rotation" in result.statement()
    entries = {c["effect"]: c for c in result.candidates()}
    assert entries["tracker_rotation"]["deciding_experiments"] == ["register"]


def test_a_curved_backbone_is_never_named_as_a_load_cell_offset_and_the_cell_reading_is_named(tmp_path):
    # Curved in the vertical plane of the horizontal endoscope: on this sweep the weight, a tilt
    # and an offset all mimic it.
    data = synthetic_validation_dataset(tmp_path, NOMINAL, NOMINAL, grid=GRID, seed=12,
                                        precurvature_per_m=(0.0, 1.2, 0.0))
    result = run_discrepancy(data, seed=1)
    assert result.verdict in ("ambiguous", "unexplained") and result.named == (), result.statement()
    probe = {s.effect: s for s in result.outside}["intrinsic_curvature"]
    assert probe.fit.values == pytest.approx([0.0, 1.2], abs=0.1)
    assert "tension_offset" in {s.effect for s in result.tied}
    best = result.tied[0].effect
    assert {"between": [best, "intrinsic_curvature"], "experiments": ["zero"], "runnable": []} in result.separations()


def test_a_tilt_with_an_offset_cap_is_never_one_confident_stand_in(tmp_path, capsys):
    truth = NOMINAL.replace({"effects.base_tilt_deg": [0.0, 1.3], "effects.tracker_offset_m": [0.0, 0.0012, 0.0]})
    folder = tmp_path / "data"
    synthetic_validation_dataset(folder, NOMINAL, truth, grid=GRID, seed=13)
    out = tmp_path / "fitted.toml"
    code = main(["discrepancy", str(folder), "--json", "--out-params", str(out)])
    answer = json.loads(capsys.readouterr().out)
    if answer["verdict"] == "effect":
        # Named only if it is the truth, both effects.
        assert code == 0 and set(answer["effects"]) == {"base_tilt", "tracker_offset"}, answer["statement"]
        return
    assert code == 3 and answer["effects"] == [] and answer["parameters"] == {}, answer["statement"]
    assert answer["candidates"] and all(c["role"] in ("tied", "stand-in", "outside the library")
                                        for c in answer["candidates"])
    # What --out-params wrote is the starting model: no stand-in in it.
    assert list(load_params(out).effects.base_tilt_deg) == [0.0, 0.0]
    assert list(load_params(out).effects.tension_offset_error_n) == [0.0] * 4
