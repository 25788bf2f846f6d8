"""What can go wrong between the host and a board, as exceptions that subclass built-ins.

Every one is a :class:`DeviceError`, itself an :class:`IOError` (``OSError``), so callers can
catch the family or one member; messages name the device URL and the value at fault.
"""

from __future__ import annotations

from twin.driver import codec

__all__ = ["ChannelCountError", "CommandRejected", "DeviceDisconnected", "DeviceError", "DeviceTimeout",
           "ProtocolVersionError"]


class DeviceError(IOError):
    """A device could not be opened, talked to, or did not do what was asked."""


class DeviceTimeout(DeviceError, TimeoutError):
    """An answer or a telemetry sample did not arrive in time (in the device's clock)."""


class DeviceDisconnected(DeviceError, ConnectionError):
    """The board went away (unplugged, reset, pseudo-terminal closed). The telemetry received
    before stays readable through :meth:`twin.driver.Device.drain` and ``latest()``."""


class ProtocolVersionError(DeviceError):
    """The board speaks another protocol version than this host. It was sent a DISABLE, in
    case it understands one, and nothing else.

    Attributes:
        board_version: the version in the board's HELLO_REPLY.
        host_version: :data:`twin.driver.codec.PROTOCOL_VERSION`.
    """

    def __init__(self, url: str, board_version: int, host_version: int = codec.PROTOCOL_VERSION):
        super().__init__(
            f"{url}: board speaks protocol version {board_version}, this host speaks {host_version}; "
            "sent it DISABLE and refused to go on; flash the firmware that matches this twin (firmware/README.md)"
        )
        self.board_version = board_version
        self.host_version = host_version


class ChannelCountError(DeviceError):
    """The board drives another number of motors than the robot has tendons. It was sent a
    DISABLE and nothing else.

    Attributes:
        board_channels: the channel count in the board's HELLO_REPLY.
        tendons: the robot's tendon count (``tendons.count``).
    """

    def __init__(self, url: str, board_channels: int, tendons: int, robot: str | None = None):
        name = "the robot" if robot is None else f"robot {robot!r}"
        super().__init__(f"board at {url} has {board_channels} channels; {name} has {tendons} tendons")
        self.board_channels = board_channels
        self.tendons = tendons


# Why the board refuses a command, in terms of what the caller should do about it.
_NACK_HINTS = {
    codec.NackError.UNKNOWN_TYPE: "the board does not know this message type",
    codec.NackError.BAD_LENGTH: "the payload length or channel count does not match the board's",
    codec.NackError.BAD_VALUE: "a value is not finite, out of range, a load cell to tare is stale, "
                               "or pairs mode on an odd count of tendons",
    codec.NackError.WRONG_MODE: "setpoints for another mode than the active one (call set_mode first)",
    codec.NackError.NOT_ENABLED: "setpoints are accepted only while enabled (call enable first)",
    codec.NackError.NOT_WHILE_ENABLED: "tare and calibration are refused while enabled (call disable first)",
    codec.NackError.NO_HANDSHAKE: "enable needs a HELLO of the board's protocol version first",
    codec.NackError.NOT_CALIBRATED: "tension mode needs set_calibration first",
}


class CommandRejected(DeviceError):
    """The board answered a command with NACK.

    Attributes:
        command: the refused message (a :mod:`twin.driver.codec` message).
        seq: the command's sequence number.
        error: the board's :class:`twin.driver.codec.NackError` (or the raw code if unknown).
    """

    def __init__(self, url: str, command: codec.Message, seq: int, error: int):
        try:
            error = codec.NackError(error)
            reason = f"{error.name} ({_NACK_HINTS[error]})"
        except ValueError:
            reason = f"unknown error code {error}"
        super().__init__(f"{url}: board rejected {codec.MsgType(command.TYPE).name} {command!r} (seq {seq}): {reason}")
        self.command = command
        self.seq = seq
        self.error = error
