"""A live 3D view of the endoscope in a web browser: measured and predicted backbone, tip, target,
tensions and the estimated tip force with its uncertainty, while a command or an env runs.

The view is a viser server (a three.js client bundled in the package, served over HTTP and a
websocket): the machines the twin runs on often have no display, and any browser on the network
(or an SSH tunnel) can watch. Callers hand it states with
:meth:`LiveView.show`, which only stores the newest one and returns at once; a background thread
draws at most ``rate_hz`` times a second and solves the Cosserat predictor (warm-started) for
the shown tensions, so the caller's loop is never slowed by drawing or predicting.

Example:
    >>> view = LiveView(params)                       # doctest: +SKIP
    >>> print(view.url)                               # doctest: +SKIP
    >>> view.show(backbone_m=plant.backbone_positions_m(), tensions_n=t)  # doctest: +SKIP
"""

from __future__ import annotations

import collections
import dataclasses
import sys
import threading
import time
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from twin.params import Params

__all__ = ["COLORS", "DIVERGENCE_LINES", "LiveDevice", "LiveState", "LiveView", "add_live_argument", "live_view_from_args", "show_twin"]

# RGB of each thing drawn; the page's legend names them in these colours. Colour-blind safe
# (Okabe-Ito): vermillion, blue, bluish green, reddish purple.
COLORS = {
    "measured": (213, 94, 0),
    "predicted": (0, 114, 178),
    "tip": (0, 158, 115),
    "target": (204, 121, 167),
    "force": (230, 159, 0),
}
_HEX = {name: "#%02x%02x%02x" % rgb for name, rgb in COLORS.items()}
# A shadow's divergences listed on the page, newest first.
DIVERGENCE_LINES = 5


@dataclasses.dataclass(frozen=True)
class LiveState:
    """One state to draw; every field may be None (not drawn).

    Attributes:
        backbone_m: (K, 3) measured backbone, base to tip, world frame (m): the twin's ground truth.
        tip_m: (3,) tracked tip position (m).
        target_m: (3,) target tip position (m).
        tensions_n: (4,) measured tendon tensions (N); the predictor solves for them.
        tip_mass_kg: mass hung at the tip (kg), a load of the prediction.
        label: one line of text above the tensions (e.g. the configuration or the step).
    """

    backbone_m: np.ndarray | None = None
    tip_m: np.ndarray | None = None
    target_m: np.ndarray | None = None
    tensions_n: np.ndarray | None = None
    tip_mass_kg: float = 0.0
    label: str = ""


def _quiet_viser() -> None:
    """viser announces itself with ``rich.print`` on stdout; a command's stdout is its result
    (``twin sim --json``), so rich's console goes to stderr."""
    import rich

    rich.reconfigure(stderr=True)


class LiveView:
    """A browser view of the endoscope, served on ``http://host:port``.

    Args:
        params: the parameter set of the predictor (default ``models/endoscope/endoscope.toml``);
            its backbone length places the camera.
        port: TCP port; 0 picks a free one (:attr:`url` says which).
        host: address to listen on; the default serves this machine only.
        rate_hz: most draws per second (each draw solves the predictor once, ~ms warm).
        base_rotation: clamp orientation (3, 3), body to world (default the parameter set's).
        predict: solve and draw the predicted backbone for the shown tensions.

    Raises:
        ImportError: viser is not installed (``pip install 'twin[live]'``).
    """

    def __init__(self, params: Params | None = None, *, port: int = 0, host: str = "127.0.0.1",
                 rate_hz: float = 4.0, base_rotation=None, predict: bool = True):
        import viser

        from twin import effects
        from twin.params import load_params
        from twin.rod import Predictor, RodModel

        self.params = params if params is not None else load_params()
        rotation = np.asarray(self.params.rig.base_rotation if base_rotation is None else base_rotation, float)
        self._rotation = effects.clamp_rotation(self.params, rotation)
        self._predictor = Predictor(RodModel.from_params(self.params)) if predict else None
        self._period_s = 1.0 / rate_hz
        _quiet_viser()
        self._server = viser.ViserServer(host=host, port=port, verbose=False)
        self.url = f"http://{host}:{self._server.get_port()}/"
        self._layout_scene(rotation)
        self._lock = threading.Lock()
        self._pending: LiveState | None = None
        self._last_state = LiveState()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._drawn = threading.Condition()
        self.draws = 0
        self.prediction_time_s = 0.0
        self._force = None  # the newest twin.force.stream.ForceSample shown
        # The shadow's newest divergences (twin.shadow.Divergence), newest last, and how many
        # were shown: drawn as lines of text and a label at the tip.
        self._divergences: collections.deque = collections.deque(maxlen=DIVERGENCE_LINES)
        self._divergences_seen = 0
        self._divergences_drawn = 0
        self._divergence_text: Any = None
        # Arrow length per newton (m/N): the contact range's top (0.3 N) half the backbone's length.
        self.force_m_per_n = self.params.backbone.length_m / 0.6
        self._thread = threading.Thread(target=self._run, name="twin-live", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------------------ public
    def show(self, state: LiveState | None = None, **fields) -> None:
        """Draw ``state`` (or a :class:`LiveState` of ``fields``) soon; returns at once. Only the
        newest state is kept: states shown faster than ``rate_hz`` are skipped."""
        state = state if state is not None else LiveState(**fields)
        with self._lock:
            self._pending = state
        self._wake.set()

    def show_force(self, sample) -> None:
        """Draw the tip force of a :class:`twin.force.stream.ForceSample` with the next draws: an
        arrow from the tracked tip along its observable part (:attr:`force_m_per_n` m per N) and
        its 95 % uncertainty ellipsoid at the arrow's head; returns at once."""
        with self._lock:
            self._force = sample
        self._wake.set()

    def show_divergence(self, event) -> None:
        """Show a shadow's :class:`twin.shadow.Divergence` with the next draw: a line of text
        (the newest :data:`DIVERGENCE_LINES` are listed) and its kind as a label at the tip;
        returns at once."""
        with self._lock:
            self._divergences.append(event)
            self._divergences_seen += 1
        self._wake.set()

    def follow_shadow(self, shadow) -> None:
        """Show every divergence a :class:`twin.shadow.ShadowDevice` raises."""
        shadow.subscribe(self.show_divergence)

    def follow(self, stream) -> None:
        """Show every sample of a :class:`twin.force.stream.ForceStream`."""
        stream.subscribe(self.show_force)

    def wait_drawn(self, draws: int, timeout_s: float = 10.0) -> bool:
        """Block until :attr:`draws` reaches ``draws`` (True) or ``timeout_s`` passes (False)."""
        with self._drawn:
            return self._drawn.wait_for(lambda: self.draws >= draws, timeout=timeout_s)

    def close(self) -> None:
        """Stop drawing and serving."""
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout=5.0)
        self._server.stop()

    def __enter__(self) -> "LiveView":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---------------------------------------------------------------------------- internals
    def _layout_scene(self, rotation: np.ndarray) -> None:
        scene, gui = self._server.scene, self._server.gui
        length_m = self.params.backbone.length_m
        axis = rotation[:, 2]
        middle = axis * length_m / 2
        scene.set_up_direction("+z")
        # Looking along world +y at the middle of the straight backbone (as the report's render).
        self._server.initial_camera.look_at = tuple(middle)
        self._server.initial_camera.position = tuple(middle + np.array([0.0, -2.2 * length_m, 0.4 * length_m]))
        # A backdrop behind the bending plane, as a scale.
        scene.add_grid("/scale", width=2 * length_m, height=2 * length_m, plane="xz", cell_size=0.01,
                       section_size=0.05, position=tuple(middle * np.array([1, 0, 1]) + [0.0, 0.3 * length_m, 0.0]))
        scene.add_frame("/base", axes_length=0.01, axes_radius=0.0005)
        gui.add_markdown(
            "**Endoscope twin** (grid: 1 cm cells, 5 cm sections)\n\n"
            + "".join(f"<span style='color:{_HEX[k]}'>&#9632; {text}</span><br>" for k, text in (
                ("measured", "measured backbone"), ("predicted", "predicted backbone (Cosserat; dots)"),
                ("tip", "tracked tip"), ("target", "target"))))
        self._label = gui.add_markdown("waiting for a state")
        self._bars = [gui.add_progress_bar(0.0, color="orange") for _ in range(4)]
        self._text = gui.add_markdown("")
        self._force_text: Any = None  # made with the first force shown: a page without one stays as it was
        self._handles: dict[str, Any] = {}

    def _run(self) -> None:
        next_s = 0.0
        while not self._stop.is_set():
            self._wake.wait()
            delay_s = next_s - time.monotonic()
            if delay_s > 0 and self._stop.wait(delay_s):
                break
            with self._lock:
                state, self._pending = self._pending, None
                force = self._force
                divergences = list(self._divergences) if self._divergences_seen > self._divergences_drawn else None
                self._divergences_drawn = self._divergences_seen
                self._wake.clear()
            if state is None and force is None and divergences is None:
                continue
            state = state if state is not None else self._last_state
            next_s = time.monotonic() + self._period_s
            try:
                self._last_state = state
                self._draw(state)
                self._draw_force(force)
                self._draw_divergences(divergences, state)
            except Exception as exc:  # a bad state must not end the view; say so once per state
                print(f"twin live view: could not draw ({exc})", file=sys.stderr)
            with self._drawn:
                self.draws += 1
                self._drawn.notify_all()

    def _predict(self, state: LiveState) -> np.ndarray | None:
        from twin import effects

        if self._predictor is None or state.tensions_n is None:
            return None
        tensions = np.clip(effects.true_tensions_n(self.params, np.asarray(state.tensions_n, float)), 0.0, None)
        start = time.perf_counter()
        sol = self._predictor.solve(tensions, tip_force_n=effects.tip_force_n(self.params, state.tip_mass_kg),
                                    base_rotation=self._rotation, raise_on_failure=False)
        self.prediction_time_s = time.perf_counter() - start
        if not sol.converged:
            self._predictor.reset()
            return None
        return sol.positions_m

    def _draw(self, state: LiveState) -> None:
        predicted = self._predict(state)
        # The rod is ~1 mm thick: drawn thicker so that it shows at the scale of the whole endoscope.
        thickness_m = max(2.0 * self.params.backbone.radius_m, 0.003)
        self._curve("measured", state.backbone_m, thickness_m)
        self._dots("predicted", predicted, 0.5 * thickness_m)
        self._point("tip", state.tip_m, 0.6 * thickness_m)
        self._point("target", state.target_m, 0.8 * thickness_m)
        self._label.content = state.label or " "
        if state.tensions_n is not None:
            tensions = np.asarray(state.tensions_n, float)
            limit_n = self.params.rig.tension_limit_n
            for bar, value in zip(self._bars, tensions):
                # viser's progress bar has the setter, but its typing also takes `value` from a read-only props class
                bar.value = float(np.clip(100.0 * value / limit_n, 0.0, 100.0))  # type: ignore[misc]
            self._text.content = ("tensions (N; bars: share of the "
                                  f"{limit_n:g} N limit): " + ", ".join(f"T{i + 1} {v:.2f}" for i, v in enumerate(tensions)))

    def _draw_force(self, sample) -> None:
        from twin.force.stream import uncertainty_ellipsoid
        from twin.pose import matrix_to_quat

        if sample is None:
            return
        scale = self.force_m_per_n
        tip = np.asarray(sample.tip_position_m, dtype=float)
        head = tip + scale * np.asarray(sample.force_observable_n, dtype=float)
        arrow: Any = self._handles.pop("force", None)
        if arrow is not None:
            arrow.remove()
        radius = max(self.params.backbone.radius_m, 0.0008)
        self._handles["force"] = self._server.scene.add_arrows(
            "/force", np.array([[tip, head]], dtype=np.float32), COLORS["force"], shaft_radius=radius,
            head_radius=2.5 * radius, head_length=6.0 * radius)
        axes, rotation = uncertainty_ellipsoid(sample.force_cov_n2)
        # A direction without variance (unobservable, or pinned) still gets a sliver to be seen.
        semi = np.maximum(axes * scale, 0.2 * radius)
        ellipsoid = self._node("force_uncertainty", sample, lambda: self._server.scene.add_icosphere(
            "/force_uncertainty", radius=1.0, color=COLORS["force"], subdivisions=2, opacity=0.35))
        ellipsoid.position = tuple(head)
        ellipsoid.wxyz = tuple(matrix_to_quat(rotation))
        ellipsoid.scale = tuple(float(v) for v in semi)
        norm = float(np.linalg.norm(sample.force_observable_n))
        std = np.sqrt(np.clip(np.diag(sample.force_cov_n2), 0.0, None))
        if self._force_text is None:
            self._force_text = self._server.gui.add_markdown("")
        self._force_text.content = (
            f"<span style='color:{_HEX['force']}'>&#9632; estimated tip force (arrow; 95 % ellipsoid at its head)</span>"
            f"<br>{norm * 1e3:.1f} mN (±{1.96 * std.max() * 1e3:.1f} mN, 95 %)" + (" — **contact**" if sample.contact else ""))

    def _draw_divergences(self, events, state: LiveState) -> None:
        if not events:
            return
        if self._divergence_text is None:
            self._divergence_text = self._server.gui.add_markdown("")
        lines = "<br>".join(f"{e.line().strip()}" for e in reversed(events))
        self._divergence_text.content = f"**shadow: the device parts from its twin** (newest first)<br>{lines}"
        # The newest one's kind by the tip, where the eye is.
        tip = state.tip_m if state.tip_m is not None else (None if state.backbone_m is None else state.backbone_m[-1])
        label: Any = self._handles.pop("divergence", None)
        if label is not None:
            label.remove()
        if tip is not None:
            self._handles["divergence"] = self._server.scene.add_label(
                "/divergence", f"{events[-1].kind} ({events[-1].t_s:.2f} s)", position=np.asarray(tip, dtype=float))

    def _node(self, name: str, value, make):
        """The scene node ``name``, made by ``make()`` on first use and shown; hidden (and None
        returned) while ``value`` is None."""
        handle = self._handles.get(name)
        if value is None:
            if handle is not None:
                handle.visible = False
            return None
        if handle is None:
            handle = self._handles[name] = make()
        handle.visible = True
        return handle

    def _curve(self, name: str, points_m, thickness_m: float) -> None:
        if points_m is None:
            self._node(name, None, lambda: None)
            return
        points = np.asarray(points_m, dtype=float)
        handle = self._node(name, points, lambda: self._server.scene.add_spline_catmull_rom(
            f"/{name}", points, thickness=thickness_m, color=COLORS[name], curve_type="chordal"))
        handle.points = points

    def _dots(self, name: str, points_m, size_m: float) -> None:
        # Dots, not a second tube: where prediction and measurement agree the tube would hide it.
        handle = self._handles.pop(name, None)
        if handle is not None:
            handle.remove()
        if points_m is not None:
            self._handles[name] = self._server.scene.add_point_cloud(
                f"/{name}", np.asarray(points_m, dtype=np.float32), colors=COLORS[name], point_size=size_m,
                point_shape="circle", precision="float32")

    def _point(self, name: str, position_m, radius_m: float) -> None:
        handle = self._node(name, position_m, lambda: self._server.scene.add_icosphere(
            f"/{name}", radius=radius_m, color=COLORS[name], subdivisions=2))
        if handle is not None:
            handle.position = tuple(np.asarray(position_m, dtype=float))


def show_twin(view: LiveView, twin, *, target_m=None, label: str = "") -> None:
    """Show a simulated twin's state now: its backbone and tip (ground truth) and its true
    tensions, which the view's predictor solves for.

    Args:
        view: the :class:`LiveView`.
        twin: a :class:`twin.device.sim_twin.SimTwin` (``device.twin``) or a
            :class:`twin.sim.plant.Plant` (they share these accessors).
        target_m: (3,) target tip position (m), or None.
        label: one line shown above the tensions.
    """
    view.show(backbone_m=twin.backbone_positions_m(), tip_m=twin.tip_pose()[0], target_m=target_m,
              tensions_n=twin.true_tensions_n(), tip_mass_kg=twin.tip_mass_kg, label=label)


class LiveDevice:
    """A :class:`twin.driver.Device` that also shows what its user reads: pass it where the
    device goes (a protocol, a controller) and the view follows the run.

    Only values the user asks for anyway are shown (telemetry from :meth:`latest` and
    :meth:`wait_next`, tracker frames from ``tracker.read()``), plus the twin's ground truth
    after each :meth:`wait` on ``sim://``: watching adds no command, no ping and no tracker
    sample, so a run watched gives the same data as one not watched. Everything else is the
    wrapped device's.

    Args:
        device: the device.
        view: the :class:`LiveView`.

    Attributes:
        target_m: (3,) target tip position shown with the state (m), or None.
    """

    def __init__(self, device, view: LiveView):
        self._device = device
        self._view = view
        self.target_m: np.ndarray | None = None
        self._tensions_n: np.ndarray | None = None
        self._tip_m: np.ndarray | None = None
        self._tracker = None if device.tracker is None else _LiveTracker(device.tracker, self)
        # Only sim:// has a twin; a rig (serial://, a pseudo-terminal board's host) shows the
        # tracked tip and the tensions only.
        self._twin = device.twin if device.url.split(":", 1)[0] == "sim" else None
        self._next_s = 0.0

    def __getattr__(self, name: str):
        return getattr(self._device, name)

    @property
    def tracker(self):
        return self._tracker

    def latest(self):
        return self._seen(self._device.latest())

    def wait_next(self, timeout_s: float = 1.0):
        return self._seen(self._device.wait_next(timeout_s))

    def wait(self, duration_s: float) -> None:
        self._device.wait(duration_s)
        self._publish()

    def _seen(self, sample):
        self._tensions_n = sample.tensions_n
        self._publish()
        return sample

    def _publish(self) -> None:
        # Throttled here too: the twin's backbone is read only when the view would draw it.
        now_s = time.monotonic()
        if now_s < self._next_s:
            return
        self._next_s = now_s + self._view._period_s
        if self._twin is not None:
            self._view.show(backbone_m=self._twin.backbone_positions_m(), tip_m=self._tip_m, target_m=self.target_m,
                            tensions_n=self._tensions_n, tip_mass_kg=self._twin.tip_mass_kg)
        else:
            self._view.show(tip_m=self._tip_m, target_m=self.target_m, tensions_n=self._tensions_n)


class _LiveTracker:
    """A tracker whose fused frames also go to a :class:`LiveDevice`'s view."""

    def __init__(self, tracker, device: LiveDevice):
        self._tracker = tracker
        self._device = device

    def __getattr__(self, name: str):
        return getattr(self._tracker, name)

    def read(self):
        result = self._tracker.read()
        if result.pose is not None:
            self._device._tip_m = result.pose.position_m
            self._device._publish()
        return result


def add_live_argument(parser) -> None:
    """``--live [PORT]`` on a command's parser (``args.live``: None, or the port; 0 picks one)."""
    parser.add_argument("--live", nargs="?", type=int, const=0, default=None, metavar="PORT",
                        help="serve a live 3D view of the endoscope on http://127.0.0.1:PORT (default a free "
                             "port; the URL is printed); needs pip install 'twin[live]'")


def live_view_from_args(args, params: Params, *, base_rotation=None, command: str) -> LiveView | None:
    """The :class:`LiveView` that ``--live`` asks for (None without it); its URL goes to stderr.

    Raises:
        SystemExit: viser is not installed (the message says how to install it).
    """
    if getattr(args, "live", None) is None:
        return None
    try:
        view = LiveView(params, port=args.live, base_rotation=base_rotation)
    except ImportError as exc:
        raise SystemExit(f"twin {command}: --live needs viser ({exc}); pip install 'twin[live]'") from None
    print(f"twin {command}: live view at {view.url}", file=sys.stderr, flush=True)
    return view
