"""The rig driver: the protocol, the transports, :class:`Device`, its telemetry, fixture and tracker client.

Open a device by URL (:func:`open_device`) — ``serial:///dev/ttyACM0`` (the rig),
``socket://host:port`` or ``rfc2217://host:port`` (a board over the network), or ``sim://`` (the
MuJoCo twin behind the real firmware, in simulated time, added by :mod:`twin.device` above) —
and use the same :class:`Device` calls on any; :attr:`Device.clock` says how time advances. On
``sim://`` :attr:`Device.twin` gives the twin's ground truth and a fast reset.

This package sits below the twin: it imports neither :mod:`twin.sim`, MuJoCo nor Numba (the
tracker fusion loads its Numba kernels on the first fusion), so a host on the rig needs neither.
"""

from twin.driver.device import MODE_NAMES, Device
from twin.driver.errors import (ChannelCountError, CommandRejected, DeviceDisconnected, DeviceError, DeviceTimeout,
                                ProtocolVersionError)
from twin.driver.fixture import Fixture, OperatorFixture
from twin.driver.telemetry import DeviceInfo, Telemetry
from twin.driver.tracker import TipTracker
from twin.driver.url import open_device, register_scheme, schemes

__all__ = [
    "MODE_NAMES",
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
    "register_scheme",
    "schemes",
]
