"""Device URLs → devices: ``sim://`` (the twin) and ``serial://`` (the rig, or an emulated board
on a pseudo-terminal).

``sim://[?seed=N][&pose=horizontal|up | &base_quat=W,X,Y,Z][&events=FILE]``
    The emulated board (:class:`twin.device.board.EmulatedBoard`) in simulated time; ``events``
    names a JSON-lines schedule of hidden events applied to its plant (:mod:`twin.sim.events`).
``serial://<path>[?igtl=host:port[&igtl_…][&cap_…]][&fixture=host:port][&pose=… | &base_quat=…]``
    A board on a serial port: ``serial:///dev/ttyACM0``, or the pseudo-terminal printed by
    ``twin emulate`` (which prints the whole URL, its tracker and fixture included). ``fixture``
    names an automatic fixture (:class:`twin.device.fixture.RemoteFixture`; ``twin emulate``
    serves one) that hangs the masses and clamps the holder; without it the operator is asked
    on the console. ``igtl`` names the OpenIGTLink server of the EM tracker (PLUS); without
    it ``device.tracker`` is None. With it: ``igtl_probes=Probe1ToTracker,Probe2ToTracker``
    (device names of probes A and B), ``igtl_axis=z`` (tool axis along the probe, e.g. ``-z``),
    ``igtl_scale=mm`` (length unit), ``igtl_clock=auto`` (or the server clock minus ours, s),
    ``igtl_timeout_s=5`` (see :func:`twin.device.igtl_source.settings_from_options`), and the cap
    calibration (:class:`twin.tracking.CapCalibration`): ``cap_a_mm=x,y,z`` and
    ``cap_a_axis=x,y,z`` for probe A in the tip frame, ``cap_b_mm``, ``cap_b_axis`` for B.

``shadow=1`` (or ``shadow=PATH``) on either runs the device with a calibrated twin in lockstep
beside it (:class:`twin.shadow.ShadowDevice`, the same parameters): divergences are named on the
console (and appended to the JSON-lines file PATH); code written for a device runs unchanged.
``shadow_warmup_s`` is the device time it learns the noise over first (default 60 s).

``pose`` / ``base_quat`` give the clamp's orientation (body → world; the twin is built in it, the
rig is mounted so); default the parameter set's ``rig.base_quat``. It is
:attr:`Device.base_rotation`: what datasets record and predictions use.
"""

from __future__ import annotations

import math
import urllib.parse
from typing import Callable

from twin.device.device import Device
from twin.device.fixture import OperatorFixture, RemoteFixture, SimFixture
from twin.device.igtl_source import URL_KEYS as IGTL_KEYS
from twin.device.igtl_source import OpenIGTLinkSource, settings_from_options
from twin.device.serial_transport import SerialTransport
from twin.device.sim_twin import SimTwin
from twin.device.tracker import TipTracker, sim_probe_source
from twin.params import Params, load_params
from twin.pose import base_rotation_from
from twin.tracking import CapCalibration, FusionSettings

__all__ = ["SCHEMES", "open_device", "open_shadow_twin"]

SCHEMES = ("sim", "serial")
_CAP_KEYS = {"cap_a_mm": "position_a_m", "cap_a_axis": "axis_a", "cap_b_mm": "position_b_m", "cap_b_axis": "axis_b"}
_QUERY_KEYS = {"sim": ("seed", "pose", "base_quat", "events", "shadow", "shadow_warmup_s"),
               "serial": ("igtl", *IGTL_KEYS, *_CAP_KEYS, "fixture", "pose", "base_quat", "shadow", "shadow_warmup_s")}


def _query(url: str, scheme: str, query: str) -> dict[str, str]:
    pairs = urllib.parse.parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query))
    options = dict(pairs)
    unknown = sorted(set(options) - set(_QUERY_KEYS[scheme]))
    if unknown or len(options) != len(pairs):
        raise ValueError(
            f"device URL {url!r}: options {', '.join(unknown) or 'repeated'} not understood; "
            f"{scheme}:// takes {', '.join(_QUERY_KEYS[scheme])}"
        )
    return options


def open_device(
    url: str,
    *,
    params: Params | None = None,
    seed: int | None = None,
    prompt: Callable[[str], object] = input,
    command_timeout_s: float = 0.5,
    keepalive_s: float | None = 0.1,
    queue_size: int = 4096,
    robot: str | None = None,
) -> Device:
    """A :class:`Device` for ``url``, not yet connected (use ``with`` or call ``connect()``).

    Args:
        url: ``sim://…`` or ``serial://…`` (see the module docstring).
        params: parameter set of the twin (``sim://``) and of the tracker fusion noise
            (default ``models/endoscope/endoscope.toml``).
        seed: sensor-noise seed of the twin; the URL's ``seed`` is used if this is None, and
            0 if neither is given.
        prompt: how the operator is asked for fixture actions on ``serial://``.
        command_timeout_s, keepalive_s, queue_size: see :class:`Device`.
        robot: the robot's name, for the message refusing a board with another channel count
            than its ``tendons.count`` (see :meth:`Device.connect`).

    Raises:
        ValueError: an unknown scheme or option, a bad option value, or a seed given twice
            with different values.
    """
    parts = urllib.parse.urlsplit(url)
    if parts.scheme not in SCHEMES:
        raise ValueError(f"device URL {url!r}: scheme {parts.scheme!r} unknown; use one of "
                         + ", ".join(f"{s}://" for s in SCHEMES))
    options = _query(url, parts.scheme, parts.query)
    params = params if params is not None else load_params()
    settings = FusionSettings.from_params(params)
    # The parameter set's tension limit is what the board drives with: Device.enable sends it.
    device_args = dict(command_timeout_s=command_timeout_s, keepalive_s=keepalive_s, queue_size=queue_size,
                       tension_limit_n=params.rig.tension_limit_n, base_rotation=_pose(url, options, params),
                       tendons=params.tendons.count, robot=robot,
                       loadcell_gain_counts_per_n=params.sensors.loadcell_gain_counts_per_n,
                       tendon_m_per_count=params.rig.tendon_m_per_count)

    if parts.scheme == "sim":
        if parts.netloc or parts.path not in ("", "/"):
            raise ValueError(f"device URL {url!r}: sim:// takes options only, e.g. sim://?seed=3&pose=up")
        # Imported here: a host on the rig needs neither MuJoCo nor the firmware build.
        from twin.device.board import EmulatedBoard
        from twin.device.sim_transport import SimTransport

        schedule = None
        if "events" in options:
            from twin.sim.events import load_events

            try:
                schedule = load_events(options["events"], params)
            except ValueError as exc:
                raise ValueError(f"device URL {url!r}: {exc}") from None
        board = EmulatedBoard(params, seed=_seed(url, options, seed), base_rotation=device_args["base_rotation"])
        # The fixture settles through the device so the firmware keeps ticking meanwhile.
        fixture = SimFixture(board, settle=lambda duration_s: device.wait(duration_s))
        device = Device(
            SimTransport(board, url=url, schedule=schedule),
            fixture=fixture,
            tracker=TipTracker(lambda: sim_probe_source(board.plant), settings=settings),
            twin=SimTwin(board, fixture),
            **device_args,
        )
        return _shadowed(device, options, params, url)

    path = parts.netloc + parts.path
    if not path:
        raise ValueError(f"device URL {url!r}: no port; e.g. serial:///dev/ttyACM0")
    if seed is not None:
        raise ValueError(f"seed = {seed!r}: only sim:// devices take a seed, not {url!r}")
    tracker = _igtl_tracker(url, options, settings)

    def ask(request: str) -> object:
        # The operator may take longer than the watchdog timeout; the host is alive meanwhile.
        with device.attended():
            return prompt(request)

    if "fixture" in options:
        host, port = _host_port(url, options["fixture"], "fixture")
        fixture = RemoteFixture(host, port, attended=lambda: device.attended())
    else:
        fixture = OperatorFixture(ask, channels=params.tendons.count)
    device = Device(SerialTransport(path, url=url), fixture=fixture, tracker=tracker, **device_args)
    return _shadowed(device, options, params, url)


def open_shadow_twin(params: Params, base_rotation, *, seed: int = 1) -> Device:
    """The twin a shadow runs beside a device: a ``sim://`` device of ``params`` in the clamp
    orientation ``base_rotation`` whose fixture acts at once (the device's fixture settles for both)."""
    from twin.device.board import EmulatedBoard
    from twin.device.sim_transport import SimTransport

    board = EmulatedBoard(params, seed=seed, base_rotation=base_rotation)
    fixture = SimFixture(board, settle=lambda duration_s: None, settle_s=0.0)
    return Device(SimTransport(board, url=f"sim://?seed={seed}"), fixture=fixture, twin=SimTwin(board, fixture),
                  tension_limit_n=params.rig.tension_limit_n, base_rotation=base_rotation,
                  tendons=params.tendons.count, loadcell_gain_counts_per_n=params.sensors.loadcell_gain_counts_per_n,
                  tendon_m_per_count=params.rig.tendon_m_per_count)


def _shadowed(device: Device, options: dict[str, str], params: Params, url: str):
    """``device``, or with ``shadow`` in the URL the device with its twin beside it."""
    value = options.get("shadow", "0")
    if value in ("0", ""):
        if "shadow_warmup_s" in options:
            raise ValueError(f"device URL {url!r}: shadow_warmup_s configures the shadow; give shadow=1 too")
        return device
    from twin.shadow import ShadowDevice

    warmup = options.get("shadow_warmup_s", "60")
    try:
        warmup_s = float(warmup)
    except ValueError:
        warmup_s = math.nan
    if not (math.isfinite(warmup_s) and warmup_s > 0):
        raise ValueError(f"device URL {url!r}: shadow_warmup_s = {warmup!r}: expected a time > 0 (s)")
    return ShadowDevice(device, open_shadow_twin(params, device.base_rotation), params, warmup_s=warmup_s,
                        log_path=None if value == "1" else value)


def _seed(url: str, options: dict[str, str], seed: int | None) -> int:
    if "seed" not in options:
        return 0 if seed is None else seed
    try:
        from_url = int(options["seed"])
    except ValueError:
        raise ValueError(f"device URL {url!r}: seed = {options['seed']!r} is not a whole number") from None
    if seed is not None and seed != from_url:
        raise ValueError(f"seed = {seed!r} contradicts the URL {url!r}")
    return from_url


def _pose(url: str, options: dict[str, str], params: Params):
    """The clamp orientation (3×3) of the URL's ``pose`` or ``base_quat``, else the parameter set's."""
    if "pose" in options and "base_quat" in options:
        raise ValueError(f"device URL {url!r}: give pose or base_quat, not both")
    try:
        if "pose" in options:
            return base_rotation_from(pose=options["pose"])
        if "base_quat" in options:
            return base_rotation_from(quat=[float(v) for v in options["base_quat"].split(",")])
    except ValueError as exc:
        key = "pose" if "pose" in options else "base_quat"
        raise ValueError(f"device URL {url!r}: {key} = {options[key]!r}: {exc}") from None
    return params.rig.base_rotation


def _host_port(url: str, value: str, key: str = "igtl") -> tuple[str, int]:
    host, _, port = value.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"device URL {url!r}: {key} = {value!r}: expected host:port, e.g. 127.0.0.1:18944")
    return host, int(port)


def _igtl_tracker(url: str, options: dict[str, str], settings: FusionSettings) -> TipTracker | None:
    """The URL's OpenIGTLink tracker, or None without ``igtl``; every value checked here, before
    anything connects."""
    extra = [key for key in (*IGTL_KEYS, *_CAP_KEYS) if key in options]
    if "igtl" not in options:
        if extra:
            raise ValueError(f"device URL {url!r}: {', '.join(extra)} configure the tracker; give igtl=host:port too")
        return None
    host, port = _host_port(url, options["igtl"])
    try:
        igtl_settings = settings_from_options(options)
    except ValueError as exc:
        raise ValueError(f"device URL {url!r}: {exc}") from None
    cap = {}
    for key, field in _CAP_KEYS.items():
        if key in options:
            try:
                values = [float(v) for v in options[key].split(",")]
            except ValueError:
                values = []
            if len(values) != 3:
                raise ValueError(f"device URL {url!r}: {key} = {options[key]!r}: expected 3 numbers, e.g. 0,-3,2")
            if key.endswith("_mm"):
                cap[field] = tuple(v * 1e-3 for v in values)
            else:  # a typed direction need not be unit length to the 6 digits the calibration checks
                norm = math.sqrt(sum(v * v for v in values))
                cap[field] = tuple(v / norm for v in values) if norm > 0 else tuple(values)
    try:
        calibration = CapCalibration(**cap)
    except ValueError as exc:
        keys = ", ".join(f"{k} = {options[k]!r}" for k in _CAP_KEYS if k in options)
        raise ValueError(f"device URL {url!r}: {keys}: {exc}") from None
    return TipTracker(lambda: OpenIGTLinkSource(host, port, settings=igtl_settings),
                      calibration=calibration, settings=settings)
