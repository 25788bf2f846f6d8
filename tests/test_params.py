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


def _two_segment_arrays_removed() -> str:
    """The two-segment robot's file without its [[segments]]: the keys they set are missing."""
    from twin.robots import robot_path

    text = robot_path("two-segment").read_text()
    return text[:text.index("[[segments]]")]


SEGMENTS = """
[[segments]]
source = "test: proximal"
length_m = 0.03
discs = 5
tendons = [{ angle_deg = 0.0 }, { angle_deg = 120.0 }, { angle_deg = 240.0 }]

[[segments]]
length_m = { value = 0.03, source = "test: distal" }
discs = 5
tendons = [{ angle_deg = 60.0, radius_m = 0.0045, routing = "straight" }, { angle_deg = 180.0 }, { angle_deg = 300.0 }]
"""


def test_segments_describe_the_robot_the_arrays_do(tmp_path):
    from twin.robots import load_robot

    path = tmp_path / "two.toml"
    path.write_text(_two_segment_arrays_removed() + SEGMENTS)
    params = load_params(path)
    assert (params.backbone.length_m, params.discs.count) == (0.06, 10)
    assert params.tendons.angles_deg == (0.0, 120.0, 240.0, 60.0, 180.0, 300.0)
    assert params.tendons.end_discs == (5, 5, 5, 10, 10, 10)
    assert params == load_robot("two-segment")
    assert params.source("tendons.end_discs") == "segments: [0] test: proximal; [1] test: distal"
    # Written back as the arrays, which read as the same robot.
    assert load_params(params.save(tmp_path / "saved.toml")) == params


@pytest.mark.parametrize("change, message", [
    (("discs = 5\ntendons = [{ angle_deg = 60.0", "discs = 4\ncolour = 1\ntendons = [{ angle = 60.0"),
     "segments[1]: unknown key(s) ['colour']; a segment has length_m, discs, tendons, source; segments[1].tendons[0]: "
     "unknown key(s) ['angle']"),
    (("discs = 5\ntendons = [{ angle_deg = 60.0", "discs = 4\ntendons = [{ angle_deg = 60.0"),
     "segments[1]: 4 discs over 0.03 m are 7.5 mm apart, segments[0]'s 6 mm"),
    (("radius_m = 0.0045", "radius_m = 0.003"), "[[segments]]: tendons' radius_m 0.003 differs from tendons.radius_m = 0.0045"),
    (("length_m = 0.03\n", "length_m = -1\n"), "segments[0].length_m = -1: must be a number > 0"),
])
def test_a_wrong_segment_is_named_with_every_other_wrong_key_in_one_line(tmp_path, change, message):
    path = tmp_path / "bad.toml"
    text = (_two_segment_arrays_removed() + SEGMENTS).replace(*change, 1)
    path.write_text(text.replace("pretension_n = { value = 1.35", "pretension_n = { value = -1", 1))
    with pytest.raises(ParameterError) as info:
        load_params(path)
    text = str(info.value)
    assert message in text and "\n" not in text and "missing key" not in text
    assert "tendons.pretension_n = -1" in text  # the other wrong key, named in the same line


def test_segments_and_the_arrays_they_set_are_not_both_given(tmp_path):
    from twin.robots import robot_path

    path = tmp_path / "both.toml"
    path.write_text(robot_path("endoscope").read_text() + SEGMENTS)
    with pytest.raises(ParameterError, match=r"\[\[segments\]\] set backbone.length_m, discs.count, tendons.angles_deg: "
                                             "give them as segments or as keys, not both"):
        load_params(path)


def test_modelfiles_refuses_a_bad_parameter_file_in_one_line_and_writes_nothing(tmp_path, monkeypatch, capsys):
    import twin.robots
    from twin.sim import modelfiles

    (tmp_path / "endoscope").mkdir()
    (tmp_path / "endoscope" / "endoscope.toml").write_text(
        twin.robots.robot_path("endoscope").read_text().replace("count = { value = 10,", "count = { value = 2.5,")
        .replace("value = 0.003, source", "value = \"thick\", source", 1))
    monkeypatch.setattr(twin.robots, "MODELS_DIR", tmp_path)
    assert modelfiles.main() == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("python -m twin.sim.modelfiles: ")
    assert "discs.count = 2.5: must be a whole number" in err and "backbone.radius_m = 'thick': must be a number" in err
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["endoscope", "endoscope.toml"]


def test_the_rigs_load_cells_and_limit_must_be_ones_the_board_can_hold():
    with pytest.raises(ParameterError, match=r"rig.tension_limit_n = 30.0: must be <= sensors.loadcell_capacity_n = "
                                             r"9.80665 and <= 50 N"):
        load_params(overrides={"rig.tension_limit_n": 30.0})
    with pytest.raises(ParameterError, match=r"sensors.loadcell_gain_counts_per_n = 200000.0: must be in 100..117440"):
        load_params(overrides={"sensors.loadcell_gain_counts_per_n": 200000.0})
    five_kg = load_params(overrides={"rig.tension_limit_n": 30.0, "sensors.loadcell_capacity_n": 49.03,
                                     "sensors.loadcell_gain_counts_per_n": 9000.0})
    assert five_kg.rig.tension_limit_n == 30.0
