"""Hidden events: changes made to a running twin at set simulated times, which the host is not told of.

A schedule is a JSON-lines file, one event a line, applied to the plant when its simulated time
(:attr:`twin.sim.plant.Plant.time_s`, s since the plant was built or reset) reaches ``t_s``::

    {"t_s": 8.3, "tip_mass_kg": 0.01}                        a mass hung at the tip (nominal kg)
    {"t_s": 9.0, "tip_force_n": [0.05, 0, 0]}                a push or contact at the tip (N, world frame)
    {"t_s": 17.1, "set": "effects.tendon_friction_coeff=0.15"}  an effect's parameter changes
    {"t_s": 24.6, "set": "effects.tension_offset_error_n=[0,0.1,0,0]"}
    {"t_s": 30.0, "tendon_slip_m": [0.0005, 0, 0, 0]}       tendons slip on their spools (m, + paid out)
    {"t_s": 31.0, "tracker_dropout_s": 0.5}                  the EM tracker sends no frame for 0.5 s
    {"t_s": 32.0, "tracker_jump_m": [0.002, 0, 0]}           the probes jump (m, tip frame: a probe moved
                                                              in its cap, a field distortion)

``set`` takes the effects that can change while the rig runs (:data:`RUNTIME_KEYS`): load-cell
offset and gain errors, tendon friction and actuation latency. A tendon slip lengthens the
tendon's spring by the slip (its tension falls by stiffness × slip) while its encoder goes on
counting the spool: what a tendon slipping round its spool does. Everything is checked when the
file is read (:func:`load_events`), one line naming the line and value on bad input.

The same :class:`EventSchedule` serves ``sim://?events=FILE`` (applied between the simulated
ticks, :class:`ScheduledTransport`) and ``twin emulate --events FILE`` (applied in the board's
thread after each tick, within 5 ms of ``t_s``).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from twin import effects
from twin.params import ParameterError, Params, parse_override

__all__ = ["KINDS", "RUNTIME_KEYS", "EventSchedule", "HiddenEvent", "load_events", "parse_event"]

# The event keys of a line and what each is.
KINDS = {
    "tip_mass_kg": "mass hung at the tip (kg, nominal)",
    "tip_force_n": "force at the tip (3 numbers, N, world frame)",
    "set": "an effect's parameter, section.key=value",
    "tendon_slip_m": "slip of each tendon on its spool (one number per tendon, m, + paid out)",
    "tracker_dropout_s": "how long the EM tracker sends no frame (s)",
    "tracker_jump_m": "jump of the tracked probes (3 numbers, m, tip frame)",
}
# The parameters a running plant can change: those the plant loop reads every step.
RUNTIME_KEYS = ("effects.tension_offset_error_n", "effects.tension_gain_error", "effects.tendon_friction_coeff",
                "effects.actuation_latency_s")


@dataclasses.dataclass(frozen=True)
class HiddenEvent:
    """One scheduled change.

    Attributes:
        t_s: simulated time at which it happens (s).
        kind: one of :data:`KINDS`.
        value: the kind's value: a float (kg, s), a (3,) or (n,) array, or for ``set`` the pair
            (key, value).
    """

    t_s: float
    kind: str
    value: Any

    def to_dict(self) -> dict:
        if self.kind == "set":
            key, value = self.value
            return {"t_s": self.t_s, "set": f"{key}={json.dumps(value)}"}
        value = self.value.tolist() if isinstance(self.value, np.ndarray) else self.value
        return {"t_s": self.t_s, self.kind: value}


def _vector(where: str, name: str, value: Any, size: int) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        array = np.zeros(0)
    if array.shape != (size,) or not np.isfinite(array).all():
        raise ValueError(f"{where}: {name} = {value!r}: expected {size} finite numbers")
    return array


def parse_event(entry: Any, params: Params, where: str = "event") -> HiddenEvent:
    """A :class:`HiddenEvent` from a decoded line, checked against the robot of ``params``.

    Raises:
        ValueError: one line naming ``where``, the key and the value.
    """
    if not isinstance(entry, dict):
        raise ValueError(f"{where}: {entry!r}: expected an object such as {{\"t_s\": 8.3, \"tip_mass_kg\": 0.01}}")
    t_s = entry.get("t_s")
    if isinstance(t_s, bool) or not isinstance(t_s, (int, float)) or not (math.isfinite(t_s) and t_s >= 0):
        raise ValueError(f"{where}: t_s = {t_s!r}: expected a simulated time >= 0 (s)")
    kinds = [key for key in entry if key != "t_s"]
    unknown = [key for key in kinds if key not in KINDS]
    if unknown or len(kinds) != 1:
        raise ValueError(f"{where}: {'keys ' + ', '.join(unknown) + ' not understood' if unknown else 'one event a line'}; "
                         f"an event is t_s and one of {', '.join(KINDS)}")
    kind = kinds[0]
    value = entry[kind]
    n = params.tendons.count
    if kind in ("tip_mass_kg", "tracker_dropout_s"):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{where}: {kind} = {value!r}: expected a finite number >= 0")
        return HiddenEvent(float(t_s), kind, float(value))
    if kind in ("tip_force_n", "tracker_jump_m"):
        return HiddenEvent(float(t_s), kind, _vector(where, kind, value, 3))
    if kind == "tendon_slip_m":
        return HiddenEvent(float(t_s), kind, _vector(where, kind, value, n))
    if not isinstance(value, str):
        raise ValueError(f"{where}: set = {value!r}: expected \"section.key=value\"")
    try:
        key, setting = parse_override(value)
    except ParameterError as exc:
        raise ValueError(f"{where}: {exc}") from None
    if key not in RUNTIME_KEYS:
        raise ValueError(f"{where}: set = {value!r}: {key} cannot change while the twin runs; "
                         f"these can: {', '.join(RUNTIME_KEYS)}")
    try:
        effects.plant_dynamics(params.replace({key: setting}))
    except (ParameterError, ValueError) as exc:
        raise ValueError(f"{where}: set = {value!r}: {str(exc).splitlines()[0]}") from None
    return HiddenEvent(float(t_s), kind, (key, setting))


def load_events(path: str | Path, params: Params) -> "EventSchedule":
    """The schedule of a JSON-lines file (blank lines and lines starting with # skipped).

    Raises:
        ValueError: the file cannot be read, or a line is not a valid event (one line naming
            the file, the line number and the value).
    """
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ValueError(f"events file {str(path)!r}: cannot be read: {exc.strerror or exc}") from None
    events = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        where = f"events file {str(path)!r} line {number}"
        try:
            entry = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{where}: not JSON ({exc.msg})") from None
        events.append(parse_event(entry, params, where))
    return EventSchedule(events)


class EventSchedule:
    """Hidden events in time order, applied to one plant as its time passes.

    Args:
        events: the events (any order; applied by ``t_s``, ties in the given order).

    Attributes:
        applied: the events applied so far, in order.
    """

    def __init__(self, events: list[HiddenEvent]):
        self.events = sorted(events, key=lambda e: e.t_s)
        self.applied: list[HiddenEvent] = []
        self._next = 0
        self._dropout_end_s = math.inf
        self._friction: Any = None  # a friction attached at run time lives as long as the plant

    @property
    def next_time_s(self) -> float:
        """Simulated time (s) of the next change: an event or a dropout's end; inf for none."""
        pending = self.events[self._next].t_s if self._next < len(self.events) else math.inf
        return min(pending, self._dropout_end_s)

    def apply_due(self, plant) -> list[HiddenEvent]:
        """Apply to ``plant`` the events due at its time now (within 1 ns); returns them."""
        now_s = plant.time_s + 1e-9
        if now_s >= self._dropout_end_s:
            self._dropout_end_s = math.inf
            s = plant.loop.state
            # The tracker resumes at its next period: frames in between are lost, not caught up.
            s.tracker_index = int(math.floor(plant.time_s * s.tracker_rate_hz)) - 1
            s.next_tracker_s = (s.tracker_index + 1) / s.tracker_rate_hz
        done = []
        while self._next < len(self.events) and self.events[self._next].t_s <= now_s:
            event = self.events[self._next]
            self._next += 1
            self._apply(plant, event)
            done.append(event)
        self.applied.extend(done)
        return done

    def apply_now(self, plant, event: HiddenEvent) -> None:
        """Apply ``event`` to ``plant`` now, whatever its time (a dropout then lasts its
        duration from now)."""
        if event.kind == "tracker_dropout_s":
            event = dataclasses.replace(event, t_s=plant.time_s)
        self._apply(plant, event)
        self.applied.append(event)

    def _apply(self, plant, event: HiddenEvent) -> None:
        s = plant.loop.state
        n = plant.tendon_count
        if event.kind == "tip_mass_kg":
            plant.set_tip_mass_kg(event.value)
        elif event.kind == "tip_force_n":
            plant.set_tip_load(event.value, plant.tip_load[1])
        elif event.kind == "tracker_dropout_s":
            s.next_tracker_s = math.inf
            self._dropout_end_s = event.t_s + event.value
        elif event.kind == "tracker_jump_m":
            for k in range(len(s.probe_position_m) // 3):
                for axis in range(3):
                    s.probe_position_m[3 * k + axis] += float(event.value[axis])
        elif event.kind == "tendon_slip_m":
            for i in range(n):
                slip = float(event.value[i])
                s.taut_length_m[i] += slip
                s.slack_length_m[i] += slip
                plant.model.tendon_lengthspring[i, 1] += slip
            s.jump = 1
        else:
            self._set(plant, *event.value)

    def _set(self, plant, key: str, value: Any) -> None:
        params = plant.params.replace({key: value}, source="hidden event")
        s = plant.loop.state
        n = plant.tendon_count
        if key in ("effects.tension_offset_error_n", "effects.tension_gain_error"):
            gain, offset_n = effects.loadcell_response(params)
            for i in range(n):
                s.loadcell_gain[i] = float(gain[i])
                s.loadcell_offset_n[i] = float(offset_n[i])
        elif key == "effects.actuation_latency_s":
            s.latency_s = effects.plant_dynamics(params).actuation_latency_s
        elif key == "effects.tendon_friction_coeff":
            if s.friction_sites:
                s.friction_coeff = float(value)
            elif value > 0:
                friction = effects.EFFECTS["tendon_friction"].step_hook(params, plant.model)
                friction.attach(s)  # type: ignore[union-attr]  # a coefficient > 0 makes one
                self._friction = friction
        plant.params = params
