"""An OpenIGTLink server of the twin: tip pose, backbone shape and the predictor's shape, for 3D Slicer.

:class:`OpenIGTLinkServer` accepts any number of clients (Slicer's OpenIGTLinkIF connects as a
client) and sends each message to all of them. :func:`twin_messages` composes one frame of the
twin: what the tracker would send (the two probes as PLUS sends them), the twin's true tip pose
and backbone, and the predictor's tip pose and backbone, so Slicer shows model and measurement
side by side. Lengths go out in millimetres, Slicer's unit; the frame is the twin's world frame,
the base at the origin.

``twin igtl-serve`` runs the twin in real time under a slow bending sweep and streams it.
"""

from __future__ import annotations

import argparse
import collections
import math
import selectors
import socket
import sys
import threading
import time
from typing import Callable

import numpy as np

from twin.driver import igtl

__all__ = ["OpenIGTLinkServer", "probe_rotation", "register", "twin_messages"]

_MM_PER_M = 1e3


class _Client:
    """One connection: its socket, the frame being written and the frames waiting behind it."""

    def __init__(self, sock: socket.socket, address, now_s: float):
        self.sock = sock
        self.address = address
        self.current = memoryview(b"")  # the rest of the frame being written: never cut mid-message
        self.queue: collections.deque[bytes] = collections.deque()
        self.progress_s = now_s  # when it last took a byte, or had nothing to take
        self.skipped_frames = 0

    @property
    def pending(self) -> bool:
        return bool(self.current) or bool(self.queue)


class OpenIGTLinkServer:
    """A TCP server sending OpenIGTLink messages to every connected client.

    Nothing a client does can slow the stream to the others: every socket is non-blocking, and
    each client has its own bounded queue of frames. A client that reads slower than frames come
    skips frames (the oldest waiting ones are dropped; a frame being written is finished first,
    so its stream stays whole); a client that takes no byte for ``send_timeout_s`` while frames
    wait is dropped. At most ``max_clients`` are served; a connection beyond that is closed at
    once. Running out of file descriptors (EMFILE) or any other failure to accept is reported
    through ``log`` and the server goes on serving the clients it has. Messages the clients send
    (Slicer sends STATUS and GET_ requests) are read and ignored, so their buffers never fill.

    Args:
        host: interface to listen on (``"0.0.0.0"`` for all).
        port: TCP port; 0 picks a free one (see :attr:`port`).
        send_timeout_s: longest a client with frames waiting may take no byte before it is
            dropped (s).
        max_clients: connections served at once; more are refused.
        queue_frames: frames a client may have waiting; beyond it its oldest are skipped.
        log: where the server reports what it refused or dropped (one line each; default stderr).

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 18944, *, send_timeout_s: float = 0.5,
                 max_clients: int = 16, queue_frames: int = 8, log: Callable[[str], None] | None = None):
        if max_clients < 1 or queue_frames < 1:
            raise ValueError(f"max_clients = {max_clients}, queue_frames = {queue_frames}: both must be >= 1")
        self._listener = socket.create_server((host, port), reuse_port=False)
        self._listener.setblocking(False)
        self.host, self.port = self._listener.getsockname()[:2]
        self.send_timeout_s = send_timeout_s
        self.max_clients = max_clients
        self.queue_frames = queue_frames
        self._log = log if log is not None else (lambda line: print(line, file=sys.stderr, flush=True))
        self._clients: dict[socket.socket, _Client] = {}
        self._lock = threading.Lock()
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._listener, selectors.EVENT_READ)
        self._accept_paused_until = 0.0
        self._said: dict[str, tuple[float, int]] = {}
        self._stop = threading.Event()
        self.sent_messages = 0  # messages handed to clients' queues, summed over clients
        self.skipped_frames = 0  # frames a slow client did not get
        self.dropped_clients = 0  # clients dropped for stalling or breaking
        self.refused_clients = 0  # connections closed at once: over max_clients or out of descriptors
        self.accept_errors = 0
        self._thread = threading.Thread(target=self._run, name=f"igtl-server :{self.port}", daemon=True)
        self._thread.start()

    @property
    def clients(self) -> int:
        """Number of connected clients."""
        with self._lock:
            return len(self._clients)

    def send(self, messages: list[bytes]) -> int:
        """Queue packed messages (:func:`twin.driver.igtl.pack`), as one frame, to every client.

        Never blocks: each client's socket takes what it can now and the rest is written as it
        drains; a client whose queue is full skips its oldest waiting frame.

        Returns:
            The number of clients the frame was queued to.
        """
        data = b"".join(messages)
        now_s = time.monotonic()
        stalled = []
        with self._lock:
            for client in self._clients.values():
                if not client.pending:
                    client.progress_s = now_s
                client.queue.append(data)
                if len(client.queue) > self.queue_frames:
                    client.queue.popleft()
                    client.skipped_frames += 1
                    self.skipped_frames += 1
                if not self._flush(client, now_s):
                    stalled.append(client)
            delivered = len(self._clients) - len(stalled)
        for client in stalled:
            self._drop(client, "stalled")
        self.sent_messages += len(messages) * delivered
        return delivered

    def close(self) -> None:
        """Disconnect every client and stop listening."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        with self._lock:
            clients, self._clients = list(self._clients.values()), {}
        for client in clients:
            client.sock.close()
        self._selector.close()
        self._listener.close()

    def __enter__(self) -> "OpenIGTLinkServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --------------------------------------------------------------------------- thread
    def _flush(self, client: _Client, now_s: float) -> bool:
        """Write what ``client`` takes without blocking (lock held); False when it is to be dropped."""
        while True:
            if not client.current:
                if not client.queue:
                    client.progress_s = now_s
                    return True
                client.current = memoryview(client.queue.popleft())
            try:
                sent = client.sock.send(client.current)
            except (BlockingIOError, InterruptedError):
                return now_s - client.progress_s <= self.send_timeout_s
            except OSError:
                return False
            client.current = client.current[sent:]
            client.progress_s = now_s

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._turn()
            except Exception as exc:  # noqa: BLE001 - the thread must outlive anything one turn meets
                self._say("error", f"{type(exc).__name__}: {exc}; still serving")
                self._stop.wait(0.05)

    def _turn(self) -> None:
        now_s = time.monotonic()
        if self._accept_paused_until and now_s >= self._accept_paused_until:
            self._accept_paused_until = 0.0
            self._selector.register(self._listener, selectors.EVENT_READ)
        with self._lock:
            for client in self._clients.values():
                events = selectors.EVENT_READ | (selectors.EVENT_WRITE if client.pending else 0)
                if self._selector.get_key(client.sock).events != events:
                    self._selector.modify(client.sock, events, client)
        stalled = []
        for key, events in self._selector.select(timeout=0.02):
            sock = key.fileobj
            if sock is self._listener:
                self._accept()
                continue
            client = key.data
            if events & selectors.EVENT_READ and not self._discard_input(client):
                stalled.append((client, "closed"))
                continue
            if events & selectors.EVENT_WRITE:
                with self._lock:
                    if not self._flush(client, time.monotonic()):
                        stalled.append((client, "stalled"))
        now_s = time.monotonic()
        with self._lock:
            stalled += [(c, "stalled") for c in self._clients.values()
                        if c.pending and now_s - c.progress_s > self.send_timeout_s]
        for client, why in stalled:
            self._drop(client, why)

    def _discard_input(self, client: _Client) -> bool:
        try:
            return bool(client.sock.recv(65536))
        except (BlockingIOError, InterruptedError):
            return True
        except OSError:
            return False

    def _accept(self) -> None:
        try:
            sock, address = self._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            # EMFILE/ENFILE/ENOBUFS/ENOMEM leave the connection in the backlog and the listener
            # readable: stop accepting for a moment instead of spinning, and say so.
            self.accept_errors += 1
            self.refused_clients += 1
            self._selector.unregister(self._listener)
            self._accept_paused_until = time.monotonic() + 0.1
            self._say("accept", f"cannot accept a connection ({exc.strerror or exc}); "
                                f"serving the {self.clients} connected, accepting again in 0.1 s")
            return
        with self._lock:
            full = len(self._clients) >= self.max_clients
        if full:
            sock.close()
            self.refused_clients += 1
            self._say("refused", f"refused {address[0]}:{address[1]}: {self.max_clients} clients already served")
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client = _Client(sock, address, time.monotonic())
        with self._lock:
            self._clients[sock] = client
        self._selector.register(sock, selectors.EVENT_READ, client)

    def _drop(self, client: _Client, why: str) -> None:
        with self._lock:
            if self._clients.pop(client.sock, None) is None:
                return
            try:
                self._selector.unregister(client.sock)
            except (KeyError, ValueError):
                pass
            client.sock.close()
        if why == "stalled":
            self.dropped_clients += 1
            self._say("dropped", f"dropped {client.address[0]}:{client.address[1]}: "
                                 f"took nothing for {self.send_timeout_s:g} s")

    def _say(self, kind: str, line: str) -> None:
        """Log ``line``, at most once a second per kind (a flood of refused connections is one
        line a second, with how many more there were)."""
        now_s = time.monotonic()
        last_s, unsaid = self._said.get(kind, (-math.inf, 0))
        if now_s - last_s < 1.0:
            self._said[kind] = (last_s, unsaid + 1)
            return
        more = f" (and {unsaid} more like it in the last second)" if unsaid else ""
        self._said[kind] = (now_s, 0)
        self._log(f"igtl-server :{self.port}: {line}{more}")


def probe_rotation(axis) -> np.ndarray:
    """A rotation (3, 3) whose z column is the unit ``axis``: how a 5-DOF probe is reported (NDI:
    the coil along the tool's z; the roll about it is arbitrary, here fixed by the world x or y)."""
    z = np.asarray(axis, dtype=float)
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _pose_message(device: str, rotation, position_m, timestamp_s: float, version: int) -> bytes:
    return igtl.pack("TRANSFORM", device, igtl.encode_transform(rotation, np.asarray(position_m) * _MM_PER_M),
                     timestamp_s=timestamp_s, version=version)


def _shape_messages(device: str, positions_m, timestamp_s: float, version: int) -> list[bytes]:
    """The backbone as a POLYDATA polyline (Slicer: a model) and as POINTs (Slicer: markups)."""
    p_mm = np.asarray(positions_m, dtype=float) * _MM_PER_M
    return [
        igtl.pack("POLYDATA", device, igtl.encode_polydata(p_mm, lines=[list(range(len(p_mm)))]),
                  timestamp_s=timestamp_s, version=version),
        igtl.pack("POINT", device + "Points", igtl.encode_point(p_mm, group=device),
                  timestamp_s=timestamp_s, version=version),
    ]


def twin_messages(
    *,
    timestamp_s: float,
    tip_pose=None,
    backbone_m=None,
    probes=None,
    predicted_tip_pose=None,
    predicted_backbone_m=None,
    probe_names: tuple[str, str] = ("Probe1ToTracker", "Probe2ToTracker"),
    version: int = 1,
) -> list[bytes]:
    """One frame of the twin as packed OpenIGTLink messages (lengths in mm).

    Device names: ``TipToTracker`` and ``ModelTipToTracker`` (TRANSFORM), ``Backbone`` and
    ``ModelBackbone`` (POLYDATA polylines), ``BackbonePoints`` and ``ModelBackbonePoints``
    (POINT), and the probes under ``probe_names`` (TRANSFORM, the probe axis as the tool's z,
    as PLUS sends an NDI Aurora 5-DOF sensor; a probe with a NaN is out of the field and not sent,
    as PLUS does).

    Args:
        timestamp_s: the frame's time (Unix seconds of the sender's clock).
        tip_pose: ``(position_m (3,), rotation (3, 3))`` of the twin's tip, or None.
        backbone_m: (n, 3) the twin's backbone points (m), base to tip, or None.
        probes: ``(positions_m (2, 3), axes (2, 3))`` of probes A and B, or None.
        predicted_tip_pose, predicted_backbone_m: the same of the predictor, or None.
        probe_names: device names of probes A and B.
        version: OpenIGTLink header version (1, or 2 for OpenIGTLink 3 clients).
    """
    out = []
    if probes is not None:
        for name, position_m, axis in zip(probe_names, *probes, strict=True):
            if np.isfinite(position_m).all() and np.isfinite(axis).all():
                out.append(_pose_message(name, probe_rotation(axis), position_m, timestamp_s, version))
    for device, pose in (("TipToTracker", tip_pose), ("ModelTipToTracker", predicted_tip_pose)):
        if pose is not None:
            out.append(_pose_message(device, pose[1], pose[0], timestamp_s, version))
    for device, shape in (("Backbone", backbone_m), ("ModelBackbone", predicted_backbone_m)):
        if shape is not None:
            out.extend(_shape_messages(device, shape, timestamp_s, version))
    return out


# --------------------------------------------------------------------------- twin igtl-serve

def register(subparsers) -> None:
    from twin.cliargs import add_param_args, add_pose_args, nonnegative, positive

    p = subparsers.add_parser(
        "igtl-serve",
        help="stream the twin (tip pose, backbone, the predictor's backbone, tracker probes) over OpenIGTLink, "
             "e.g. to 3D Slicer",
    )
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (default 127.0.0.1; 0.0.0.0 for all)")
    p.add_argument("--port", type=int, default=18944, help="TCP port (default 18944; 0 picks a free one)")
    p.add_argument("--rate-hz", type=positive, default=20.0, help="frames per second (default 20)")
    p.add_argument("--kappa", type=nonnegative, default=15.0, help="curvature of the bending sweep (1/m, default 15)")
    p.add_argument("--period-s", type=positive, default=10.0, help="one turn of the bending direction (s, default 10)")
    p.add_argument("--duration-s", type=positive, default=None,
                   help="stop after this long (s; default: until Ctrl-C or SIGTERM)")
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed of the twin")
    p.add_argument("--probes", default="Probe1ToTracker,Probe2ToTracker", help="device names of probes A and B")
    p.add_argument("--header-version", type=int, choices=(1, 2), default=1,
                   help="OpenIGTLink header version (default 1)")
    p.add_argument("--tip-force", action="store_true",
                   help="also stream the tip force estimated from the tensions and the tip pose (TipForce: an arrow "
                        "and its 95%% ellipsoid as models, the tip and the arrow's head as points)")
    add_pose_args(p)
    add_param_args(p)
    p.set_defaults(func=run_serve)


def run_serve(args: argparse.Namespace) -> int:
    """Run the twin in real time under a sweep of the bending direction and stream each frame."""
    from twin.cliargs import params_from_args, sigterm_event
    from twin.rod.grid import pcc_tensions_n
    from twin.rod.model import RodModel
    from twin.rod.solver import ConvergenceError, Predictor
    from twin.sim.plant import Plant

    from twin.driver.igtl_source import settings_from_options

    try:  # the names the tracker client would accept, checked the same way
        probes = settings_from_options({"igtl_probes": args.probes})
    except ValueError as exc:
        print(f"twin igtl-serve: --probes: {exc}", file=sys.stderr)
        return 2
    names = (probes.device_a, probes.device_b)
    params = params_from_args(args)
    plant = Plant(params, seed=args.seed)
    predictor = Predictor(RodModel.from_params(params))
    g = params.environment.gravity_m_s2
    stream = None
    if args.tip_force:
        from twin import effects
        from twin.force.stream import ForceStream, force_messages

        stream = ForceStream(params, tendon_m_per_count=1.0, base_rotation=plant.base_rotation)
    with sigterm_event() as stop, OpenIGTLinkServer(args.host, args.port) as server:
        frame_s = 1.0 / args.rate_hz
        start = None
        frames = skipped = slot = 0
        try:
            while not stop.is_set():
                elapsed_s = 0.0 if start is None else time.monotonic() - start
                if args.duration_s is not None and elapsed_s >= args.duration_s:
                    break
                tensions = pcc_tensions_n(args.kappa, 360.0 * elapsed_s / args.period_s, params)
                plant.set_tensions(tensions)
                plant.step_until(elapsed_s)
                try:
                    sol = predictor.solve(plant.true_tensions_n(), base_rotation=plant.base_rotation,
                                          tip_force_n=(0.0, 0.0, -plant.tip_mass_kg * g))
                except ConvergenceError:
                    sol = None
                frame = plant.tracker_probes()
                extra = []
                if stream is not None:
                    tip_m, tip_rotation = plant.tip_pose()
                    force = stream.estimate(elapsed_s, plant.true_tensions_n(),
                                            effects.tracked_point_m(params, tip_m, tip_rotation), tip_rotation)
                    extra = force_messages(force, timestamp_s=time.time(), version=args.header_version)
                server.send(extra + twin_messages(
                    timestamp_s=time.time(), tip_pose=plant.tip_pose(), backbone_m=plant.backbone_positions_m(),
                    probes=(frame.positions_m, frame.axes),
                    predicted_tip_pose=None if sol is None else (sol.tip_position_m, sol.tip_rotation),
                    predicted_backbone_m=None if sol is None else sol.positions_m,
                    probe_names=names, version=args.header_version))
                frames += 1
                if start is None:
                    # The first frame (the predictor's compile) is made before the clock starts and
                    # before "serving" is said, so no frames are owed and none come in a burst.
                    start = time.monotonic()
                    print(f"serving OpenIGTLink on {server.host}:{server.port}", flush=True)
                # A frame that comes late is not made up for: the schedule moves on to the slot now running.
                slot += 1
                running = int((time.monotonic() - start) / frame_s)
                if running > slot:
                    skipped, slot = skipped + running - slot, running
                stop.wait(max(0.0, start + slot * frame_s - time.monotonic()))
        except KeyboardInterrupt:
            pass
        elapsed_s = 0.0 if start is None else time.monotonic() - start
        print(f"stopped after {frames} frames ({elapsed_s:.1f} s; {skipped} late slots skipped), "
              f"{server.sent_messages} messages sent, {server.dropped_clients} clients dropped for stalling, "
              f"{server.refused_clients} refused", flush=True)
    return 0
