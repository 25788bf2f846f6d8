"""The parameter seam: loading, provenance, overrides and refusal of bad values."""

import math

import pytest

from twin.params import DEFAULT_PARAMS_PATH, ParameterError, load_params, parse_override


def test_default_file_loads_with_a_source_for_every_value():
    p = load_params()
    d = p.to_dict()
    assert d["backbone"]["length_m"]["value"] == pytest.approx(0.060)
    for section, entries in d.items():
        for key, entry in entries.items():
            assert entry["source"].split(":")[0].split(" ")[0] in {
                "thesis", "assumption", "datasheet", "fitted", "default"
            }, f"{section}.{key} has no recognised source: {entry['source']!r}"


def test_required_keys_exist():
    p = load_params()
    for key in [
        "backbone.length_m", "backbone.radius_m", "backbone.youngs_modulus_pa",
        "backbone.shear_modulus_pa", "backbone.mass_kg", "backbone.torsion",
        "tendons.radius_m", "tendons.angles_deg", "discs.count", "environment.gravity_m_s2",
    ]:
        p.get(key)


def test_override_is_read_as_toml_and_marked():
    p = load_params(overrides=["backbone.shear_modulus_pa=3e6", "backbone.torsion=GJ",
                               "tendons.angles_deg=[0, 120, 240]",
                               "effects.tension_gain_error=[0,0,0]",
                               "effects.tension_offset_error_n=[0,0,0]",
                               "sensors.loadcell_offset_counts=[0,0,0]"])
    assert p.backbone.shear_modulus_pa == 3e6
    assert p.backbone.torsion == "GJ"
    assert p.tendons.angles_deg == (0.0, 120.0, 240.0)
    assert p.source("backbone.torsion") == "override"
    assert p.backbone.torsional_stiffness_nm2 == pytest.approx(3e6 * math.pi * 0.003**4 / 2)


@pytest.mark.parametrize(
    "override, names",
    [
        ("backbone.youngs_modulus_pa=-8e6", "backbone.youngs_modulus_pa"),
        ("backbone.length_m=0", "backbone.length_m"),
        ("backbone.mass_kg=nan", "backbone.mass_kg"),
        ("tendons.radius_m=0.0059", "tendons.radius_m"),
        ("backbone.torsion=XX", "backbone.torsion"),
        ("discs.count=2.5", "discs.count"),
        ("tendons.angles_deg=[0, 90]", "effects.tension_gain_error"),
        ("backbone.colour=1", "backbone.colour"),
    ],
)
def test_bad_values_are_refused_naming_key_and_value(override, names):
    with pytest.raises(ParameterError, match=names.replace(".", r"\.")):
        load_params(overrides=[override])


def test_round_trip_through_toml(tmp_path):
    p = load_params(overrides=["backbone.youngs_modulus_pa=7.5e6"])
    q = load_params(p.save(tmp_path / "p.toml"))
    assert q == p
    assert q.source("backbone.youngs_modulus_pa") == "override"


def test_parse_override_bare_word_is_string():
    assert parse_override("backbone.torsion=GJ") == ("backbone.torsion", "GJ")
    with pytest.raises(ParameterError):
        parse_override("backbone.length_m")


def test_default_path_exists():
    assert DEFAULT_PARAMS_PATH.is_file()
