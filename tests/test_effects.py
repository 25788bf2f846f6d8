"""One place per effect: the registry, the keys it gives the parameter set, the composed hooks,
and a new effect that reaches the twin, the prediction and the candidate list from its own unit."""

import dataclasses
import tomllib

import numpy as np
import pytest

from twin import effects
from twin.data.prediction import predict_rows
from twin.discrepancy.candidates import UNTESTABLE_EFFECTS, candidate_library
from twin.effects import EFFECTS, PER_TENDON, Candidate, Effect, FitParameter, Key
from twin.effects.tendon_friction import FRICTION_MAX_STEP_S
from twin.params import DEFAULT_PARAMS_PATH, ParameterError, load_params
from twin.pose import HORIZONTAL, UP, rot_x, rot_y
from twin.sim.model import build_model

NOMINAL = load_params()
ALL_ON = NOMINAL.replace({
    "effects.tendon_friction_coeff": 0.1, "effects.tendon_compliance_m_per_n": 5e-5,
    "effects.tension_gain_error": [0.05, 0.0, 0.0, -0.03], "effects.tension_offset_error_n": [0.1, 0.0, -0.02, 0.0],
    "effects.disc_mass_fraction": 0.5, "effects.base_tilt_deg": [2.0, -1.0],
    "effects.tip_load_error_fraction": 0.1, "effects.tracker_offset_m": [0.001, 0.0, 0.002]})


def _entries(key: Key, value) -> list[float]:
    return list(value) if key.size is not None else [value]


def test_every_effect_key_is_in_the_parameter_set_and_off_by_default():
    for effect in EFFECTS.values():
        assert effect.description and effect.keys, effect.name
        for key in effect.uses:
            NOMINAL.get(key)
        for key in effect.parameters:
            value = NOMINAL.get(key.key)
            assert all(v == key.off for v in _entries(key, value)), (key.key, value)
            if key.size == PER_TENDON:
                assert len(value) == NOMINAL.tendons.count
            elif key.size is not None:
                assert len(value) == key.size


def test_the_registry_is_the_effects_section_of_the_parameter_set():
    declared = [k.name for k in effects.parameter_keys()]
    assert len(declared) == len(set(declared))
    assert [f.name for f in dataclasses.fields(NOMINAL.effects)] == declared
    with open(DEFAULT_PARAMS_PATH, "rb") as fh:
        assert set(tomllib.load(fh)["effects"]) == set(declared)
    assert set(UNTESTABLE_EFFECTS) == {e.name for e in EFFECTS.values() if e.untestable} == {
        "tendon_compliance", "actuation_latency", "damping", "loadcell_lag", "motor_friction", "spool_backlash"}


@pytest.mark.parametrize("key", effects.parameter_keys(), ids=lambda k: k.name)
def test_the_parameter_set_refuses_what_a_key_declares_invalid(key):
    entries = NOMINAL.tendons.count if key.size == PER_TENDON else key.size
    bad = [[key.off] * (entries + 1)] if key.size is not None else [[key.off]]
    if key.nonnegative:
        bad.append([-1.0] * entries if key.size is not None else -1.0)
    if key.choices:
        bad.append(max(key.choices) + 1.0)
    for value in bad:
        with pytest.raises(ParameterError, match=key.key.replace(".", r"\.")):
            NOMINAL.replace({key.key: value})


def test_with_every_effect_off_the_compositions_change_nothing():
    base = rot_x(0.3) @ HORIZONTAL
    gain, offset = effects.loadcell_response(NOMINAL)
    assert np.array_equal(gain, np.ones(4)) and np.array_equal(offset, np.zeros(4))
    assert np.array_equal(effects.clamp_rotation(NOMINAL, base), base)
    assert np.array_equal(effects.tracker_offset_m(NOMINAL), np.zeros(3))
    assert effects.true_tip_mass_kg(NOMINAL, 0.01) == 0.01
    assert effects.body_spec(NOMINAL) == effects.BodySpec.nominal(NOMINAL)
    assert effects.step_hooks(NOMINAL, build_model(NOMINAL)) == []


def test_the_compositions_give_what_each_effect_describes():
    e, b, d = ALL_ON.effects, ALL_ON.backbone, ALL_ON.discs
    gain, offset = effects.loadcell_response(ALL_ON)
    # The twin's load cells report (1 + g) T + o, in that order of operations.
    assert gain.tolist() == [1.0 + g for g in e.tension_gain_error]
    assert offset.tolist() == list(e.tension_offset_error_n)
    tensions = np.array([[1.2, 2.5, 0.3, 4.0], [1.35, 1.35, 1.35, 1.35]])
    assert np.allclose(effects.true_tensions_n(ALL_ON, gain * tensions + offset), tensions, rtol=0, atol=1e-14)
    assert np.array_equal(effects.true_tensions_n(ALL_ON, gain * tensions[0] + offset),
                          effects.true_tensions_n(ALL_ON, gain * tensions + offset)[0])
    tilt_x, tilt_y = np.radians(e.base_tilt_deg)
    assert np.allclose(effects.clamp_rotation(ALL_ON, UP), rot_y(tilt_y) @ rot_x(tilt_x), atol=1e-15)
    tip, rotation = np.array([0.01, 0.02, 0.05]), rot_x(0.4)
    assert np.allclose(effects.tracked_point_m(ALL_ON, tip, rotation), tip + rotation @ e.tracker_offset_m)
    assert effects.tip_force_n(ALL_ON, 0.01) == pytest.approx(
        [0.0, 0.0, -0.01 * 1.1 * ALL_ON.environment.gravity_m_s2])
    body = effects.body_spec(ALL_ON)
    assert body.line_mass_kg_per_m == pytest.approx(0.5 * b.mass_kg / b.length_m)
    assert body.disc_mass_kg == pytest.approx(d.lumped_mass_kg + 0.5 * b.mass_kg / d.count)
    assert body.line_mass_kg_per_m * b.length_m + body.disc_mass_kg * d.count == pytest.approx(
        b.mass_kg + d.lumped_mass_kg * d.count)
    assert (body.tendon_compliance_m_per_n, body.friction_coeff) == (5e-5, 0.1)
    with pytest.raises(ValueError, match="effects.disc_mass_fraction = 1.5: must be <= 1"):
        effects.body_spec(ALL_ON.replace({"effects.disc_mass_fraction": 1.5}))
    assert effects.friction_direction([0.001, -0.001, 0.0, 0.002], -1.0).tolist() == [1.0, -1.0, -1.0, 1.0]


def test_friction_finds_every_tendon_path_in_the_twin_by_name():
    model = build_model(ALL_ON)
    (hook,) = effects.step_hooks(ALL_ON, model)
    assert hook.max_step_s == FRICTION_MAX_STEP_S
    sites = hook._sites
    names = [[model.site(int(k)).name for k in row] for row in sites]
    assert len(names) == 4
    for i, row in enumerate(names):
        assert row[:2] == [f"spool{i}", f"hole{i}"]
        assert row[2:] == [f"t{i}_s{j}" for j in range(1, len(row) - 1)]
    assert len(names[0]) - 2 == sum(1 for k in range(model.nsite) if model.site(k).name.startswith("t0_s"))
    assert [model.dof_jntid[d] for d in hook._spool_dofs] == [model.joint(f"spool{i}").id for i in range(4)]


class CapLength(Effect):
    """A toy effect: a probe cap longer than the tip along the tip axis."""

    name = "cap_length"
    description = "the probe cap sits further along the tip axis"
    parameters = (Key("cap_length_m", nonnegative=True),)

    def tracker_offset_m(self, params, offset_m):
        return offset_m + np.array([0.0, 0.0, params.effects.cap_length_m])

    def candidate(self, params):
        return Candidate(self.name, (FitParameter("effects.cap_length_m", scale=1e-3),))


def test_a_new_effect_reaches_parameters_twin_prediction_and_candidates_from_its_unit(monkeypatch, tmp_path):
    monkeypatch.setitem(EFFECTS, "cap_length", CapLength())
    # A parameter file without the key has the effect off; a value is checked as declared.
    assert load_params().effects.cap_length_m == 0.0
    assert load_params().source("effects.cap_length_m") == "default: off"
    with pytest.raises(ParameterError, match=r"effects\.cap_length_m = -0\.001: must be >= 0"):
        NOMINAL.replace({"effects.cap_length_m": -0.001})
    off = load_params(NOMINAL.replace({"effects.cap_length_m": 0.0}).save(tmp_path / "p.toml"))
    on = off.replace({"effects.cap_length_m": 0.003})
    assert on.effects.cap_length_m == 0.003
    # The twin's tracker and the prediction see it through the composed hooks.
    assert np.allclose(effects.tracker_offset_m(on), [0.0, 0.0, 0.003])
    tensions = np.array([[1.35] * 4, [2.5, 1.35, 1.35, 1.35]])
    rows = (HORIZONTAL, tensions, np.zeros(2), np.zeros((2, 4)))
    tip_off, ok_off, _, _ = predict_rows(off, *rows)
    tip_on, ok_on, _, _ = predict_rows(on, *rows)
    assert ok_off.all() and ok_on.all()
    # The solved tip rotation is orthonormal to the integrator's accuracy (~1e-7).
    assert np.allclose(np.linalg.norm(tip_on - tip_off, axis=1), 0.003, rtol=0, atol=1e-9)
    # The discrepancy workflow tries it.
    library = candidate_library(on)
    assert [p.key for p in library["cap_length"].parameters] == ["effects.cap_length_m"]
    assert set(library) | set(UNTESTABLE_EFFECTS) == set(EFFECTS)


def test_a_key_claimed_twice_is_refused(monkeypatch):
    class Twin(CapLength):
        name = "cap_length_again"

    monkeypatch.setitem(EFFECTS, "cap_length", CapLength())
    monkeypatch.setitem(EFFECTS, "cap_length_again", Twin())
    with pytest.raises(ValueError, match=r"effects\.cap_length_m is declared by both"):
        effects.parameter_keys()
