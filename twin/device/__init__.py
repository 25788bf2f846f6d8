"""Devices behind one interface: the rig over serial, its emulation, and the protocol between them.

Open a device by URL — ``sim://`` (the MuJoCo twin behind the real firmware, in simulated
time) or ``serial:///dev/ttyACM0`` (the rig, wall-clock time) — and use the same
:class:`Device` calls on either; :attr:`Device.clock` says how time advances. On ``sim://``
:attr:`Device.twin` (:class:`SimTwin`) gives the twin's ground truth and a fast reset.
"""

from typing import TYPE_CHECKING

from twin.lazy import lazy_exports

if TYPE_CHECKING:
    from twin.device.device import MODE_NAMES, Device
    from twin.device.errors import (ChannelCountError, CommandRejected, DeviceDisconnected, DeviceError, DeviceTimeout,
                                    ProtocolVersionError)
    from twin.device.fixture import Fixture, OperatorFixture, SimFixture
    from twin.device.sim_twin import SimTwin
    from twin.device.telemetry import DeviceInfo, Telemetry
    from twin.device.tracker import TipTracker
    from twin.device.url import SCHEMES, open_device

# name → the module that defines it, imported when the name is first used
_EXPORTS = {
    "MODE_NAMES": "twin.device.device", "Device": "twin.device.device",
    "ChannelCountError": "twin.device.errors", "CommandRejected": "twin.device.errors",
    "DeviceDisconnected": "twin.device.errors", "DeviceError": "twin.device.errors",
    "DeviceTimeout": "twin.device.errors", "ProtocolVersionError": "twin.device.errors",
    "Fixture": "twin.device.fixture", "OperatorFixture": "twin.device.fixture", "SimFixture": "twin.device.fixture",
    "SimTwin": "twin.device.sim_twin",
    "DeviceInfo": "twin.device.telemetry", "Telemetry": "twin.device.telemetry",
    "TipTracker": "twin.device.tracker",
    "SCHEMES": "twin.device.url", "open_device": "twin.device.url",
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = [
    "MODE_NAMES",
    "SCHEMES",
    "CommandRejected",
    "Device",
    "DeviceDisconnected",
    "DeviceError",
    "DeviceInfo",
    "DeviceTimeout",
    "Fixture",
    "OperatorFixture",
    "ProtocolVersionError",
    "ChannelCountError",
    "SimFixture",
    "SimTwin",
    "Telemetry",
    "TipTracker",
    "open_device",
]
