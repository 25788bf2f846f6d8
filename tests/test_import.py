"""``twin import``: a lab's CSV of its own layout into a dataset the discrepancy workflow reads."""

from pathlib import Path

import numpy as np
import pytest

from twin.cli import main
from twin.data.dataset import read_dataset
from twin.data.importer import MapError, import_csv
from twin.robots import load_robot

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"


def test_the_worked_example_imports_free_poses_and_the_workflow_names_the_hidden_tilt(tmp_path, capsys):
    """docs/import.md: 40 free poses of the three-tendon robot in mm, raw counts and grams, taken
    on a twin whose clamp is tilted 2° about x (scripts/make_lab_example.py)."""
    out = tmp_path / "lab"
    assert main(["import", str(EXAMPLES / "lab-poses.csv"), "--map", str(EXAMPLES / "lab-map.toml"),
                 "--robot", "three-tendon", "--out", str(out)]) == 0
    assert "40 rows (40 free poses), 3 tendons, without tendon lengths" in capsys.readouterr().out
    d = read_dataset(out)
    assert d.free.all() and np.isnan(d.lengths_m).all() and d.robot == "three-tendon"
    params = load_robot("three-tendon")
    s = params.sensors
    # Row 1: cell1_raw = 120448 counts, X = 59.1263 mm, no mass; row 2 the same pose under 10 g.
    assert d.tensions_n[0, 0] == pytest.approx((120448 - s.loadcell_offset_counts[0]) / s.loadcell_gain_counts_per_n)
    assert d["tip_x_m"][0] == pytest.approx(0.0591263) and d["tip_mass_kg"][:2].tolist() == [0.0, 0.01]
    assert d["config"][:2].tolist() == [1, 1]
    # A free pose's arc goes through its tip: κ·L ≈ the bend seen, φ where the tip leans.
    kappa, phi = d.bends()
    assert np.all((kappa > 0) & (kappa < 40)) and np.all((phi >= 0) & (phi < 360))

    assert main(["discrepancy", str(out), "--report", str(tmp_path / "report")]) == 0
    text = capsys.readouterr().out
    assert "named: base_tilt" in text
    line = text.split("effects.base_tilt_deg[0] = ")[1].splitlines()[0]
    tilt = float(line.split(",")[0])
    low, high = (float(v) for v in line.split("95 % interval ")[1].split(" (")[0].split(" … "))
    assert tilt == pytest.approx(2.0, abs=0.2)
    assert low <= 2.0 <= high, line
    assert "nan" not in (tmp_path / "report" / "report.md").read_text()


def _write(tmp_path, csv_text, map_text):
    csv_path, map_path = tmp_path / "lab.csv", tmp_path / "map.toml"
    csv_path.write_text(csv_text)
    map_path.write_text(map_text)
    return csv_path, map_path


MAP = """
[tip]
columns = ["x", "y", "z"]
unit = "mm"
origin = [0.0, 0.0, 1.0]
[tension]
columns = ["t1", "t2", "t3", "t4"]
unit = "g"
[tip_mass]
value = 5
unit = "g"
[length]
columns = ["e1", "e2", "e3", "e4"]
unit = "counts"
[command]
kappa = "k"
kappa_unit = "1/mm"
phi = "p"
phi_unit = "rad"
[time]
column = "t_ms"
unit = "ms"
"""
CSV = "x,y,z,t1,t2,t3,t4,e1,e2,e3,e4,k,p,t_ms\n50,1,-9,150,140,130,120,-100,0,100,0,0.013,1.5707963267948966,250\n"


def test_units_of_every_kind_are_converted_through_the_robot(tmp_path):
    csv_path, map_path = _write(tmp_path, CSV, MAP)
    params = load_robot("endoscope")
    d = import_csv(csv_path, map_path, tmp_path / "d", params)
    g = params.environment.gravity_m_s2
    assert d.tip_positions_m[0].tolist() == pytest.approx([0.05, 0.001, -0.010])
    assert d.tensions_n[0].tolist() == pytest.approx([0.150 * g, 0.140 * g, 0.130 * g, 0.120 * g])
    assert d.lengths_m[0].tolist() == pytest.approx(np.array([-100, 0, 100, 0]) * params.rig.tendon_m_per_count)
    assert d["kappa_cmd_per_m"][0] == pytest.approx(13.0) and d["phi_cmd_deg"][0] == pytest.approx(90.0)
    assert d["tip_mass_kg"][0] == pytest.approx(0.005) and d["time_s"][0] == pytest.approx(0.25)
    assert not d.free.any()


@pytest.mark.parametrize("change, message", [
    (('unit = "mm"', 'unit = "inch"'), r"tip.unit = 'inch': unknown unit; use one of m, cm, mm, um"),
    (('kappa_unit = "1/mm"', 'kappa_unit = "1/ft"'), r"command.kappa_unit = '1/ft': unknown unit"),
    (('unit = "counts"', 'unit = "furlongs"'), r"length.unit = 'furlongs': unknown unit; use one of m, mm, um, counts"),
    (("[tip_mass]\nvalue = 5\nunit = \"g\"", ""), r"no \[tip_mass\]: the tip mass is required"),
    (('columns = ["t1", "t2", "t3", "t4"]', 'columns = ["t1", "t2", "t3"]'),
     r"tension.columns = \['t1', 't2', 't3'\]: expected 4 column names"),
    (('columns = ["x", "y", "z"]', 'columns = ["x", "y", "height"]'),
     r"tip.columns = 'height': no such column in .*lab.csv"),
    (("[time]", "[clock]"), r"unknown table\(s\) clock"),
    (('origin = [0.0, 0.0, 1.0]', 'offset = 1'), r"\[tip\] has unknown key\(s\) offset"),
])
def test_a_bad_map_is_refused_in_one_line_naming_key_and_value(tmp_path, change, message):
    csv_path, map_path = _write(tmp_path, CSV, MAP.replace(*change))
    with pytest.raises(MapError, match=message):
        import_csv(csv_path, map_path, tmp_path / "d", load_robot("endoscope"))
    assert not (tmp_path / "d").exists()


def test_the_command_line_refuses_in_one_line_and_writes_nothing(tmp_path, capsys):
    csv_path, map_path = _write(tmp_path, CSV.replace(",150,", ",heavy,"), MAP)
    out = tmp_path / "d"
    assert main(["import", str(csv_path), "--map", str(map_path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"twin import: {csv_path}: row 2, column 't1': 'heavy' is not a number"
    assert not out.exists()
    assert main(["import", str(csv_path), "--map", str(tmp_path / "none.toml"), "--out", str(out)]) == 2
    assert "--map " in capsys.readouterr().err
    # Four tension columns for the three-tendon robot: the map is for another robot.
    csv_path, map_path = _write(tmp_path, CSV, MAP)
    assert main(["import", str(csv_path), "--map", str(map_path), "--robot", "three-tendon", "--out", str(out)]) == 2
    assert "expected 3 column names" in capsys.readouterr().err
    assert not out.exists()


def test_a_tension_the_dataset_refuses_leaves_no_half_written_folder(tmp_path):
    csv_path, map_path = _write(tmp_path, CSV.replace(",150,", ",-900,"), MAP)
    with pytest.raises(ValueError, match="below -0.5 N"):
        import_csv(csv_path, map_path, tmp_path / "d", load_robot("endoscope"))
    assert not (tmp_path / "d").exists()
