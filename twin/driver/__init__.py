"""Devices behind one interface: the rig over serial, its emulation, and the protocol between them.

Open a device by URL — ``sim://`` (the MuJoCo twin behind the real firmware, in simulated
time) or ``serial:///dev/ttyACM0`` (the rig, wall-clock time) — and use the same
:class:`Device` calls on either; :attr:`Device.clock` says how time advances. On ``sim://``
:attr:`Device.twin` (:class:`SimTwin`) gives the twin's ground truth and a fast reset.
"""

from twin.driver.device import MODE_NAMES, Device
from twin.driver.errors import (ChannelCountError, CommandRejected, DeviceDisconnected, DeviceError, DeviceTimeout,
                                ProtocolVersionError)
from twin.driver.fixture import Fixture, OperatorFixture
from twin.driver.telemetry import DeviceInfo, Telemetry
from twin.driver.tracker import TipTracker
from twin.driver.url import SCHEMES, open_device

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
    "Telemetry",
    "TipTracker",
    "open_device",
]
