"""The interval-coverage measurement (scripts/interval_coverage.py) on a reduced set of hidden
twin cases: it runs, reports each fitted value against the truth, and its widened interval
(with the split-to-split scatter) is never narrower than the statistical one."""

import importlib.util
import re
from pathlib import Path

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "interval_coverage.py"


def load():
    spec = importlib.util.spec_from_file_location("interval_coverage", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_coverage_reports_every_fitted_value_and_widens_by_the_split_scatter(capsys):
    code = load().main(["2", "--splits", "2", "--seed", "5"])
    out = capsys.readouterr().out
    rows = [line.split("|")[1:-1] for line in out.splitlines() if re.match(r"\| \d+ \|", line)]
    # Case 0 is a tilt (two angles), case 1 a friction coefficient.
    assert [r[1].strip() for r in rows] == ["base_tilt", "base_tilt", "tendon_friction"]
    for r in rows:
        z, z_wide = float(r[5]), float(r[7])
        assert abs(z_wide) <= abs(z) + 1e-9 and (abs(z) <= 1.96) == (r[6].strip() == "yes")
    assert "coverage of the 95 % intervals over 3 parameters" in out
    assert code in (0, 1) and (code == 0) == ("with the split scatter (goal 90%)" in out and
                                              float(re.search(r"(\d+)% with the split", out).group(1)) >= 90)


def test_bad_arguments_are_one_line(capsys):
    assert load().main(["0"]) == 2
    assert load().main(["2", "--splits", "1"]) == 2
    assert capsys.readouterr().err.count("\n") == 2
