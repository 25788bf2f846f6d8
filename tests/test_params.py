"""The parameter seam: loading, provenance, overrides and refusal of bad values."""

import math
import re

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


@pytest.mark.parametrize("source", ["measured\non the rig", "tab\tand bell\x07", 'quote " and back\\slash',
                                    "\x7f delete and \u00e9 accents", "line\r\nend"])
def test_a_source_with_any_text_round_trips(tmp_path, source):
    # Before: a newline or control character in a source wrote a file that could not be read.
    p = load_params().replace({"backbone.youngs_modulus_pa": 7.5e6}, source=source)
    q = load_params(p.save(tmp_path / "p.toml"))
    assert q == p and q.source("backbone.youngs_modulus_pa") == source


def test_parse_override_bare_word_is_string():
    assert parse_override("backbone.torsion=GJ") == ("backbone.torsion", "GJ")
    with pytest.raises(ParameterError):
        parse_override("backbone.length_m")


def test_default_path_exists():
    assert DEFAULT_PARAMS_PATH.is_file()


def _file_with(tmp_path, key, value_text):
    """The default parameter file with ``key``'s value replaced by the TOML text ``value_text``."""
    section, name = key.split(".")
    lines, current = [], None
    for line in DEFAULT_PARAMS_PATH.read_text().splitlines():
        if line.startswith("["):
            current = line.strip("[]")
        elif current == section and line.startswith(f"{name} = {{ value = "):
            line = re.sub(r"value = [^,]+,", f"value = {value_text},", line, count=1)
        lines.append(line)
    path = tmp_path / "params.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("key", ["sim.elements", "discs.count", "rig.encoder_counts_per_rev", "solver.steps"])
@pytest.mark.parametrize("text, shown", [
    ("inf", "inf"), ("-inf", "-inf"), ("nan", "nan"), ("1e300", "1e+300"), ("2.5", "2.5"), ("true", "True"),
    ("99999999999999999999", "99999999999999999999"), ('"10"', "'10'"),
])
def test_integer_parameters_refuse_what_is_no_count_naming_file_key_and_value(tmp_path, key, text, shown):
    path = _file_with(tmp_path, key, text)
    with pytest.raises(ParameterError) as info:
        load_params(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {key} = {shown}: must be a whole number"), message


@pytest.mark.parametrize("value", ["1e300", "2147483648", "-1e12"])
def test_integer_overrides_out_of_range_are_refused_naming_key_and_value(value):
    with pytest.raises(ParameterError, match=r"solver\.steps = .*: must be a whole number within ±2147483647"):
        load_params(overrides=[f"solver.steps={value}"])


def test_an_error_from_a_parameter_file_names_the_file(tmp_path):
    path = _file_with(tmp_path, "backbone.length_m", "-0.06")
    with pytest.raises(ParameterError, match=re.escape(f"{path}: backbone.length_m = -0.06: must be > 0")):
        load_params(path)


@pytest.mark.parametrize("content, reason", [
    (bytes(range(256)) * 4, "not a TOML parameter file (byte 129 is not UTF-8 text"),
    ('[backbone]\nlength_m = { value = 0.06, source = "caf\xe9" }\n'.encode("latin-1"), "is not UTF-8 text"),
    (b"\0" * 64, "not a TOML parameter file (not valid TOML"),
    (b"a parameter file, honestly\n", "not a TOML parameter file (not valid TOML"),
    (b"backbone = 3\n", "[backbone] must be a table of keys"),
])
def test_a_file_that_is_not_a_toml_parameter_file_is_one_error_naming_it(tmp_path, content, reason):
    path = tmp_path / "weird.toml"
    path.write_bytes(content)
    with pytest.raises(ParameterError) as info:
        load_params(path)
    assert str(info.value).startswith(f"{path}: ") and reason in str(info.value)


@pytest.mark.parametrize("content, expected", [
    (bytes(range(256)), "not a TOML parameter file"),
    (None, "cannot read it"),
])
def test_the_cli_reports_a_bad_parameter_file_in_one_line(tmp_path, capsys, content, expected):
    from twin.cli import main

    path = tmp_path / "p.toml"
    if content is not None:
        path.write_bytes(content)
    assert main(["predict", "--tensions", "1,0,0,0", "--params", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("twin: parameter error: ") and str(path) in err
    assert expected in err


def test_a_bad_description_is_refused_with_every_inconsistent_key_named_at_once():
    with pytest.raises(ParameterError) as info:
        load_params(overrides={"tendons.angles_deg": [0.0, 120.0, 240.0], "tendons.radius_m": 0.01,
                               "discs.count": 40})
    message = str(info.value)
    for key in ("tendons.radius_m", "discs.thickness_m", "sensors.loadcell_offset_counts",
                "effects.tension_gain_error", "sim.elements"):
        assert key in message, message
    with pytest.raises(ParameterError) as info:
        load_params(overrides={"backbone.mass_kg": -1.0, "sim.elements": 0, "rig.base_quat": [0, 0, 0, 0]})
    assert all(key in str(info.value) for key in ("backbone.mass_kg", "sim.elements", "rig.base_quat"))
