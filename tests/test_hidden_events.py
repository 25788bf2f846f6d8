"""Hidden events on sim:// and twin emulate: applied at their simulated time, bad files refused in one line."""

import json

import numpy as np
import pytest

from twin.cli import main
from twin.driver import open_device
from twin.params import load_params
from twin.sim.events import EventSchedule, load_events


def _write(tmp_path, *lines):
    path = tmp_path / "events.jsonl"
    path.write_text("\n".join(line if isinstance(line, str) else json.dumps(line) for line in lines) + "\n")
    return path


BAD = [
    ("{\"t_s\": -1, \"tip_mass_kg\": 0.01}", ["line 1", "t_s = -1"]),
    ("{\"t_s\": 1, \"tip_mass\": 0.01}", ["line 1", "tip_mass"]),
    ("{\"t_s\": 1, \"tip_mass_kg\": -0.01}", ["tip_mass_kg = -0.01"]),
    ("{\"t_s\": 1, \"set\": \"effects.base_tilt_deg=[1, 0]\"}", ["effects.base_tilt_deg", "cannot change"]),
    ("{\"t_s\": 1, \"set\": \"effects.tension_offset_error_n=[0, 0.1]\"}", ["tension_offset_error_n"]),
    ("{\"t_s\": 1, \"tendon_slip_m\": [0.001]}", ["tendon_slip_m", "4 finite numbers"]),
    ("{\"t_s\": 1, \"tip_mass_kg\": 0.01, \"tracker_dropout_s\": 1}", ["one event a line"]),
    ("not json", ["line 1", "not JSON"]),
]


@pytest.mark.parametrize("line, words", BAD, ids=[b[0][:40] for b in BAD])
def test_a_bad_line_is_refused_in_one_line_naming_it(tmp_path, line, words):
    path = _write(tmp_path, line)
    with pytest.raises(ValueError) as info:
        load_events(path, load_params())
    message = str(info.value)
    assert "\n" not in message
    for word in words:
        assert word in message


def test_emulate_and_sim_urls_refuse_a_bad_file_before_starting(tmp_path, capsys):
    path = _write(tmp_path, {"t_s": 1, "tip_mass_kg": "heavy"})
    assert main(["emulate", "--events", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--events" in err and "heavy" in err
    with pytest.raises(ValueError, match="events file"):
        open_device(f"sim://?events={path}")
    with pytest.raises(ValueError, match="cannot be read"):
        open_device(f"sim://?events={tmp_path / 'missing.jsonl'}")


def test_events_happen_at_their_time_on_sim(tmp_path):
    """A load-cell offset shows on its channel only from its time on; a tip mass and a dropout too."""
    path = _write(tmp_path, {"t_s": 0.4, "set": "effects.tension_offset_error_n=[0, 0.2, 0, 0]"},
                  {"t_s": 0.6, "tip_mass_kg": 0.01}, {"t_s": 0.7, "tracker_dropout_s": 0.3})
    with open_device(f"sim://?events={path}") as device:
        device.tare()
        device.wait(0.35)
        before = device.latest().tensions_n.copy()
        assert device.twin.tip_mass_kg == 0.0
        device.wait(0.1)
        after = device.latest().tensions_n
        shift = after - before
        assert shift[1] == pytest.approx(0.2, abs=0.03)
        assert np.all(np.abs(shift[[0, 2, 3]]) < 0.03)
        device.wait(0.15)
        assert device.twin.tip_mass_kg == 0.01
        device.wait(0.1)
        stamp = device.tracker.read_frame().probe_a.timestamp_s
        device.wait(0.2)
        assert device.tracker.read_frame().probe_a.timestamp_s == stamp  # no frame during the dropout
        device.wait(0.2)
        assert device.tracker.read_frame().probe_a.timestamp_s > stamp + 0.25


def test_slip_friction_and_latency_change_the_running_plant(tmp_path):
    from twin.sim.plant import Plant

    params = load_params()
    plant = Plant(params)
    events = EventSchedule([])
    from twin.sim.events import parse_event

    state = plant.loop.state
    taut = state.taut_length_m[0]
    events.apply_now(plant, parse_event({"t_s": 0, "tendon_slip_m": [0.001, 0, 0, 0]}, params))
    assert state.taut_length_m[0] == pytest.approx(taut + 0.001)
    assert not state.friction_sites
    events.apply_now(plant, parse_event({"t_s": 0, "set": "effects.tendon_friction_coeff=0.2"}, params))
    assert state.friction_sites and state.friction_coeff == pytest.approx(0.2)
    events.apply_now(plant, parse_event({"t_s": 0, "set": "effects.actuation_latency_s=0.01"}, params))
    assert state.latency_s == pytest.approx(0.01)
    assert plant.params.effects.tendon_friction_coeff == pytest.approx(0.2)
