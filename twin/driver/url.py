"""Device URLs → devices, through a registry of schemes.

As in pyserial's ``serial_for_url``, a scheme is a name and a function that builds the device
(:class:`Scheme`, :func:`register_scheme`), and the modules that add schemes are named in
:data:`SCHEME_MODULES` and imported when a URL first asks for a scheme not yet known: the driver
names the twin's module without importing it, so a host on the rig never loads the twin.

The driver's own schemes reach a board through pyserial (``serial.serial_for_url``), in
wall-clock time:

``serial://<path>``
    A board on a serial port: ``serial:///dev/ttyACM0``, or the pseudo-terminal printed by
    ``twin emulate`` (which prints the whole URL, its tracker and fixture included).
``socket://<host>:<port>``
    A board whose serial bytes are served raw over TCP (``twin emulate --tcp PORT``, or ser2net
    in raw mode in front of the rig's port).
``rfc2217://<host>:<port>``
    A serial port shared over the network by an RFC 2217 server (ser2net in telnet mode,
    pyserial's ``rfc2217_server.py``).

Each takes ``?igtl=host:port[&igtl_…][&cap_…]``, ``&fixture=host:port`` and ``&pose=… | &base_quat=…``.
``fixture`` names an automatic fixture (:class:`twin.driver.fixture.RemoteFixture`; ``twin
emulate`` serves one) that hangs the masses and clamps the holder; without it the operator is
asked on the console. ``igtl`` names the OpenIGTLink server of the EM tracker (PLUS); without
it ``device.tracker`` is None. With it: ``igtl_probes=Probe1ToTracker,Probe2ToTracker``
(device names of probes A and B), ``igtl_axis=z`` (tool axis along the probe, e.g. ``-z``),
``igtl_scale=mm`` (length unit), ``igtl_clock=auto`` (or the server clock minus ours, s),
``igtl_timeout_s=5`` (see :func:`twin.driver.igtl_source.settings_from_options`), and the cap
calibration (:class:`twin.tracking.CapCalibration`): ``cap_a_mm=x,y,z`` and
``cap_a_axis=x,y,z`` for probe A in the tip frame, ``cap_b_mm``, ``cap_b_axis`` for B.

``sim://[?seed=N][&pose=…][&events=FILE]`` is the twin behind the real firmware in simulated
time, registered by :mod:`twin.device.sim_url` above the driver.

Rooms above the driver may also add query keys that every scheme takes (:class:`Wrapper`,
:func:`register_wrapper`, found through :data:`WRAPPER_MODULES` when a URL uses a key its scheme
does not know): ``shadow=1`` (or ``shadow=PATH``, ``&shadow_warmup_s=S``) runs any device with
a calibrated twin in lockstep beside it (:mod:`twin.shadow.url`).

``pose`` / ``base_quat`` give the clamp's orientation (body → world; the twin is built in it, the
rig is mounted so); default the parameter set's ``rig.base_quat``. It is
:attr:`Device.base_rotation`: what datasets record and predictions use.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import urllib.parse
from typing import Any, Callable

from twin.driver import codec
from twin.driver.device import Device
from twin.driver.fixture import Fixture, OperatorFixture, RemoteFixture
from twin.driver.igtl_source import URL_KEYS as IGTL_KEYS
from twin.driver.igtl_source import OpenIGTLinkSource, settings_from_options
from twin.driver.serial_transport import SerialTransport
from twin.driver.tracker import TipTracker
from twin.params import Params, load_params
from twin.pose import base_rotation_from
from twin.tracking import CapCalibration, FusionSettings

__all__ = ["POSE_KEYS", "SCHEME_MODULES", "WRAPPER_MODULES", "DeviceRequest", "Scheme", "Wrapper", "device_arguments",
           "open_device", "register_scheme", "register_wrapper", "schemes"]

_CAP_KEYS = {"cap_a_mm": "position_a_m", "cap_a_axis": "axis_a", "cap_b_mm": "position_b_m", "cap_b_axis": "axis_b"}
# The query keys every scheme takes.
POSE_KEYS = ("pose", "base_quat")


@dataclasses.dataclass(frozen=True)
class DeviceRequest:
    """What a scheme's opener is given: the URL taken apart and what every device shares.

    Attributes:
        url: the URL as given.
        parts: ``urllib.parse.urlsplit(url)``.
        options: the query's keys and values, each key one the scheme declared.
        params: the parameter set.
        seed: the caller's sensor-noise seed (None: not given); schemes without noise refuse one.
        prompt: how the operator is asked for fixture actions.
        device_args: keyword arguments of :class:`Device` every scheme passes on (timeouts, the
            tension limit, the clamp orientation, tendon count, load-cell gain, m per count).
        fusion: the tracker fusion's noise settings of the parameter set.
    """

    url: str
    parts: urllib.parse.SplitResult
    options: dict[str, str]
    params: Params
    seed: int | None
    prompt: Callable[[str], object]
    device_args: dict[str, Any]
    fusion: FusionSettings


@dataclasses.dataclass(frozen=True)
class Scheme:
    """One device URL scheme.

    Attributes:
        name: the scheme, without ``://``.
        keys: the query keys it takes (any other is refused, naming these).
        open: builds the device (not yet connected); a bad URL is a ValueError naming it.
    """

    name: str
    keys: tuple[str, ...]
    open: Callable[[DeviceRequest], Device]


@dataclasses.dataclass(frozen=True)
class Wrapper:
    """Query keys that every scheme takes, handled above the driver.

    Attributes:
        name: what the wrapper is (one of a name is kept).
        keys: its query keys; a URL with any of them has its device passed through ``wrap``.
        wrap: gets the opened device and the request, returns the device to hand out (the same
            one, or another in its place); a bad value is a ValueError naming the URL.
    """

    name: str
    keys: tuple[str, ...]
    wrap: Callable[[Device, DeviceRequest], Device]


_SCHEMES: dict[str, Scheme] = {}
_WRAPPERS: dict[str, Wrapper] = {}
# Modules that register wrappers when imported, loaded only when a URL has a key its scheme lacks.
WRAPPER_MODULES: list[str] = ["twin.shadow.url"]
# Modules that register more schemes when imported, named rather than imported (pyserial's
# ``protocol_handler_packages``): the twin's rooms sit above the driver. Append your own.
SCHEME_MODULES: list[str] = ["twin.device.sim_url"]
_LOADED: set[str] = set()


def register_scheme(scheme: Scheme) -> None:
    """Make ``scheme.name://`` URLs open through ``scheme`` (replacing one of that name)."""
    _SCHEMES[scheme.name] = scheme


def register_wrapper(wrapper: Wrapper) -> None:
    """Make ``wrapper.keys`` valid on every scheme's URLs (replacing a wrapper of that name)."""
    _WRAPPERS[wrapper.name] = wrapper


def _load_scheme_modules(until: str | None = None) -> None:
    for module in SCHEME_MODULES:
        if until is not None and until in _SCHEMES:
            return
        if module not in _LOADED:
            importlib.import_module(module)
            _LOADED.add(module)


def schemes() -> dict[str, Scheme]:
    """Every scheme known, by name (the modules of :data:`SCHEME_MODULES` imported first)."""
    _load_scheme_modules()
    return dict(_SCHEMES)


def _query(url: str, scheme: Scheme, query: str) -> dict[str, str]:
    pairs = urllib.parse.parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query))
    options = dict(pairs)
    if set(options) - set(scheme.keys):
        for module in WRAPPER_MODULES:
            importlib.import_module(module)
    known = [*scheme.keys, *(key for wrapper in _WRAPPERS.values() for key in wrapper.keys)]
    unknown = sorted(set(options) - set(known))
    if unknown or len(options) != len(pairs):
        raise ValueError(
            f"device URL {url!r}: options {', '.join(unknown) or 'repeated'} not understood; "
            f"{scheme.name}:// takes {', '.join(known)}"
        )
    return options


def device_arguments(params: Params, base_rotation, *, robot: str | None = None, command_timeout_s: float = 0.5,
                     keepalive_s: float | None = 0.1, queue_size: int = 4096) -> dict[str, Any]:
    """The keyword arguments of :class:`Device` that come from the parameter set: the tension
    limit the board drives with (:meth:`Device.enable` sends it), the tendon count, load-cell
    gain, length per encoder count and motors the board is checked against and told, and the
    clamp orientation (3×3)."""
    return dict(command_timeout_s=command_timeout_s, keepalive_s=keepalive_s, queue_size=queue_size,
                tension_limit_n=params.rig.tension_limit_n, base_rotation=base_rotation,
                tendons=params.tendons.count, robot=robot,
                loadcell_gain_counts_per_n=params.sensors.loadcell_gain_counts_per_n,
                tendon_m_per_count=params.rig.tendon_m_per_count,
                motors=codec.SetMotors(params.rig.motor_stall_force_n, params.rig.motor_no_load_speed_m_per_s,
                                       params.rig.motor_reflected_mass_kg))


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
        url: ``sim://…``, ``serial://…``, ``socket://…``, ``rfc2217://…`` or any registered
            scheme (see the module docstring).
        params: parameter set of the twin (``sim://``) and of the tracker fusion noise
            (default ``models/endoscope/endoscope.toml``).
        seed: sensor-noise seed of the twin; the URL's ``seed`` is used if this is None, and
            0 if neither is given.
        prompt: how the operator is asked for fixture actions on a board without an automatic fixture.
        command_timeout_s, keepalive_s, queue_size: see :class:`Device`.
        robot: the robot's name, for the message refusing a board with another channel count
            than its ``tendons.count`` (see :meth:`Device.connect`).

    Raises:
        ValueError: an unknown scheme or option, a bad option value, or a seed given twice
            with different values.
    """
    parts = urllib.parse.urlsplit(url)
    _load_scheme_modules(until=parts.scheme)
    scheme = _SCHEMES.get(parts.scheme)
    if scheme is None:
        raise ValueError(f"device URL {url!r}: scheme {parts.scheme!r} unknown; use one of "
                         + ", ".join(f"{s}://" for s in schemes()))
    options = _query(url, scheme, parts.query)
    params = params if params is not None else load_params()
    device_args = device_arguments(params, _pose(url, options, params), robot=robot,
                                   command_timeout_s=command_timeout_s, keepalive_s=keepalive_s,
                                   queue_size=queue_size)
    request = DeviceRequest(url, parts, options, params, seed, prompt, device_args, FusionSettings.from_params(params))
    device = scheme.open(request)
    for wrapper in _WRAPPERS.values():
        if any(key in options for key in wrapper.keys):
            device = wrapper.wrap(device, request)
    return device


def _open_port(request: DeviceRequest) -> Device:
    """A board through pyserial: ``serial://`` a local port, ``socket://`` and ``rfc2217://`` one
    over the network."""
    url, parts, options = request.url, request.parts, request.options
    if parts.scheme == "serial":
        port = parts.netloc + parts.path
        if not port:
            raise ValueError(f"device URL {url!r}: no port; e.g. serial:///dev/ttyACM0")
    else:
        if parts.path not in ("", "/"):
            raise ValueError(f"device URL {url!r}: {parts.scheme}:// takes host:port only, "
                             f"e.g. {parts.scheme}://127.0.0.1:7000")
        host, port_number = _host_port(url, parts.netloc, "address")
        # pyserial's URL, without the query keys that are ours.
        port = f"{parts.scheme}://{host}:{port_number}"
    if request.seed is not None:
        raise ValueError(f"seed = {request.seed!r}: only sim:// devices take a seed, not {url!r}")
    tracker = _igtl_tracker(url, options, request.fusion)

    def ask(text: str) -> object:
        # The operator may take longer than the watchdog timeout; the host is alive meanwhile.
        with device.attended():
            return request.prompt(text)

    fixture: Fixture
    if "fixture" in options:
        host, fixture_port = _host_port(url, options["fixture"], "fixture")
        fixture = RemoteFixture(host, fixture_port, attended=lambda: device.attended())
    else:
        fixture = OperatorFixture(ask, channels=request.params.tendons.count)
    device = Device(SerialTransport(port, url=url), fixture=fixture, tracker=tracker, **request.device_args)
    return device


for _name in ("serial", "socket", "rfc2217"):
    register_scheme(Scheme(_name, ("igtl", *IGTL_KEYS, *_CAP_KEYS, "fixture", *POSE_KEYS), _open_port))


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
    cap: dict[str, Any] = {}
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
