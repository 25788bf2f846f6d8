"""``sim://``: the twin behind the real firmware, in simulated time, as a device URL scheme.

``sim://[?seed=N][&pose=horizontal|up | &base_quat=W,X,Y,Z][&events=FILE]`` opens the emulated board
(:class:`twin.device.board.EmulatedBoard`: the firmware core built for the host driving the
MuJoCo plant) through :class:`twin.device.sim_transport.SimTransport`, with the twin's fixture
(:class:`twin.device.sim_fixture.SimFixture`), its tracker probes and :attr:`Device.twin`. The
driver finds this module by name (:data:`twin.driver.url.SCHEME_MODULES`); importing it
registers the scheme and loads neither MuJoCo nor the firmware build until a device is opened.
``events`` names a JSON-lines schedule of hidden events applied to the plant at their simulated
times (:mod:`twin.sim.events`): what the device's user is not told.
"""

from __future__ import annotations

from twin.device.sim_fixture import SimFixture
from twin.device.sim_twin import SimTwin
from twin.driver.device import Device
from twin.driver.tracker import TipTracker
from twin.driver.url import POSE_KEYS, DeviceRequest, Scheme, device_arguments, register_scheme
from twin.params import Params
from twin.tracking import CallableSource

__all__ = ["open_shadow_twin", "open_sim", "sim_probe_source"]


def open_sim(request: DeviceRequest) -> Device:
    """The ``sim://`` device of ``request`` (not yet connected)."""
    url, parts = request.url, request.parts
    if parts.netloc or parts.path not in ("", "/"):
        raise ValueError(f"device URL {url!r}: sim:// takes options only, e.g. sim://?seed=3&pose=up")
    # Imported here: listing the schemes needs neither MuJoCo nor the firmware build.
    from twin.device.board import EmulatedBoard
    from twin.device.sim_transport import SimTransport

    schedule = None
    if "events" in request.options:
        from twin.sim.events import load_events

        try:
            schedule = load_events(request.options["events"], request.params)
        except ValueError as exc:
            raise ValueError(f"device URL {url!r}: {exc}") from None
    board = EmulatedBoard(request.params, seed=_seed(url, request.options, request.seed),
                          base_rotation=request.device_args["base_rotation"])
    # The fixture settles through the device so the firmware keeps ticking meanwhile.
    fixture = SimFixture(board, settle=lambda duration_s: device.wait(duration_s))
    device = Device(
        SimTransport(board, url=url, schedule=schedule),
        fixture=fixture,
        tracker=TipTracker(lambda: sim_probe_source(board.plant), settings=request.fusion),
        twin=SimTwin(board, fixture),
        **request.device_args,
    )
    return device


# The shadow twin's sensor-noise seed: a sim:// device of the same seed draws the same noise.
SHADOW_TWIN_SEED = 1


def open_shadow_twin(params: Params, base_rotation, *, seed: int = SHADOW_TWIN_SEED) -> Device:
    """The twin a shadow runs beside a device: a ``sim://`` device of ``params`` in the clamp
    orientation ``base_rotation`` (3×3) whose fixture acts at once (the device's fixture settles
    for both)."""
    from twin.device.board import EmulatedBoard
    from twin.device.sim_transport import SimTransport

    board = EmulatedBoard(params, seed=seed, base_rotation=base_rotation)
    fixture = SimFixture(board, settle=lambda duration_s: None, settle_s=0.0)
    return Device(SimTransport(board, url=f"sim://?seed={seed}"), fixture=fixture, twin=SimTwin(board, fixture),
                  **device_arguments(params, base_rotation))


def sim_probe_source(plant) -> CallableSource:
    """The twin's probe frames (held between its 40 Hz samples), as a tracking source."""

    def sample():
        frame = plant.tracker_probes()
        return frame.time_s, frame.positions_m, frame.axes

    return CallableSource(sample)


def _seed(url: str, options: dict[str, str], seed: int | None) -> int:
    """The sensor-noise seed: the URL's or the caller's (they must agree), else 0."""
    if "seed" not in options:
        return 0 if seed is None else seed
    try:
        from_url = int(options["seed"])
    except ValueError:
        raise ValueError(f"device URL {url!r}: seed = {options['seed']!r} is not a whole number") from None
    if seed is not None and seed != from_url:
        raise ValueError(f"seed = {seed!r} contradicts the URL {url!r}")
    return from_url


register_scheme(Scheme("sim", ("seed", *POSE_KEYS, "events"), open_sim))
