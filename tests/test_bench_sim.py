"""``twin bench sim``: its figures name the element count they were taken at, and ``--elements``."""

import json

from twin.cli import main
from twin.sim.bench import SCALING_FACTORS, bench_sim


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_scaling_runs_each_name_their_element_count():
    figures = bench_sim(duration_s=0.02)
    runs = figures["scaling"]
    assert [run["elements"] for run in runs] == [factor * figures["elements"] for factor in SCALING_FACTORS]
    assert all(later["dofs"] > earlier["dofs"] for earlier, later in zip(runs, runs[1:]))
    assert all(run["factor_s"] > 0 and run["realtime_factor"] > 0 for run in runs)
    assert figures["scaling_realtime_ratio"] == runs[-1]["realtime_factor"] / runs[0]["realtime_factor"]


def test_elements_times_that_count_alone(capsys):
    code, out, _ = run(capsys, "bench", "sim", "--elements", "12", "--json")
    data = json.loads(out)
    assert code == 0
    assert data["elements"] == 12 and data["dofs"] > 40
    assert "scaling" not in data and "scaling_realtime_ratio" not in data


def test_too_few_elements_is_one_line_naming_the_argument(capsys):
    code, out, err = run(capsys, "bench", "sim", "--elements", "5")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "--elements 5" in err and "discs.count" in err


def test_elements_is_refused_for_other_targets(capsys):
    code, _, err = run(capsys, "bench", "env", "--elements", "40")
    assert code == 2 and "--elements 40" in err and "sim" in err
