"""Operator and fixture actions the experiments need, behind one small interface.

Some steps of the thesis's protocols are done by hand on the rig: hanging a mass at the tip,
clamping the reference holder around the discs, hanging calibration masses on the tendons over
the load-cell pulleys. :class:`Fixture` names them; ``device.fixture`` provides them for the
device's backend. Every action returns once the load or clamp is in place and still:

* :class:`twin.device.sim_fixture.SimFixture` (``sim://``, above the driver) acts on the twin's
  plant at once, then lets the twin run for ``settle_s`` of simulated time.
* :class:`OperatorFixture` (``serial://``) asks the operator on the console and returns when
  they press Enter. With no console to answer (stdin at its end) it stops the run with a
  :class:`FixtureUnavailable`, one line, instead of waiting for nobody.
* :class:`RemoteFixture` (``serial://…?fixture=host:port``) asks an automatic fixture over TCP:
  ``twin emulate`` serves one (:class:`twin.device.emulated_rig.FixtureServer`) that does to its
  twin what the ``sim://`` fixture does, so the rig's commands run against the emulated board with
  no person at hand. The requests are lines of JSON, ``{"action": NAME, "args": [...]}`` with
  NAME a method of :class:`Fixture` (:data:`ACTIONS`), answered ``{"ok": true}`` once the action
  is done and settled, or ``{"ok": false, "error": "…"}``.

Channel indices are 0..N-1 as everywhere in the API; messages to the operator say tendon 1..N.
"""

from __future__ import annotations

import abc
import contextlib
import json
import math
import socket
from typing import BinaryIO, Callable, ContextManager, Iterable

import numpy as np

from twin.checks import finite_vector
from twin.driver.codec import DEFAULT_CHANNELS
from twin.driver.errors import DeviceError

__all__ = ["ACTIONS", "Fixture", "FixtureUnavailable", "OperatorFixture", "RemoteFixture", "check_channels",
           "check_mass"]

# The fixture's actions, by method name: what a RemoteFixture may ask of a fixture server.
ACTIONS = ("hang_tip_mass", "apply_tip_load", "engage_holder", "release_holder", "hang_calibration_mass",
           "remove_calibration_masses")


class FixtureUnavailable(DeviceError):
    """A fixture action could not be done: no operator answers the prompt (stdin ended), or the
    automatic fixture cannot be reached or refused the action. The message names the action."""


def check_mass(name: str, value: float) -> float:
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} = {value!r}: must be finite and >= 0")
    return float(value)


def check_channels(channels: Iterable[int], count: int) -> tuple[int, ...]:
    channels = tuple(channels)
    if not channels or any(not (isinstance(c, (int, np.integer)) and 0 <= c < count) for c in channels):
        raise ValueError(f"channels = {channels!r}: expected one or more of 0..{count - 1}")
    return tuple(int(c) for c in channels)


class Fixture(abc.ABC):
    """What the operator or the fixture does to the rig during an experiment.

    Attributes:
        settle_s: device time each action gives the load or clamp to come to rest (s), for
            callers that choose it (the env: long enough at reset, none mid-episode). On the
            rig the operator decides when it is still, so :class:`OperatorFixture` ignores it.
    """

    settle_s: float = 0.0

    @abc.abstractmethod
    def hang_tip_mass(self, mass_kg: float) -> None:
        """Hang ``mass_kg`` (kg) at the tip; 0 removes it."""

    @abc.abstractmethod
    def apply_tip_load(self, force_n=(0.0, 0.0, 0.0), moment_nm=(0.0, 0.0, 0.0)) -> None:
        """Push the tip with ``force_n`` (N) and twist it with ``moment_nm`` (N·m), both world
        frame (e.g. a pulley and weight for a sideways force); zeros remove it."""

    @abc.abstractmethod
    def engage_holder(self) -> None:
        """Clamp the reference holder: the discs are held straight (for pretensioning and tares)."""

    @abc.abstractmethod
    def release_holder(self) -> None:
        """Remove the reference holder."""

    @abc.abstractmethod
    def hang_calibration_mass(self, mass_g: float, channels: Iterable[int]) -> None:
        """Hang ``mass_g`` (g; 0 = nothing) on the tendon over the load cell of each channel.

        The signature is the ``hang_mass`` protocol of :func:`twin.calibration.run_calibration`.
        """

    @abc.abstractmethod
    def remove_calibration_masses(self) -> None:
        """Take every calibration mass off; the motors drive the tendons again."""


class OperatorFixture(Fixture):
    """Fixture actions asked of the operator at the rig.

    Args:
        prompt: shows a request and returns when the operator confirms it; :func:`input` by
            default (press Enter). Tests pass a recorder.
        channels: load cells on the rig (the robot's ``tendons.count``; default the thesis
            endoscope's four).
    """

    def __init__(self, prompt: Callable[[str], object] = input, *, channels: int = DEFAULT_CHANNELS):
        self._prompt = prompt
        self._count = channels

    def hang_tip_mass(self, mass_kg: float) -> None:
        mass_kg = check_mass("mass_kg", mass_kg)
        if mass_kg > 0:
            self._ask(f"Hang {mass_kg * 1e3:g} g at the tip, let it hang still")
        else:
            self._ask("Remove any mass from the tip")

    def apply_tip_load(self, force_n=(0.0, 0.0, 0.0), moment_nm=(0.0, 0.0, 0.0)) -> None:
        force, moment = finite_vector("force_n", force_n, 3), finite_vector("moment_nm", moment_nm, 3)
        if not (force.any() or moment.any()):
            self._ask("Remove any force and moment from the tip")
            return
        self._ask(f"Apply {np.round(force, 4).tolist()} N and {np.round(moment, 5).tolist()} N·m (world frame) "
                  "at the tip, let it come to rest")

    def engage_holder(self) -> None:
        self._ask("Clamp the reference holder around the discs")

    def release_holder(self) -> None:
        self._ask("Open and remove the reference holder")

    def hang_calibration_mass(self, mass_g: float, channels: Iterable[int]) -> None:
        mass_g = check_mass("mass_g", mass_g)
        tendons = ", ".join(str(c + 1) for c in check_channels(channels, self._count))
        if mass_g > 0:
            self._ask(f"Hang {mass_g:g} g on tendon(s) {tendons} over the load-cell pulley, let it hang still")
        else:
            self._ask(f"Take any mass off tendon(s) {tendons}")

    def remove_calibration_masses(self) -> None:
        self._ask("Take all calibration masses off the tendons")

    def _ask(self, request: str) -> None:
        try:
            self._prompt(f"{request}, then press Enter: ")
        except EOFError:
            raise FixtureUnavailable(
                f"no operator to ask (stdin ended) to: {request}; run it on a console, or give the device URL "
                "fixture=host:port of an automatic fixture (twin emulate serves one)") from None


class RemoteFixture(Fixture):
    """Fixture actions done by an automatic fixture over TCP (``twin emulate``'s).

    Each action is one request on a connection kept open between actions, answered once the
    fixture has done it and let it settle (``settle_s`` of the board's time, sent along).

    Args:
        host, port: the fixture server.
        attended: a context in which the host waits on purpose (:meth:`twin.driver.Device.attended`:
            the board's watchdog is fed meanwhile); none by default.
        timeout_s: longest wait for one answer (wall s).
        settle_s: board time each action is given to come to rest (s).
    """

    def __init__(self, host: str, port: int, *, attended: Callable[[], ContextManager] | None = None,
                 timeout_s: float = 30.0, settle_s: float = 0.5):
        self.address = (host, int(port))
        self._attended = attended
        self.timeout_s = timeout_s
        self.settle_s = settle_s
        self._socket: socket.socket | None = None
        self._reader: BinaryIO | None = None

    def hang_tip_mass(self, mass_kg: float) -> None:
        self._do("hang_tip_mass", check_mass("mass_kg", mass_kg))

    def apply_tip_load(self, force_n=(0.0, 0.0, 0.0), moment_nm=(0.0, 0.0, 0.0)) -> None:
        force, moment = finite_vector("force_n", force_n, 3), finite_vector("moment_nm", moment_nm, 3)
        self._do("apply_tip_load", force.tolist(), moment.tolist())

    def engage_holder(self) -> None:
        self._do("engage_holder")

    def release_holder(self) -> None:
        self._do("release_holder")

    def hang_calibration_mass(self, mass_g: float, channels: Iterable[int]) -> None:
        self._do("hang_calibration_mass", check_mass("mass_g", mass_g), [int(c) for c in channels])

    def remove_calibration_masses(self) -> None:
        self._do("remove_calibration_masses")

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
        if self._socket is not None:
            self._socket.close()
        self._socket = self._reader = None

    def _do(self, action: str, *args) -> None:
        host, port = self.address
        where = f"fixture at {host}:{port}"
        request = (json.dumps({"action": action, "args": list(args), "settle_s": self.settle_s}) + "\n").encode()
        with self._attended() if self._attended is not None else contextlib.nullcontext():
            try:
                if self._socket is None or self._reader is None:
                    self._socket = socket.create_connection(self.address, timeout=self.timeout_s)
                    self._reader = self._socket.makefile("rb")
                self._socket.sendall(request)
                line = self._reader.readline()
            except OSError as exc:
                self.close()
                raise FixtureUnavailable(f"{where}: {action}: {exc.strerror or exc}") from None
        if not line:
            self.close()
            raise FixtureUnavailable(f"{where}: {action}: the fixture closed the connection")
        try:
            answer = json.loads(line)
        except ValueError:
            answer = {"ok": False, "error": f"not an answer: {line[:80]!r}"}
        if not answer.get("ok"):
            raise FixtureUnavailable(f"{where}: {action}: {answer.get('error', 'refused')}")
