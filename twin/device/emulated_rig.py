"""The whole rig emulated for a host on ``serial://`` or ``socket://``: board, EM tracker and an automatic fixture.

:class:`EmulatedRig` is what ``twin emulate`` runs: the emulated board on a pseudo-terminal or a
TCP port (:class:`twin.device.pty_board.PtyBoard`) and, beside it,

* **the tracker**: the twin's two 5-DOF probes streamed over OpenIGTLink as PLUS streams the
  rig's NDI Aurora (:class:`TrackerPublisher`: TRANSFORM messages named
  ``Probe1ToTracker``/``Probe2ToTracker``, millimetres, the probe axis as the tool's z, each
  frame at the tracker's 40 Hz of board time, stamped with the wall clock as PLUS stamps with its
  own), served by :class:`twin.device.igtl_server.OpenIGTLinkServer`;
* **the fixture**: :class:`FixtureServer`, which hangs the tip and calibration masses and clamps
  the reference holder on the twin as :class:`twin.device.sim_fixture.SimFixture` does on
  ``sim://``, asked over TCP by :class:`twin.driver.fixture.RemoteFixture`.

:attr:`EmulatedRig.url` is the device URL that uses all three, e.g.
``serial:///dev/pts/5?igtl=127.0.0.1:18944&igtl_probes=Probe1ToTracker,Probe2ToTracker&fixture=127.0.0.1:18945``:
``twin validate --device URL`` then runs the main job end to end through the serial driver,
the protocol, the OpenIGTLink client and the fusion, with no person at hand. On the rig the URL
has no ``fixture`` and the operator is asked on the console.
"""

from __future__ import annotations

import json
import socketserver
import threading
import time
from typing import TYPE_CHECKING

import numpy as np

from twin.device.sim_fixture import SimFixture
from twin.driver.fixture import ACTIONS
from twin.device.pty_board import PtyBoard
from twin.params import Params

if TYPE_CHECKING:
    from twin.device.igtl_server import OpenIGTLinkServer

__all__ = ["EmulatedRig", "FixtureServer", "PLUS_PROBE_NAMES", "TrackerPublisher"]

# The device names PLUS gives the Aurora's two tools (docs/igtl.md's PlusDeviceSet example).
PLUS_PROBE_NAMES = ("Probe1ToTracker", "Probe2ToTracker")
# Longest an action may wait for the board's thread (wall s): a tick is 5 ms.
_CALL_TIMEOUT_S = 5.0
# Longest settle an action may ask for (board s): a request is not a way to hang the server.
_MAX_SETTLE_S = 10.0


class TrackerPublisher:
    """Streams the emulated board's tracker probes over an OpenIGTLink server.

    A tick hook copies each new probe frame of the plant (40 Hz of board time) in the board's
    thread; a thread of its own sends it, so a slow client never holds up the board.

    Args:
        board: the running :class:`PtyBoard`.
        server: an :class:`twin.device.igtl_server.OpenIGTLinkServer`.
        probe_names: device names of probes A and B.
    """

    def __init__(self, board: PtyBoard, server, probe_names: tuple[str, str] = PLUS_PROBE_NAMES):
        self._board, self._server, self.probe_names = board, server, (probe_names[0], probe_names[1])
        self._frame: tuple[np.ndarray, np.ndarray] | None = None
        self._index: int | None = None
        self._ready = threading.Condition()
        self._stop = False
        self.frames = 0
        board.tick_hooks.append(self._after_tick)
        self._thread = threading.Thread(target=self._run, name="emulated tracker", daemon=True)
        self._thread.start()

    def _after_tick(self) -> None:
        frame = self._board.board.plant.tracker_probes()
        if frame.index == self._index:
            return
        self._index = frame.index
        with self._ready:
            self._frame = (frame.positions_m.copy(), frame.axes.copy())
            self._ready.notify()

    def _run(self) -> None:
        from twin.device.igtl_server import twin_messages

        while True:
            with self._ready:
                self._ready.wait_for(lambda: self._stop or self._frame is not None)
                if self._stop:
                    return
                frame, self._frame = self._frame, None
            self._server.send(twin_messages(timestamp_s=time.time(), probes=frame, probe_names=self.probe_names))
            self.frames += 1

    def close(self) -> None:
        if self._after_tick in self._board.tick_hooks:
            self._board.tick_hooks.remove(self._after_tick)
        with self._ready:
            self._stop = True
            self._ready.notify()
        self._thread.join(timeout=2.0)


class _TCPServer(socketserver.ThreadingTCPServer):
    allow_reuse_address = True
    daemon_threads = True


class FixtureServer:
    """An automatic fixture for the emulated board, over TCP (lines of JSON, see
    :mod:`twin.driver.fixture`): each action is done on the twin in the board's thread, between
    two ticks, then the server waits the request's ``settle_s`` of board time and answers.

    Args:
        board: the running :class:`PtyBoard`.
        host, port: where to listen (port 0 picks a free one: :attr:`port`).

    Attributes:
        actions: the actions done so far, ``(name, args)``, in order.
    """

    def __init__(self, board: PtyBoard, host: str = "127.0.0.1", port: int = 18945):
        self._board = board
        # The actions themselves; the settling is the server's (waiting out of the board's thread).
        self._fixture = SimFixture(board.board, settle=lambda _: None, settle_s=0.0)
        self.actions: list[tuple[str, list]] = []
        owner = self

        class Handler(socketserver.StreamRequestHandler):
            def handle(self):
                for line in self.rfile:
                    self.wfile.write((json.dumps(owner._answer(line)) + "\n").encode())

        self._server = _TCPServer((host, port), Handler)
        self.host, self.port = self._server.server_address[:2]
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.05},
                                        name=f"fixture :{self.port}", daemon=True)
        self._thread.start()

    def _answer(self, line: bytes) -> dict:
        try:
            request = json.loads(line)
            action, args = request["action"], list(request.get("args", []))
            settle_s = float(request.get("settle_s", 0.5))
        except (ValueError, KeyError, TypeError):
            return {"ok": False, "error": f"not a request: {line[:80]!r}"}
        if action not in ACTIONS:
            return {"ok": False, "error": f"action {action!r} unknown; one of {', '.join(ACTIONS)}"}
        if not 0 <= settle_s <= _MAX_SETTLE_S:
            return {"ok": False, "error": f"settle_s = {settle_s!r}: must be within 0..{_MAX_SETTLE_S:g}"}
        try:
            self._board.call(lambda: getattr(self._fixture, action)(*args), timeout_s=_CALL_TIMEOUT_S)
        except (ValueError, TypeError, RuntimeError, TimeoutError) as exc:
            return {"ok": False, "error": str(exc)}
        self.actions.append((action, args))
        self._board.wait_board_s(settle_s)
        return {"ok": True}

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(timeout=2.0)


class EmulatedRig:
    """The emulated board on a pseudo-terminal with its tracker and fixture (``twin emulate``).

    Args:
        params: parameter set of the twin (default ``models/endoscope/endoscope.toml``).
        seed: sensor-noise seed.
        base_rotation: clamp orientation (default the parameter set's).
        link_path: optional stable link to the port (:class:`PtyBoard`).
        host: interface the tracker and fixture (and the board, with ``board_port``) listen on.
        board_port: serve the board on this TCP port of ``host`` (0: a free one), reached as
            ``socket://host:port``, instead of on a pseudo-terminal (None).
        igtl_port, fixture_port: their TCP ports (0: free ones), or None for none.
        probe_names: the tracker's device names of probes A and B.

    Use as a context manager, or call :meth:`start` and :meth:`close`.
    """

    def __init__(self, params: Params | None = None, *, seed: int = 0, base_rotation=None, link_path=None,
                 host: str = "127.0.0.1", igtl_port: int | None = 18944, fixture_port: int | None = 18945,
                 probe_names: tuple[str, str] = PLUS_PROBE_NAMES, board_port: int | None = None):
        self.board = PtyBoard(params, seed=seed, base_rotation=base_rotation, link_path=link_path,
                              tcp=None if board_port is None else (host, board_port))
        self.host, self.probe_names = host, (probe_names[0], probe_names[1])
        self._ports = (igtl_port, fixture_port)
        self.igtl_server: OpenIGTLinkServer | None = None
        self.tracker: TrackerPublisher | None = None
        self.fixture: FixtureServer | None = None
        self._base_rotation = base_rotation
        self._started = False

    def start(self) -> str:
        """Plug the board and open the tracker and fixture (once: again does nothing); returns :attr:`url`."""
        from twin.device.igtl_server import OpenIGTLinkServer

        if self._started:
            return self.url
        self._started = True
        self.board.plug()
        try:
            igtl_port, fixture_port = self._ports
            if igtl_port is not None:
                self.igtl_server = OpenIGTLinkServer(self.host, igtl_port)
                self.tracker = TrackerPublisher(self.board, self.igtl_server, self.probe_names)
            if fixture_port is not None:
                self.fixture = FixtureServer(self.board, self.host, fixture_port)
        except BaseException:
            self.close()
            raise
        return self.url

    @property
    def twin(self):
        """The twin behind the port (:class:`twin.device.sim_twin.SimTwin`): ground truth for code
        in this process; read it through :meth:`PtyBoard.call` so as not to see a half-stepped plant."""
        from twin.device.sim_twin import SimTwin

        return SimTwin(self.board.board)

    @property
    def url(self) -> str:
        """The device URL of the board with the tracker and fixture served here."""
        query = []
        if self.igtl_server is not None:
            query += [f"igtl={self.host}:{self.igtl_server.port}", f"igtl_probes={','.join(self.probe_names)}"]
        if self.fixture is not None:
            query.append(f"fixture={self.host}:{self.fixture.port}")
        if self._base_rotation is not None:
            from twin.pose import matrix_to_quat

            query.append("base_quat=" + ",".join(f"{q:.12g}" for q in matrix_to_quat(np.asarray(self._base_rotation))))
        return self.board.url + ("?" + "&".join(query) if query else "")

    def close(self) -> None:
        for part in (self.tracker, self.igtl_server, self.fixture):
            if part is not None:
                part.close()
        self.tracker = self.igtl_server = self.fixture = None
        self.board.close()
        self._started = False

    def __enter__(self) -> "EmulatedRig":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
