"""Host side of the board protocol: messages, frames and a streaming decoder.

The protocol is specified in ``firmware/PROTOCOL.md``; ``firmware/golden/vectors.json`` pins
its bytes for this codec and the firmware's C++ codec alike. A frame is
``[type u8][seq u16][payload][crc u16]`` (little-endian, CRC-16/CCITT-FALSE over everything
before it), COBS-encoded and terminated by ``0x00``.

The board's channel count (motors and load cells) is its HELLO_REPLY's ``channels``; each
message whose layout depends on it (TARE, SET_SETPOINTS, SET_CALIBRATION, TELEMETRY) starts
with its count, and its per-channel fields have that many entries.

Example:
    >>> frame = encode_frame(SetSetpoints.lengths([0.001, 0.0, -0.001], channels=3), seq=7)
    >>> decoder = FrameDecoder()
    >>> [f.seq for f in decoder.feed(b"garbage\\x00" + frame)], decoder.bad_frames
    ([7], 1)
"""

from __future__ import annotations

import binascii
import dataclasses
import enum
import functools
import math
import struct
from typing import TYPE_CHECKING, Any, Callable, ClassVar, Iterable, Sequence, TypeVar, cast

__all__ = [
    "PROTOCOL_VERSION",
    "MAX_CHANNELS",
    "DEFAULT_CHANNELS",
    "TELEMETRY_TICKS",
    "pairs_possible",
    "MAX_PAYLOAD_BYTES",
    "MAX_RAW_FRAME_BYTES",
    "MsgType",
    "Mode",
    "State",
    "Drive",
    "NackError",
    "Fault",
    "enum_member",
    "CodecError",
    "FrameError",
    "MessageError",
    "Message",
    "Hello",
    "Ping",
    "Enable",
    "Disable",
    "Tare",
    "SetMode",
    "SetSetpoints",
    "SetGains",
    "SetCalibration",
    "SetLimits",
    "SetMotors",
    "HelloReply",
    "Ack",
    "Nack",
    "TelemetryMessage",
    "MESSAGE_TYPES",
    "mask_bytes",
    "payload_size",
    "check_fields",
    "Frame",
    "FrameDecoder",
    "crc16",
    "cobs_encode",
    "cobs_decode",
    "encode_payload",
    "decode_payload",
    "encode_frame",
    "decode_frame",
]

PROTOCOL_VERSION = 5
# Most channels a board may have: the firmware's kMaxChannels (firmware/core/config.h), which
# the TELEMETRY fault flags have a tension and an implausible bit each for.
MAX_CHANNELS = 12
# The thesis endoscope's four tendons (models/endoscope/endoscope.toml, tendons.count): the
# count of a message built without one.
DEFAULT_CHANNELS = 4
# Board ticks per TELEMETRY frame, whose encoder counts each frame carries: the firmware's
# kTelemetryTicks, its 25 ms telemetry period over its 5 ms tick (firmware/core/config.h).
TELEMETRY_TICKS = 5
# The longest payload: TELEMETRY of MAX_CHANNELS channels (27 bytes, 25 per channel, the stale
# mask, 2 per channel and tick of the encoder history).
MAX_PAYLOAD_BYTES = 27 + 25 * MAX_CHANNELS + (MAX_CHANNELS + 7) // 8 + 2 * TELEMETRY_TICKS * MAX_CHANNELS
_HEADER = struct.Struct("<BH")
_CRC = struct.Struct("<H")
MAX_RAW_FRAME_BYTES = _HEADER.size + MAX_PAYLOAD_BYTES + _CRC.size
# Longest COBS encoding of a raw frame (without its delimiter).
_MAX_ENCODED_BYTES = MAX_RAW_FRAME_BYTES + MAX_RAW_FRAME_BYTES // 254 + 1


class MsgType(enum.IntEnum):
    HELLO = 0x01
    PING = 0x02
    ENABLE = 0x03
    DISABLE = 0x04
    TARE = 0x05
    SET_MODE = 0x06
    SET_SETPOINTS = 0x07
    SET_GAINS = 0x08
    SET_CALIBRATION = 0x09
    SET_LIMITS = 0x0A
    SET_MOTORS = 0x0B
    HELLO_REPLY = 0x81
    ACK = 0x82
    NACK = 0x83
    TELEMETRY = 0x84


class Mode(enum.IntEnum):
    """Control mode: setpoints are N lengths (m), N/2 antagonistic pair lengths (m) or N tensions (N)."""

    LENGTHS = 0
    PAIRS = 1
    TENSION = 2


class State(enum.IntEnum):
    DISABLED = 0
    ENABLED = 1
    FAULT = 2


class Drive(enum.IntEnum):
    """H-bridge drive of one motor: coast (both inputs low), PWM drive, or brake (both high)."""

    COAST = 0
    DRIVE = 1
    BRAKE = 2


_E = TypeVar("_E", bound=enum.Enum)


def enum_member(enum_cls: type[_E], value: int) -> _E:
    """``enum_cls(value)``, cached: each telemetry sample looks up seven enum members. A value
    the enum refuses still raises."""
    return cast(_E, _enum_member(enum_cls, value))


@functools.lru_cache(maxsize=512)
def _enum_member(enum_cls: type[enum.Enum], value: int) -> enum.Enum:
    return enum_cls(value)


class NackError(enum.IntEnum):
    UNKNOWN_TYPE = 1
    BAD_LENGTH = 2
    BAD_VALUE = 3
    WRONG_MODE = 4
    NOT_ENABLED = 5
    NOT_WHILE_ENABLED = 6
    NO_HANDSHAKE = 7
    NOT_CALIBRATED = 8


if TYPE_CHECKING:
    class Fault(enum.IntFlag):
        """The type checker's view of the flags below: the named ones (a channel's by ``Fault[name]``)."""

        WATCHDOG = 1 << 0
        TENSION_LIMIT = 1 << 1
        LOADCELL_STALE = 1 << 2
        LOADCELL_IMPLAUSIBLE = 1 << 3
else:
    Fault = enum.IntFlag("Fault", {
        "WATCHDOG": 1 << 0,
        "TENSION_LIMIT": 1 << 1,
        "LOADCELL_STALE": 1 << 2,
        "LOADCELL_IMPLAUSIBLE": 1 << 3,
        # The channel bits, 1-based names as the operator counts tendons: bits 8..19 and 20..31.
        **{f"TENSION_CHANNEL_{i + 1}": 1 << (8 + i) for i in range(MAX_CHANNELS)},
        **{f"IMPLAUSIBLE_CHANNEL_{i + 1}": 1 << (20 + i) for i in range(MAX_CHANNELS)},
    }, module=__name__)
Fault.__doc__ = """Telemetry fault flags: WATCHDOG, TENSION_LIMIT and LOADCELL_IMPLAUSIBLE latch until
ENABLE; LOADCELL_STALE is live. TENSION_CHANNEL_k and IMPLAUSIBLE_CHANNEL_k say which channel
(1-based) tripped."""


def pairs_possible(channels: int) -> bool:
    """Whether ``channels`` tendons form antagonistic pairs (i, i + channels/2): an even count."""
    return channels >= 2 and channels % 2 == 0


class CodecError(ValueError):
    """Bytes or a message that the protocol cannot carry; the message names the bad value."""


class FrameError(CodecError):
    """A frame failed COBS, length or CRC checks: its content cannot be trusted."""


class MessageError(CodecError):
    """A frame passed its CRC but its type is unknown, its payload has the wrong length, or a
    field of a board → host message holds a value the protocol does not define."""


@dataclasses.dataclass(frozen=True)
class Message:
    """Base of all messages. ``LAYOUT`` lists (field, struct code) in wire order; a code with a
    count (``"3B"``) is a tuple field, ``"*f"`` a tuple of one entry per channel, ``"#h"`` one
    of :data:`TELEMETRY_TICKS` × channels entries (tick by tick, each tick's channels in order)
    and ``"m"`` a bit per channel in ceil(channels / 8) bytes. A message with per-channel fields
    starts with ``channels`` (``"B"``)."""

    TYPE: ClassVar[MsgType]
    LAYOUT: ClassVar[tuple[tuple[str, str], ...]] = ()


# Host → board.
@dataclasses.dataclass(frozen=True)
class Hello(Message):
    """Version request; the board answers HelloReply and accepts ENABLE only if the versions match."""

    TYPE = MsgType.HELLO
    LAYOUT = (("protocol_version", "H"),)
    protocol_version: int = PROTOCOL_VERSION


@dataclasses.dataclass(frozen=True)
class Ping(Message):
    """Keepalive: feeds the watchdog; answered by Ack."""

    TYPE = MsgType.PING


@dataclasses.dataclass(frozen=True)
class Enable(Message):
    """Enter ENABLED (clearing latched faults); the rig holds its current lengths/tensions."""

    TYPE = MsgType.ENABLE


@dataclasses.dataclass(frozen=True)
class Disable(Message):
    """Enter DISABLED: all motors coast."""

    TYPE = MsgType.DISABLE


@dataclasses.dataclass(frozen=True)
class Tare(Message):
    """Zero load cells (bit i: offset := latest raw count) and lengths (bit i: origin := encoder count).

    Refused while enabled.
    """

    TYPE = MsgType.TARE
    LAYOUT = (("channels", "B"), ("loadcell_mask", "m"), ("length_mask", "m"))
    loadcell_mask: int = 0
    length_mask: int = 0
    channels: int = DEFAULT_CHANNELS


@dataclasses.dataclass(frozen=True)
class SetMode(Message):
    TYPE = MsgType.SET_MODE
    LAYOUT = (("mode", "B"),)
    mode: int = Mode.LENGTHS


@dataclasses.dataclass(frozen=True)
class SetSetpoints(Message):
    """Setpoints of the active mode (``mode`` must match it), one per channel.

    ``values``: the tendon lengths (m) in LENGTHS; the N/2 pair lengths (m) then N/2 zeros in
    PAIRS; the tensions (N) in TENSION.
    """

    TYPE = MsgType.SET_SETPOINTS
    LAYOUT = (("channels", "B"), ("mode", "B"), ("values", "*f"))
    mode: int = Mode.LENGTHS
    values: tuple[float, ...] = (0.0,) * DEFAULT_CHANNELS
    channels: int = DEFAULT_CHANNELS

    @classmethod
    def lengths(cls, lengths_m: Sequence[float], channels: int = DEFAULT_CHANNELS) -> "SetSetpoints":
        return cls(Mode.LENGTHS, _floats("lengths_m", lengths_m, channels), channels)

    @classmethod
    def pairs(cls, pair_lengths_m: Sequence[float], channels: int = DEFAULT_CHANNELS) -> "SetSetpoints":
        """Pair k couples tendon k with tendon k + channels/2 ((1,3) then (2,4) of four):
        tendon 1 at c₁₃ + d, tendon 3 at c₁₃ − d (m). ``channels`` must be even."""
        if not pairs_possible(channels):
            raise CodecError(f"channels = {channels!r}: pairs need an even count of tendons")
        half = channels // 2
        return cls(Mode.PAIRS, _floats("pair_lengths_m", pair_lengths_m, half) + (0.0,) * half, channels)

    @classmethod
    def tensions(cls, tensions_n: Sequence[float], channels: int = DEFAULT_CHANNELS) -> "SetSetpoints":
        return cls(Mode.TENSION, _floats("tensions_n", tensions_n, channels), channels)


@dataclasses.dataclass(frozen=True)
class SetGains(Message):
    """PID gains of one mode. Units per m of length (LENGTHS, PAIRS) or per N (TENSION):
    ``kp`` duty/unit, ``ki`` duty/(unit·s), ``kd`` duty·s/unit; ``output_limit`` in (0, 1]."""

    TYPE = MsgType.SET_GAINS
    LAYOUT = (("mode", "B"), ("kp", "f"), ("ki", "f"), ("kd", "f"), ("output_limit", "f"))
    mode: int = Mode.LENGTHS
    kp: float = 0.0
    ki: float = 0.0
    kd: float = 0.0
    output_limit: float = 1.0


@dataclasses.dataclass(frozen=True)
class SetCalibration(Message):
    """Load-cell calibration: tension_n = gain_n_per_count · (raw − offset_counts). Refused while enabled."""

    TYPE = MsgType.SET_CALIBRATION
    LAYOUT = (("channels", "B"), ("gain_n_per_count", "*f"), ("offset_counts", "*f"))
    gain_n_per_count: tuple[float, ...] = (1.0,) * DEFAULT_CHANNELS
    offset_counts: tuple[float, ...] = (0.0,) * DEFAULT_CHANNELS
    channels: int = DEFAULT_CHANNELS


@dataclasses.dataclass(frozen=True)
class SetLimits(Message):
    """Per-channel tension limit, watchdog timeout and the load cells' rated sensitivity: the
    board bounds calibrations by it and converts readings with it until one arrives."""

    TYPE = MsgType.SET_LIMITS
    LAYOUT = (("tension_limit_n", "f"), ("watchdog_timeout_ms", "H"), ("loadcell_gain_counts_per_n", "f"))
    tension_limit_n: float = 6.0
    watchdog_timeout_ms: int = 250
    loadcell_gain_counts_per_n: float = 45000.0


@dataclasses.dataclass(frozen=True)
class SetMotors(Message):
    """The motors at the tendons, all alike: stall force (N), no-load speed (m/s) and reflected
    rotor mass (kg), which the board's tension bound derives from. Defaults: the thesis rig's
    (0.5 N·m and 1500 rpm on a 3.25 mm spool, 1e-6 kg·m² behind 5.3:1), the board's own until
    it is sent another. Another one is refused while enabled."""

    TYPE = MsgType.SET_MOTORS
    LAYOUT = (("stall_force_n", "f"), ("no_load_speed_m_per_s", "f"), ("reflected_mass_kg", "f"))
    stall_force_n: float = 0.5 / 0.00325
    no_load_speed_m_per_s: float = 1500.0 * 2.0 * math.pi / 60.0 * 0.00325
    reflected_mass_kg: float = 1e-6 * 5.3**2 / 0.00325**2


# Board → host.
@dataclasses.dataclass(frozen=True)
class HelloReply(Message):
    TYPE = MsgType.HELLO_REPLY
    LAYOUT = (
        ("protocol_version", "H"),
        ("firmware_version", "3B"),
        ("channels", "B"),
        ("control_period_us", "I"),
        ("telemetry_period_us", "I"),
        ("tendon_m_per_count", "f"),
    )
    protocol_version: int = PROTOCOL_VERSION
    firmware_version: tuple[int, ...] = (0, 0, 0)
    channels: int = DEFAULT_CHANNELS
    control_period_us: int = 0
    telemetry_period_us: int = 0
    tendon_m_per_count: float = 0.0


@dataclasses.dataclass(frozen=True)
class Ack(Message):
    TYPE = MsgType.ACK
    LAYOUT = (("acked_seq", "H"), ("acked_type", "B"))
    acked_seq: int = 0
    acked_type: int = 0


@dataclasses.dataclass(frozen=True)
class Nack(Message):
    TYPE = MsgType.NACK
    LAYOUT = (("acked_seq", "H"), ("acked_type", "B"), ("error", "B"))
    acked_seq: int = 0
    acked_type: int = 0
    error: int = 0


@dataclasses.dataclass(frozen=True)
class TelemetryMessage(Message):
    """One 40 Hz sample. ``targets`` are per motor, in m (length modes) or N (tension);
    ``duty`` in [-1, 1], positive pays tendon out; ``drive_modes`` holds a Drive per motor;
    ``stale_mask`` bit i = load cell i stale. ``encoder_history`` holds the encoder counts at
    each of the :data:`TELEMETRY_TICKS` board ticks since the frame before, oldest first and
    the last this frame's own (all 0), tick by tick with each tick's channels in order, as
    differences from ``encoder_counts`` (counts) saturated to the int16 range."""

    TYPE = MsgType.TELEMETRY
    LAYOUT = (
        ("channels", "B"),
        ("time_us", "Q"),
        ("sample_seq", "I"),
        ("encoder_counts", "*i"),
        ("lengths_m", "*f"),
        ("raw_counts", "*i"),
        ("tensions_n", "*f"),
        ("targets", "*f"),
        ("duty", "*f"),
        ("drive_modes", "*B"),
        ("state", "B"),
        ("mode", "B"),
        ("fault_flags", "I"),
        ("stale_mask", "m"),
        ("rx_bad_frames", "I"),
        ("tx_dropped_frames", "I"),
        ("encoder_history", "#h"),
    )
    time_us: int = 0
    sample_seq: int = 0
    encoder_counts: tuple[int, ...] = (0,) * DEFAULT_CHANNELS
    lengths_m: tuple[float, ...] = (0.0,) * DEFAULT_CHANNELS
    raw_counts: tuple[int, ...] = (0,) * DEFAULT_CHANNELS
    tensions_n: tuple[float, ...] = (0.0,) * DEFAULT_CHANNELS
    targets: tuple[float, ...] = (0.0,) * DEFAULT_CHANNELS
    duty: tuple[float, ...] = (0.0,) * DEFAULT_CHANNELS
    state: int = State.DISABLED
    mode: int = Mode.LENGTHS
    fault_flags: int = 0
    stale_mask: int = 0
    drive_modes: tuple[int, ...] = (Drive.COAST,) * DEFAULT_CHANNELS
    rx_bad_frames: int = 0
    tx_dropped_frames: int = 0
    channels: int = DEFAULT_CHANNELS
    encoder_history: tuple[int, ...] = (0,) * (TELEMETRY_TICKS * DEFAULT_CHANNELS)

    def drives(self) -> tuple[Drive, ...]:
        """The Drive of each motor."""
        return tuple(enum_member(Drive, d) for d in self.drive_modes)


MESSAGE_TYPES: dict[int, type[Message]] = {
    cls.TYPE: cls
    for cls in (Hello, Ping, Enable, Disable, Tare, SetMode, SetSetpoints, SetGains, SetCalibration,
                SetLimits, SetMotors, HelloReply, Ack, Nack, TelemetryMessage)
}


def _floats(name: str, values: Iterable[float], count: int) -> tuple[float, ...]:
    values = tuple(float(v) for v in values)
    if len(values) != count:
        raise CodecError(f"{name} = {values!r}: must have {count} entries")
    return values


def _sized(cls: type[Message]) -> bool:
    """Whether ``cls``'s layout depends on the channel count (it then starts with ``channels``)."""
    return any(code[0] in "*#" or code == "m" for _, code in cls.LAYOUT)


_SIZED = frozenset(t for t, cls in MESSAGE_TYPES.items() if _sized(cls))
assert all(MESSAGE_TYPES[t].LAYOUT[0] == ("channels", "B") for t in _SIZED)


def mask_bytes(channels: int) -> int:
    """Bytes of a bit-per-channel mask on the wire: ceil(channels / 8)."""
    return (channels + 7) // 8


_MASK_CODES = {1: "B", 2: "H"}


def _codes(cls: type[Message], channels: int) -> list[tuple[str, str, int | None]]:
    """(name, struct code, count or None for a scalar) of each field of ``cls`` at ``channels``."""
    out: list[tuple[str, str, int | None]] = []
    for name, code in cls.LAYOUT:
        if code[0] == "*":
            out.append((name, f"{channels}{code[1:]}", channels))
        elif code[0] == "#":
            out.append((name, f"{TELEMETRY_TICKS * channels}{code[1:]}", TELEMETRY_TICKS * channels))
        elif code == "m":
            out.append((name, _MASK_CODES[mask_bytes(channels)], None))
        elif code[0].isdigit():
            out.append((name, code, int(code[:-1])))
        else:
            out.append((name, code, None))
    return out


@functools.lru_cache(maxsize=None)
def _layout(msg_type: int, channels: int) -> tuple[struct.Struct, tuple[tuple[str, int, int | None], ...]]:
    """The struct of a message type at a channel count, and each field's (name, index of its
    first value in the unpacked tuple, count or None for a scalar)."""
    fields, start, fmt = [], 0, "<"
    for name, code, count in _codes(MESSAGE_TYPES[msg_type], channels):
        fields.append((name, start, count))
        start += count or 1
        fmt += code
    return struct.Struct(fmt), tuple(fields)


def payload_size(msg_type: int, channels: int = DEFAULT_CHANNELS) -> int:
    """Payload bytes of a message of ``msg_type``; ``channels`` sizes those whose layout depends on it."""
    return _layout(msg_type, channels)[0].size


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final XOR)."""
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (no delimiter appended); the result contains no 0x00."""
    # Each run of non-zero bytes becomes code + run, in blocks of at most 254 bytes (code 0xFF,
    # no zero implied). A new block starts after a full one only if data follows (canonical COBS).
    out = bytearray()
    runs = data.split(b"\x00")
    last = len(runs) - 1
    for k, run in enumerate(runs):
        start, n = 0, len(run)
        while n - start >= 0xFE:
            out.append(0xFF)
            out += run[start:start + 0xFE]
            start += 0xFE
        if start < n or k < last or start == 0:
            out.append(n - start + 1)
            out += run[start:]
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Decode one COBS frame (without its delimiter).

    Raises:
        FrameError: a zero byte, or a block running past the end.
    """
    # In place: each code byte after the first becomes the zero it stands for, or goes when it
    # follows a full block (0xFF). A frame has a block per zero byte (a TELEMETRY of four
    # channels about 140), so the loop does no more per block than it must.
    n = len(data)
    if n == 0:
        return b""
    if 0 in data:
        _raise_cobs_error(data)
    out = bytearray(data)
    after_full, i = [], 0
    while True:
        code = data[i]
        following = i + code
        if following >= n:
            break
        if code == 0xFF:
            after_full.append(following)
        else:
            out[following] = 0
        i = following
    if following > n:
        _raise_cobs_error(data)
    for position in reversed(after_full):
        del out[position]
    return bytes(out[1:])


def _raise_cobs_error(data: bytes) -> None:
    """Raise FrameError naming the first bad block of ``data``."""
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        block = data[i + 1:i + code]
        if code == 0 or len(block) != code - 1 or 0 in block:
            raise FrameError(f"invalid COBS block code {code} at byte {i} of {n}")
        i += code
    raise FrameError(f"invalid COBS frame of {n} bytes")


def _channels_of(message: Message) -> int:
    channels = getattr(message, "channels") if message.TYPE in _SIZED else DEFAULT_CHANNELS
    if not (isinstance(channels, int) and 1 <= channels <= MAX_CHANNELS):
        raise CodecError(f"{type(message).__name__}.channels = {channels!r}: must be in 1..{MAX_CHANNELS}")
    return channels


def encode_payload(message: Message) -> bytes:
    """The payload bytes of ``message`` (little-endian, fields in LAYOUT order)."""
    layout, fields = _layout(message.TYPE, _channels_of(message))
    flat: list = []
    for name, _, count in fields:
        value = getattr(message, name)
        if count is None:
            flat.append(value)
        elif isinstance(value, (tuple, list)) and len(value) == count:
            flat.extend(value)
        else:
            raise CodecError(f"{type(message).__name__}.{name} = {value!r}: must have {count} entries")
    try:
        return layout.pack(*flat)
    except (struct.error, OverflowError) as exc:
        raise CodecError(f"{message!r} cannot be encoded: {exc}") from None


def decode_payload(msg_type: int, payload: bytes) -> Message:
    """The message of type ``msg_type`` carried by ``payload``; one whose layout depends on the
    channel count is sized by the count it starts with.

    Raises:
        MessageError: unknown type, a channel count outside 1..MAX_CHANNELS, or a payload of the
            wrong length.
    """
    cls = MESSAGE_TYPES.get(msg_type)
    if cls is None:
        raise MessageError(f"unknown message type 0x{msg_type:02x}")
    channels, sized = DEFAULT_CHANNELS, msg_type in _SIZED
    if sized:
        if not payload:
            raise MessageError(f"{cls.__name__} payload is empty, expected its channel count first")
        channels = payload[0]
        if not 1 <= channels <= MAX_CHANNELS:
            raise MessageError(f"{cls.__name__}.channels = {channels}: must be in 1..{MAX_CHANNELS}")
    layout, fields = _layout(msg_type, channels)
    if len(payload) != layout.size:
        per = f" for {channels} channels" if sized else ""
        raise MessageError(f"{cls.__name__} payload is {len(payload)} bytes, expected {layout.size}{per}")
    flat = layout.unpack(payload)
    return cls(**{name: flat[start] if count is None else flat[start:start + count]
                  for name, start, count in fields})


@dataclasses.dataclass(frozen=True)
class Frame:
    """A received frame: the sender's sequence number and the message."""

    seq: int
    message: Message


def encode_frame(message: Message, seq: int) -> bytes:
    """The wire bytes of ``message`` with sequence number ``seq`` (0..65535), delimiter included."""
    if not 0 <= seq <= 0xFFFF:
        raise CodecError(f"seq = {seq!r}: must be in 0..65535")
    payload = encode_payload(message)
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise CodecError(f"{type(message).__name__} payload is {len(payload)} bytes, max {MAX_PAYLOAD_BYTES}")
    body = _HEADER.pack(message.TYPE, seq) + payload
    return cobs_encode(body + _CRC.pack(crc16(body))) + b"\x00"


def _check_frame(encoded: bytes) -> tuple[int, int, bytes]:
    """(type, seq, payload) of an encoded frame without delimiter; FrameError unless intact."""
    if len(encoded) > _MAX_ENCODED_BYTES:
        raise FrameError(f"frame of {len(encoded)} encoded bytes exceeds {_MAX_ENCODED_BYTES}")
    raw = cobs_decode(encoded)
    if not _HEADER.size + _CRC.size <= len(raw) <= MAX_RAW_FRAME_BYTES:
        raise FrameError(f"frame of {len(raw)} bytes outside {_HEADER.size + _CRC.size}..{MAX_RAW_FRAME_BYTES}")
    body, (crc,) = raw[: -_CRC.size], _CRC.unpack(raw[-_CRC.size :])
    if crc != crc16(body):
        raise FrameError(f"CRC 0x{crc:04x} does not match 0x{crc16(body):04x}")
    msg_type, seq = _HEADER.unpack(body[: _HEADER.size])
    return msg_type, seq, body[_HEADER.size :]


_STATES = frozenset(State)
_MODES = frozenset(Mode)
_DRIVES = frozenset(Drive)


def _check_telemetry(m: TelemetryMessage) -> None:
    duty = m.duty
    # One expression for the common case, a sample each 25 ms: a sum of float32 values is
    # finite exactly when every one is (float32's range is far inside float64's), so the duty
    # bounds are then its extremes.
    if (m.state in _STATES and m.mode in _MODES and _DRIVES.issuperset(m.drive_modes) and not m.stale_mask >> m.channels
            and not m.fault_flags & ~_defined_faults(m.channels)
            and math.isfinite(sum(m.lengths_m + m.tensions_n + m.targets + duty))
            and -1.0 <= min(duty) and max(duty) <= 1.0):
        return
    if m.state not in _STATES:
        raise MessageError(f"TelemetryMessage.state = {m.state}: not a State")
    if m.mode not in _MODES:
        raise MessageError(f"TelemetryMessage.mode = {m.mode}: not a Mode")
    if not _DRIVES.issuperset(m.drive_modes):
        raise MessageError(f"TelemetryMessage.drive_modes = {m.drive_modes!r}: a motor's drive is not a Drive")
    if m.stale_mask >> m.channels:
        raise MessageError(f"TelemetryMessage.stale_mask = 0x{m.stale_mask:02x}: bits beyond the {m.channels} load cells")
    if m.fault_flags & ~_defined_faults(m.channels):
        raise MessageError(f"TelemetryMessage.fault_flags = 0x{m.fault_flags:08x}: bits "
                           f"0x{m.fault_flags & ~_defined_faults(m.channels):08x} are no fault of {m.channels} channels")
    for name in ("lengths_m", "tensions_n", "targets"):
        if not all(map(math.isfinite, getattr(m, name))):
            raise MessageError(f"TelemetryMessage.{name} = {getattr(m, name)!r}: not finite")
    raise MessageError(f"TelemetryMessage.duty = {duty!r}: not within [-1, 1]")


@functools.lru_cache(maxsize=None)
def _defined_faults(channels: int) -> int:
    """The fault-flag bits a board of ``channels`` channels can set: the four faults and a
    tension and an implausible bit per channel."""
    bits = Fault.WATCHDOG | Fault.TENSION_LIMIT | Fault.LOADCELL_STALE | Fault.LOADCELL_IMPLAUSIBLE
    for i in range(channels):
        bits |= Fault[f"TENSION_CHANNEL_{i + 1}"] | Fault[f"IMPLAUSIBLE_CHANNEL_{i + 1}"]
    return int(bits)


_NACK_ERRORS = frozenset(NackError)
_TYPES = frozenset(MsgType)


def _check_reply(m: Ack | Nack) -> None:
    if m.acked_type not in _TYPES:
        raise MessageError(f"{type(m).__name__}.acked_type = 0x{m.acked_type:02x}: not a message type")
    if isinstance(m, Nack) and m.error not in _NACK_ERRORS:
        raise MessageError(f"Nack.error = {m.error}: not a NackError")


def _check_hello_reply(m: HelloReply) -> None:
    # The protocol version is not checked here: the host refuses another version by name. Nor
    # is the count checked against a robot: the device does that, naming both.
    if not 1 <= m.channels <= MAX_CHANNELS:
        raise MessageError(f"HelloReply.channels = {m.channels}: must be in 1..{MAX_CHANNELS}")
    if not math.isfinite(m.tendon_m_per_count):
        raise MessageError(f"HelloReply.tendon_m_per_count = {m.tendon_m_per_count!r}: not finite")


# Board → host messages whose fields hold enums or physical values. Commands are not checked
# here: the board answers a bad value with NACK BAD_VALUE, which is the protocol's verdict.
# Fault flags are checked too: the handshake refuses another protocol version, so within this
# one a bit no fault defines is corruption, not a fault the host has no name for.
_FIELD_CHECKS: dict[int, Callable[[Any], None]] = {MsgType.TELEMETRY: _check_telemetry, MsgType.HELLO_REPLY: _check_hello_reply,
                 MsgType.ACK: _check_reply, MsgType.NACK: _check_reply}


def check_fields(message: Message) -> None:
    """Check that a board → host message carries only values the protocol defines: enum fields
    hold members, floats are finite, duty lies in [-1, 1], fault flags set only the bits of
    defined faults and channels, an ACK or NACK names a message type and a NACK a defined
    error, a HELLO_REPLY names 1..MAX_CHANNELS channels.

    Raises:
        MessageError: naming the field and its value.
    """
    check = _FIELD_CHECKS.get(message.TYPE)
    if check is not None:
        check(message)


def decode_frame(encoded: bytes) -> Frame:
    """Decode one frame given without its 0x00 delimiter.

    Raises:
        FrameError: COBS, length or CRC failure.
        MessageError: intact frame of an unknown type or wrong payload length.
    """
    msg_type, seq, payload = _check_frame(encoded)
    return Frame(seq, decode_payload(msg_type, payload))


class FrameDecoder:
    """Streaming receiver: feed bytes in any chunking, get the complete frames.

    Whatever is not a valid frame is skipped and counted, and reception resynchronises on the
    next 0x00: ``bad_frames`` counts framing and CRC failures (corruption, truncation,
    garbage, over-long runs), ``bad_messages`` intact frames of an unknown type or wrong
    length, or board → host messages with a value the protocol does not define
    (:func:`check_fields`). Empty frames (repeated delimiters) are ignored.

    Attributes:
        bad_frames: frames dropped for framing or CRC errors.
        bad_messages: intact frames that carried no usable message.
        last_error: why the latest bad frame or message was dropped, or None.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._overflow = False
        self.bad_frames = 0
        self.bad_messages = 0
        self.last_error: str | None = None

    def feed(self, data: bytes) -> list[Frame]:
        frames: list[Frame] = []
        start = 0
        while True:
            end = data.find(0, start)
            if end < 0:
                self._append(data[start:])
                return frames
            self._append(data[start:end])
            frame = self._finish()
            if frame is not None:
                frames.append(frame)
            start = end + 1

    def _append(self, chunk: bytes) -> None:
        if self._overflow:
            return
        self._buffer += chunk
        if len(self._buffer) > _MAX_ENCODED_BYTES:
            self._buffer.clear()
            self._overflow = True

    def _finish(self) -> Frame | None:
        encoded, overflow = bytes(self._buffer), self._overflow
        self._buffer.clear()
        self._overflow = False
        if overflow:
            self.bad_frames += 1
            self.last_error = f"frame longer than {_MAX_ENCODED_BYTES} encoded bytes"
            return None
        if not encoded:
            return None
        try:
            frame = decode_frame(encoded)
            check_fields(frame.message)
            return frame
        except FrameError as exc:
            self.bad_frames += 1
            self.last_error = str(exc)
        except MessageError as exc:
            self.bad_messages += 1
            self.last_error = str(exc)
        return None
