"""The experiment that decides: when static data leave candidates tied, ``twin discrepancy
--device`` runs what tells them apart on the device, appends it to the dataset and decides."""

import csv
import json

import numpy as np

from twin import effects
from twin.cli import main
from twin.data.dataset import read_dataset
from twin.driver import open_device
from twin.discrepancy.decide import DESIGNS, designs_for
from twin.experiments.protocols import nominal_calibration, run_validation
from twin.params import load_params
from twin.robots import load_robot

FRICTION = "effects.tendon_friction_coeff=0.15"
GRID = [(i, kappa, phi, mass) for i, (kappa, phi, mass) in enumerate(
    (k, p, m) for k in (13.0, 26.2) for p in (0.0, 90.0, 180.0, 270.0) for m in (0.0, 0.01))]


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr()


def test_every_effect_names_designs_that_exist_and_a_tie_runs_the_union_of_theirs():
    for effect in effects.EFFECTS.values():
        assert set(effect.deciding_experiments) <= set(DESIGNS), effect.name
    assert [d.name for d in designs_for(["tendon_friction", "stiffness"])] == ["reapproach", "tip-load"]
    assert [d.name for d in designs_for(["tracker_offset", "base_tilt"])] == ["planes"]
    assert designs_for(["no such effect"]) == []


def _sweep(folder, twin_set: dict):
    """GRID on the twin with ``twin_set`` hidden, calibrated as ``twin validate`` calibrates it."""
    params = load_params()
    with open_device("sim://", params=params.replace(twin_set) if twin_set else params) as device:
        device.connect()
        cal = nominal_calibration(params)
        device.set_calibration(gain_counts_per_n=cal["gain_counts_per_n"], offset_counts=cal["offset_counts"])
        run_validation(device, folder, params, grid=GRID, progress=False, calibration=cal)


def _older_friction_dataset(folder):
    """A friction twin's sweep as a host that does not record the sliding state would take it."""
    _sweep(folder, {"effects.tendon_friction_coeff": 0.15})
    path = folder / "measurements.csv"
    rows = list(csv.reader(open(path, newline="")))
    keep = [i for i, name in enumerate(rows[0]) if not name.startswith("slide_")]
    with open(path, "w", newline="") as f:
        csv.writer(f, lineterminator="\r\n").writerows([[r[i] for i in keep] for r in rows])


def test_on_a_friction_dataset_without_sliding_states_the_reapproach_decides_for_friction(tmp_path, capsys):
    data = tmp_path / "data"
    _older_friction_dataset(data)
    code, out = run(capsys, "discrepancy", data, "--json")
    static = json.loads(out.out)
    # Without the sliding states a stiffer backbone explains friction about as well: a tie.
    assert code == 3 and static["verdict"] in ("ambiguous", "unexplained") and static["effect"] != "tendon_friction"
    assert "stiffness" in {c["effect"] for c in static["candidates"]}

    code, out = run(capsys, "discrepancy", data, "--device", "sim://", "--twin-set", FRICTION, "--json")
    decided = json.loads(out.out)
    assert code == 0 and decided["verdict"] == "effect" and decided["effects"][0] == "tendon_friction", out.out
    assert "reapproach" in decided["decided_by"]["experiments"]
    assert "tendon_friction" in decided["decided_by"]["contenders"]
    coeff = decided["parameters"]["effects.tendon_friction_coeff"]["value"]
    assert 0.1 < coeff < 0.2
    # The older rows keep their guessed friction direction; the new ones carry the state.
    assert decided["remaining_rms_m"] < static["remaining_rms_m"] / 2
    extended = read_dataset(data)
    appended = extended["experiment"] == "decide-reapproach"
    assert appended.sum() > 0
    assert np.count_nonzero(extended["experiment"] != "validation") == decided["decided_by"]["rows_added"]
    # The appended rows carry the sliding state the older rows lack.
    assert np.isfinite(extended.sliding_state[appended]).all()
    assert np.isnan(extended.sliding_state[extended["experiment"] == "validation"]).all()


def test_when_the_static_data_decide_the_device_is_not_touched(tmp_path, capsys):
    _sweep(tmp_path / "d", {})
    rows = len(read_dataset(tmp_path / "d"))
    code, out = run(capsys, "discrepancy", tmp_path / "d", "--device", "sim://", "--json")
    result = json.loads(out.out)
    assert code == 0 and result["verdict"] == "none" and result["decided_by"] is None, out.out
    assert "the static data decide" in out.err and len(read_dataset(tmp_path / "d")) == rows


def test_twin_set_without_a_sim_device_is_refused_in_one_line(tmp_path, capsys):
    code, out = run(capsys, "discrepancy", tmp_path, "--twin-set", FRICTION)
    assert code == 2 and len(out.err.strip().splitlines()) == 1


def test_a_bad_device_url_or_hidden_setting_is_refused_before_any_work(tmp_path, capsys):
    _sweep(tmp_path / "d", {})
    for extra in (["--device", "foo://x"], ["--device", "sim://?bad=1"],
                  ["--device", "sim://", "--twin-set", "effects.no_such_key=1"]):
        code, out = run(capsys, "discrepancy", tmp_path / "d", *extra)
        assert code == 2 and len(out.err.strip().splitlines()) == 1, out.err
        assert "predicting" not in out.err and out.out == ""


def test_a_device_in_another_pose_than_the_dataset_is_refused_before_any_work(tmp_path, capsys):
    _sweep(tmp_path / "d", {})
    code, out = run(capsys, "discrepancy", tmp_path / "d", "--device", "sim://?pose=up")
    assert code == 2 and "another base pose" in out.err and len(out.err.strip().splitlines()) == 1


def test_a_deciding_experiment_the_twin_diverges_in_leaves_the_dataset_as_it_was(tmp_path, capsys, monkeypatch):
    from twin.device.sim_fixture import SimFixture

    data = tmp_path / "data"
    _older_friction_dataset(data)
    before = {name: (data / name).read_bytes() for name in ("measurements.csv", "metadata.json")}
    hang = SimFixture.hang_tip_mass
    hung = []

    def diverging(self, mass_kg):
        # Past the first configurations of the deciding experiment (their rows written), the twin
        # goes unstable as a diverging step leaves it: MuJoCo itself detects it on the next step.
        hang(self, mass_kg)
        hung.append(mass_kg)
        if len(hung) == 5:
            self._board.plant.data.qvel[:] = 1e30

    monkeypatch.setattr(SimFixture, "hang_tip_mass", diverging)
    code, out = run(capsys, "discrepancy", data, "--device", "sim://", "--twin-set", FRICTION)
    assert code == 4, out.err
    last = out.err.strip().splitlines()[-1]
    assert "a deciding experiment stopped (SimulationError: MuJoCo warned" in last and "holds none of its rows" in last
    assert "Traceback" not in out.err and out.out == ""
    assert {name: (data / name).read_bytes() for name in before} == before
    # No copy of the dataset is left beside it.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]


def test_a_deciding_experiment_whose_robot_does_not_come_to_rest_leaves_the_dataset_as_it_was(tmp_path, capsys,
                                                                                            monkeypatch):
    # Under strong friction a loaded bend can keep creeping past the wait for rest (long at μ = 0.6,
    # κ 15.72 φ 180, 20 g): the protocol stops, and the command says so in one line.
    from twin.experiments import protocols

    data = tmp_path / "data"
    _older_friction_dataset(data)
    before = {name: (data / name).read_bytes() for name in ("measurements.csv", "metadata.json")}
    wait = protocols.wait_for_rest
    calls = []

    def creeping(device, **kwargs):
        calls.append(1)
        if len(calls) == 4:  # past the first configurations of the experiment, their rows written
            raise protocols.NotAtRestError("the robot did not come to rest within 10.0 s (tip to 0.30 mm)")
        return wait(device, **kwargs)

    monkeypatch.setattr(protocols, "wait_for_rest", creeping)
    code, out = run(capsys, "discrepancy", data, "--device", "sim://", "--twin-set", FRICTION)
    assert code == 4 and len(calls) == 4, out.err
    last = out.err.strip().splitlines()[-1]
    assert "a deciding experiment stopped (NotAtRestError: the robot did not come to rest" in last
    assert "holds none of its rows" in last and "Traceback" not in out.err and out.out == ""
    assert {name: (data / name).read_bytes() for name in before} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]


def test_a_heavier_tip_whose_fall_friction_slows_is_waited_for(tmp_path):
    # The long robot bent so that it lifts its tip above the clamp (κ 15.72 1/m, φ 180°) falls
    # sideways out of its plane under the tip-load design's 20 g; tendon friction of μ 0.6 draws
    # that fall out past the validation sweep's 10 s wait for rest. The experiment waits it out.
    from types import SimpleNamespace

    from twin.discrepancy.decide import decide
    from twin.discrepancy.verdict import Verdict

    params = load_robot("long")
    hidden = params.replace({"effects.tendon_friction_coeff": 0.6})
    data = tmp_path / "data"
    cal = nominal_calibration(params)
    with open_device("sim://?seed=0", params=hidden) as device:
        device.connect()
        device.set_calibration(gain_counts_per_n=cal["gain_counts_per_n"], offset_counts=cal["offset_counts"])
        run_validation(device, data, params, grid=[(0, 15.72, 180.0, 0.0), (1, 15.72, 180.0, 0.01)],
                       progress=False, calibration=cal)
    undecided = SimpleNamespace(verdict=Verdict.UNEXPLAINED, named=(), tied=[], outside=[], rounds=[],
                                stand_ins=[SimpleNamespace(effects=("stiffness",))])
    with open_device("sim://?seed=0", params=hidden) as device:
        device.connect()
        device.set_calibration(gain_counts_per_n=cal["gain_counts_per_n"], offset_counts=cal["offset_counts"])
        decision = decide(undecided, device, data, params, progress=False, max_rounds=1,
                          run_workflow=lambda dataset: dataset)
    assert decision is not None and decision.designs == ("tip-load",) and decision.rows_added == 2
    extended = read_dataset(data)
    heavy = extended["tip_mass_kg"][extended["experiment"] == "decide-tip-load"]
    assert sorted(heavy) == [0.0, 0.02]
