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
import selectors
import socket
import sys
import threading
import time

import numpy as np

from twin.device import igtl

__all__ = ["OpenIGTLinkServer", "probe_rotation", "register", "twin_messages"]

_MM_PER_M = 1e3


class OpenIGTLinkServer:
    """A TCP server sending OpenIGTLink messages to every connected client.

    Messages the clients send (Slicer sends STATUS and GET_ requests) are read and ignored, so
    their buffers never fill. A client that cannot take a message within ``send_timeout_s`` is
    dropped rather than allowed to stall the stream.

    Args:
        host: interface to listen on (``"0.0.0.0"`` for all).
        port: TCP port; 0 picks a free one (see :attr:`port`).
        send_timeout_s: longest a send to one client may block (s).

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 18944, *, send_timeout_s: float = 0.5):
        self._listener = socket.create_server((host, port), reuse_port=False)
        self._listener.setblocking(False)
        self.host, self.port = self._listener.getsockname()[:2]
        self.send_timeout_s = send_timeout_s
        self._clients: list[socket.socket] = []
        self._lock = threading.Lock()
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._listener, selectors.EVENT_READ)
        self._stop = threading.Event()
        self.sent_messages = 0
        self._thread = threading.Thread(target=self._run, name=f"igtl-server :{self.port}", daemon=True)
        self._thread.start()

    @property
    def clients(self) -> int:
        """Number of connected clients."""
        with self._lock:
            return len(self._clients)

    def send(self, messages: list[bytes]) -> int:
        """Send packed messages (:func:`twin.device.igtl.pack`) to every client, in order.

        Returns:
            The number of clients that took them.
        """
        data = b"".join(messages)
        with self._lock:
            clients = list(self._clients)
        delivered = 0
        for client in clients:
            try:
                client.sendall(data)
                delivered += 1
            except OSError:  # includes the timeout: a stalled client must not stall the stream
                self._drop(client)
        self.sent_messages += len(messages) * delivered
        return delivered

    def close(self) -> None:
        """Disconnect every client and stop listening."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        with self._lock:
            clients, self._clients = self._clients, []
        for client in clients:
            client.close()
        self._selector.close()
        self._listener.close()

    def __enter__(self) -> "OpenIGTLinkServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            for key, _ in self._selector.select(timeout=0.05):
                sock = key.fileobj
                if sock is self._listener:
                    self._accept()
                    continue
                try:
                    data = sock.recv(65536)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError:
                    data = b""
                if not data:
                    self._drop(sock)

    def _accept(self) -> None:
        try:
            client, _ = self._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client.settimeout(self.send_timeout_s)
        with self._lock:
            self._clients.append(client)
        self._selector.register(client, selectors.EVENT_READ)

    def _drop(self, client: socket.socket) -> None:
        with self._lock:
            if client not in self._clients:
                return
            self._clients.remove(client)
        try:
            self._selector.unregister(client)
        except (KeyError, ValueError):
            pass
        client.close()


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

    from twin.device.igtl_source import settings_from_options

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
    with sigterm_event() as stop, OpenIGTLinkServer(args.host, args.port) as server:
        print(f"serving OpenIGTLink on {server.host}:{server.port}", flush=True)
        frame_s = 1.0 / args.rate_hz
        start = time.monotonic()
        frames = 0
        try:
            while not stop.is_set():
                elapsed_s = time.monotonic() - start
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
                server.send(twin_messages(
                    timestamp_s=time.time(), tip_pose=plant.tip_pose(), backbone_m=plant.backbone_positions_m(),
                    probes=(frame.positions_m, frame.axes),
                    predicted_tip_pose=None if sol is None else (sol.tip_position_m, sol.tip_rotation),
                    predicted_backbone_m=None if sol is None else sol.positions_m,
                    probe_names=names, version=args.header_version))
                frames += 1
                stop.wait(max(0.0, start + frames * frame_s - time.monotonic()))
        except KeyboardInterrupt:
            pass
        print(f"stopped after {frames} frames ({time.monotonic() - start:.1f} s), "
              f"{server.sent_messages} messages sent", flush=True)
    return 0
