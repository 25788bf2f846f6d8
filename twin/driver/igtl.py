"""The OpenIGTLink wire format: header, CRC-64, and the message bodies the twin reads and writes.

Every message is a 58-byte big-endian header followed by a body::

    uint16 header version | char[12] type | char[20] device name | uint32 seconds |
    uint32 fraction of a second (/2³²) | uint64 body size | uint64 CRC-64 of the body

Header version 1 (OpenIGTLink 1 and 2) has the content as the body. Version 2 (OpenIGTLink 3)
wraps it: a 12-byte extended header (uint16 its size, uint16 metadata-header size, uint32
metadata size, uint32 message id), the content, then the metadata (uint16 count, per entry
uint16 key size, uint16 value encoding, uint32 value size; then the keys and values). The CRC
is CRC-64/ECMA-182 (polynomial 0x42F0E1EBA9EA3693, not reflected, initial value and final XOR 0).

Contents handled here (all big-endian float32 unless noted, lengths in the sender's unit):

``TRANSFORM``
    12 floats: the rotation's three columns, then the translation (a 4×4 matrix whose bottom
    row is implied).
``POSITION``
    3 floats of position, then either nothing (12 bytes), the quaternion's x, y, z with w ≥ 0
    implied (24 bytes) or x, y, z, w (28 bytes). pyigtl writes another layout, 152 bytes per
    named element (name, group, RGBA, position, quaternion x y z w, diameter, owner); that
    one is read too.
``POINT``
    136 bytes per point: char[64] name, char[32] group, uint8 RGBA, 3 floats position,
    float diameter, char[20] owner.
``POLYDATA``
    uint32 counts (points; vertices, lines, polygons, triangle strips, each as a cell count and
    a byte size; attributes), the points as float32 triplets, then each cell list as uint32
    ``n, i₁ … iₙ`` runs. Attributes are neither written nor read.
``STRING``
    uint16 character encoding (the IANA MIBenum; 106 UTF-8), uint16 byte length, the bytes:
    Slicer shows it as a text node named by the device.
"""

from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np

from twin.pose import quat_to_matrix

__all__ = [
    "HEADER_SIZE",
    "Message",
    "MessageError",
    "Pose",
    "crc64",
    "decode",
    "decode_point",
    "decode_polydata",
    "decode_pose",
    "decode_string",
    "encode_point",
    "encode_polydata",
    "encode_position",
    "encode_string",
    "encode_transform",
    "pack",
    "unpack_header",
]

HEADER_SIZE = 58
_HEADER = struct.Struct(">H12s20sIIQQ")
_EXTENDED_HEADER = struct.Struct(">HHII")
_METADATA_ENTRY = struct.Struct(">HHI")
_IANA_US_ASCII = 3
_IANA_UTF8 = 106
# Bodies above this are refused: a corrupt size field must not make a reader wait for gigabytes.
MAX_BODY_BYTES = 64 * 1024 * 1024

_CRC64_POLY = 0x42F0E1EBA9EA3693
_MASK64 = (1 << 64) - 1


def _crc64_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 56
        for _ in range(8):
            crc = ((crc << 1) ^ _CRC64_POLY) if crc & (1 << 63) else (crc << 1)
        table.append(crc & _MASK64)
    return tuple(table)


_CRC64_TABLE = _crc64_table()


def _crc64_python(data: bytes) -> int:
    crc = 0
    table = _CRC64_TABLE
    for byte in data:
        crc = table[((crc >> 56) ^ byte) & 0xFF] ^ ((crc << 8) & _MASK64)
    return crc


def _crc64_compiled():
    """crcmod's CRC function when its C extension is built (~40x the table loop: 64 MB in 0.2 s
    of CPU instead of 8 s), else None."""
    try:
        import crcmod
        import crcmod._crcfunext  # noqa: F401 - only the compiled one is worth taking
    except ImportError:
        return None
    return crcmod.mkCrcFun(_CRC64_POLY | (1 << 64), initCrc=0, rev=False, xorOut=0)


_CRC64_C = _crc64_compiled()


def crc64(data: bytes) -> int:
    """CRC-64/ECMA-182 of ``data`` as OpenIGTLink computes it (MSB first, init 0, no final XOR)."""
    return _CRC64_C(data) if _CRC64_C is not None else _crc64_python(data)


class MessageError(ValueError):
    """A message that cannot be decoded: bad CRC, a size that does not fit, a malformed body."""


@dataclasses.dataclass(frozen=True)
class Message:
    """One OpenIGTLink message.

    Attributes:
        type: message type, e.g. ``"TRANSFORM"`` (at most 12 ASCII characters).
        device: device name, e.g. ``"Probe1ToTracker"`` (at most 20 bytes).
        timestamp_s: sender's time (Unix seconds of its clock); 0 means "not stamped".
        content: the body without the version-2 wrapping.
        metadata: version-2 key/value pairs (empty for version 1).
        version: header version, 1 or 2.
    """

    type: str
    device: str
    timestamp_s: float
    content: bytes
    metadata: dict = dataclasses.field(default_factory=dict)
    version: int = 1


def _name(value: str, size: int, what: str) -> bytes:
    raw = value.encode("utf-8")
    if len(raw) > size:
        raise ValueError(f"{what} {value!r}: longer than {size} bytes, OpenIGTLink's limit")
    return raw


def _timestamp_fields(timestamp_s: float) -> tuple[int, int]:
    seconds = int(math.floor(timestamp_s))
    fraction = min(int(round((timestamp_s - seconds) * 2.0**32)), 2**32 - 1)
    return seconds, fraction


def pack(type: str, device: str, content: bytes, *, timestamp_s: float, metadata: dict | None = None,
         version: int = 1, message_id: int = 0) -> bytes:
    """The bytes of one message.

    Args:
        type: message type (``TRANSFORM``, ``POSITION``, ``POINT``, ``POLYDATA``, ...).
        device: device name.
        content: the encoded content (see the ``encode_*`` functions).
        timestamp_s: Unix time of the sender's clock (s).
        metadata: key/value strings, version 2 only.
        version: header version 1 or 2.
        message_id: version-2 message id.
    """
    if version not in (1, 2):
        raise ValueError(f"version = {version!r}: OpenIGTLink header versions are 1 and 2")
    if metadata and version == 1:
        raise ValueError("metadata needs header version 2")
    body = content
    if version == 2:
        encoded = [(str(k).encode("utf-8"), str(v).encode("utf-8")) for k, v in (metadata or {}).items()]
        meta_header = struct.pack(">H", len(encoded)) + b"".join(
            _METADATA_ENTRY.pack(len(k), _IANA_UTF8, len(v)) for k, v in encoded)
        meta_body = b"".join(k + v for k, v in encoded)
        extended = _EXTENDED_HEADER.pack(_EXTENDED_HEADER.size, len(meta_header), len(meta_body), message_id)
        body = extended + content + meta_header + meta_body
    seconds, fraction = _timestamp_fields(timestamp_s)
    header = _HEADER.pack(version, _name(type, 12, "message type"), _name(device, 20, "device name"),
                          seconds, fraction, len(body), crc64(body))
    return header + body


def unpack_header(header: bytes) -> tuple[int, str, str, float, int, int]:
    """``(version, type, device, timestamp_s, body_size, crc)`` of a 58-byte header.

    Raises:
        MessageError: a body size above :data:`MAX_BODY_BYTES` (a corrupt or foreign stream).
    """
    version, type_, device, seconds, fraction, size, crc = _HEADER.unpack(header)
    if size > MAX_BODY_BYTES:
        raise MessageError(f"body size {size} bytes: more than {MAX_BODY_BYTES}, not an OpenIGTLink stream")
    return (version, type_.rstrip(b"\0").decode("utf-8", "replace"), device.rstrip(b"\0").decode("utf-8", "replace"),
            seconds + fraction / 2.0**32, size, crc)


def decode(header: bytes, body: bytes) -> Message:
    """The :class:`Message` of a header and its body, the CRC checked.

    Raises:
        MessageError: CRC mismatch or a version-2 wrapping that does not fit the body.
    """
    version, type_, device, timestamp_s, size, crc = unpack_header(header)
    if len(body) != size:
        raise MessageError(f"{type_} {device!r}: body of {len(body)} bytes, header says {size}")
    if crc64(body) != crc:
        raise MessageError(f"{type_} {device!r}: CRC mismatch")
    if version < 2:
        return Message(type_, device, timestamp_s, body, {}, version)
    if size < _EXTENDED_HEADER.size:
        raise MessageError(f"{type_} {device!r}: version-2 body of {size} bytes has no extended header")
    ext_size, meta_header_size, meta_size, _ = _EXTENDED_HEADER.unpack_from(body)
    end = size - meta_header_size - meta_size
    if ext_size < _EXTENDED_HEADER.size or end < ext_size:
        raise MessageError(f"{type_} {device!r}: extended header sizes ({ext_size}, {meta_header_size}, "
                           f"{meta_size}) do not fit a {size}-byte body")
    return Message(type_, device, timestamp_s, body[ext_size:end], _metadata(body[end:], meta_header_size), version)


def _metadata(raw: bytes, header_size: int) -> dict:
    if header_size < 2:
        return {}
    (count,) = struct.unpack_from(">H", raw)
    if 2 + count * _METADATA_ENTRY.size > header_size:
        raise MessageError(f"metadata: {count} entries do not fit a {header_size}-byte metadata header")
    out, offset = {}, header_size
    for i in range(count):
        key_size, encoding, value_size = _METADATA_ENTRY.unpack_from(raw, 2 + i * _METADATA_ENTRY.size)
        key = raw[offset:offset + key_size].decode("utf-8", "replace")
        offset += key_size
        value = raw[offset:offset + value_size]
        offset += value_size
        out[key] = value.decode("ascii" if encoding == _IANA_US_ASCII else "utf-8", "replace")
    return out


# --------------------------------------------------------------------------- contents

@dataclasses.dataclass(frozen=True, eq=False)
class Pose:
    """A decoded TRANSFORM or POSITION, in the sender's length unit.

    Attributes:
        translation: (3,) position (sender's unit, mm for PLUS).
        rotation: (3, 3) rotation, or None for a POSITION that carries no orientation.
    """

    translation: np.ndarray
    rotation: np.ndarray | None


def encode_transform(rotation, translation) -> bytes:
    """TRANSFORM content of a rotation (3, 3) and a translation (3,) in the unit to send."""
    r = np.asarray(rotation, dtype=float).reshape(3, 3)
    t = np.asarray(translation, dtype=float).reshape(3)
    return np.concatenate([r.T.ravel(), t]).astype(">f4").tobytes()


def encode_position(translation, quaternion=None) -> bytes:
    """Standard POSITION content: position (3,), and a quaternion ``(w, x, y, z)`` if given (28 bytes)."""
    t = np.asarray(translation, dtype=float).reshape(3)
    if quaternion is None:
        return t.astype(">f4").tobytes()
    w, x, y, z = np.asarray(quaternion, dtype=float).reshape(4)
    return np.array([*t, x, y, z, w]).astype(">f4").tobytes()


_PYIGTL_POSITION_ITEM = 64 + 32 + 4 + 7 * 4 + 4 + 20


def decode_pose(message: Message) -> Pose:
    """The pose of a TRANSFORM or POSITION message.

    Raises:
        MessageError: another type, or a content size neither layout has.
    """
    c = message.content
    if message.type == "TRANSFORM":
        if len(c) != 48:
            raise MessageError(f"TRANSFORM {message.device!r}: {len(c)} bytes of content, expected 48")
        v = np.frombuffer(c, dtype=">f4").astype(float)
        return Pose(v[9:12].copy(), v[:9].reshape(3, 3).T.copy())
    if message.type != "POSITION":
        raise MessageError(f"{message.type} {message.device!r}: not a pose message")
    if len(c) in (12, 24, 28):
        v = np.frombuffer(c, dtype=">f4").astype(float)
        if len(c) == 12:
            return Pose(v.copy(), None)
        x, y, z = v[3:6]
        w = v[6] if len(c) == 28 else math.sqrt(max(0.0, 1.0 - (x * x + y * y + z * z)))
        return Pose(v[:3].copy(), _quat_matrix(w, x, y, z))
    if len(c) and len(c) % _PYIGTL_POSITION_ITEM == 0:
        v = np.frombuffer(c[100:128], dtype=">f4").astype(float)
        return Pose(v[:3].copy(), _quat_matrix(v[6], v[3], v[4], v[5]))
    raise MessageError(f"POSITION {message.device!r}: {len(c)} bytes of content, expected 12, 24 or 28 "
                       f"(or a multiple of {_PYIGTL_POSITION_ITEM})")


def _quat_matrix(w, x, y, z) -> np.ndarray | None:
    # quat_to_matrix refuses a zero quaternion; from a sender it means "no orientation".
    q = np.array([w, x, y, z], dtype=float)
    if not np.isfinite(q).all() or np.linalg.norm(q) < 1e-6:
        return None
    return quat_to_matrix(q)


_POINT = struct.Struct(">64s32s4B3ff20s")


def encode_point(positions, *, names=None, group: str = "", rgba=(255, 255, 0, 255), diameter: float = 0.0,
                 owner: str = "") -> bytes:
    """POINT content of points (n, 3) in the unit to send; names default to ``P1 … Pn``."""
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    names = [f"P{i + 1}" for i in range(len(p))] if names is None else list(names)
    out = bytearray()
    for name, xyz in zip(names, p, strict=True):
        out += _POINT.pack(_name(name, 64, "point name"), _name(group, 32, "point group"), *rgba,
                           *(float(v) for v in xyz), float(diameter), _name(owner, 20, "point owner"))
    return bytes(out)


def decode_point(content: bytes) -> tuple[list[str], np.ndarray]:
    """Names and positions (n, 3) of POINT content."""
    if len(content) % _POINT.size:
        raise MessageError(f"POINT: {len(content)} bytes of content, not a multiple of {_POINT.size}")
    names, positions = [], []
    for item in _POINT.iter_unpack(content):
        names.append(item[0].rstrip(b"\0").decode("utf-8", "replace"))
        positions.append(item[6:9])
    return names, np.array(positions, dtype=float).reshape(-1, 3)


_POLYDATA_HEADER = struct.Struct(">10I")


def encode_polydata(points, *, lines=()) -> bytes:
    """POLYDATA content of points (n, 3) in the unit to send and polylines (lists of point indices)."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    cells = np.array([v for line in lines for v in (len(line), *line)], dtype=">u4")
    header = _POLYDATA_HEADER.pack(len(p), 0, 0, len(lines), cells.nbytes, 0, 0, 0, 0, 0)
    return header + p.astype(">f4").tobytes() + cells.tobytes()


def decode_polydata(content: bytes) -> tuple[np.ndarray, list[list[int]]]:
    """Points (n, 3) and polylines of POLYDATA content (vertices, polygons, strips skipped)."""
    if len(content) < _POLYDATA_HEADER.size:
        raise MessageError(f"POLYDATA: {len(content)} bytes of content, shorter than its header")
    n, _, vert_bytes, n_lines, line_bytes, _, poly_bytes, _, strip_bytes, _ = _POLYDATA_HEADER.unpack_from(content)
    start = _POLYDATA_HEADER.size
    if start + 12 * n + vert_bytes + line_bytes + poly_bytes + strip_bytes > len(content):
        raise MessageError(f"POLYDATA: {n} points and cell lists do not fit {len(content)} bytes")
    points = np.frombuffer(content, dtype=">f4", count=3 * n, offset=start).astype(float).reshape(n, 3)
    offset = start + 12 * n + vert_bytes
    flat = np.frombuffer(content, dtype=">u4", count=line_bytes // 4, offset=offset).tolist()
    lines: list[list[int]] = []
    i = 0
    while i < len(flat) and len(lines) < n_lines:
        count = flat[i]
        lines.append(flat[i + 1:i + 1 + count])
        i += 1 + count
    return points, lines


_STRING_HEADER = struct.Struct(">HH")


def encode_string(text: str) -> bytes:
    """STRING content of ``text`` (UTF-8; at most 65535 bytes, OpenIGTLink's limit)."""
    raw = text.encode("utf-8")
    if len(raw) > 0xFFFF:
        raise ValueError(f"STRING of {len(raw)} bytes: longer than 65535 bytes, OpenIGTLink's limit")
    return _STRING_HEADER.pack(_IANA_UTF8, len(raw)) + raw


def decode_string(content: bytes) -> str:
    """The text of STRING content (US-ASCII or UTF-8)."""
    if len(content) < _STRING_HEADER.size:
        raise MessageError(f"STRING: {len(content)} bytes of content, shorter than its header")
    encoding, size = _STRING_HEADER.unpack_from(content)
    if _STRING_HEADER.size + size > len(content):
        raise MessageError(f"STRING: {size} bytes of text do not fit {len(content)} bytes")
    if encoding not in (_IANA_US_ASCII, _IANA_UTF8):
        raise MessageError(f"STRING: character encoding {encoding} (IANA MIBenum), expected 3 or 106")
    return content[_STRING_HEADER.size:_STRING_HEADER.size + size].decode("utf-8", "replace")
