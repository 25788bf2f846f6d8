"""The Python codec against the golden vectors, and both codecs under fuzzing.

The same ``firmware/golden/vectors.json`` is checked by the C++ tests (``make -C firmware
host-test``), so a change to either codec that moves a byte fails one side.
"""

from __future__ import annotations

import binascii
import dataclasses
import json
import re
import struct

import numpy as np
import pytest
from conftest import load_script

from twin.driver import codec as c
from twin.device.board import TICK_S
from twin.device.firmware_lib import FIRMWARE_DIR, FirmwareFrameDecoder
from twin.driver.telemetry import Telemetry

VECTORS_PATH = FIRMWARE_DIR / "golden" / "vectors.json"
VECTORS = json.loads(VECTORS_PATH.read_text())


def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def _wire_value(value):
    """A JSON field value as it reads back from the wire (floats rounded to float32)."""
    if isinstance(value, list):
        return tuple(_wire_value(v) for v in value)
    return _f32(value) if isinstance(value, float) else value


@pytest.mark.parametrize("vector", VECTORS["valid"], ids=lambda v: v["name"])
def test_golden_valid_vector_decodes_to_its_fields_and_encodes_back(vector):
    frame = bytes.fromhex(vector["hex"])
    assert frame.endswith(b"\x00") and b"\x00" not in frame[:-1]
    decoded = c.decode_frame(frame[:-1])
    assert type(decoded.message).__name__ == vector["message"]
    assert decoded.seq == vector["seq"]
    assert dataclasses.asdict(decoded.message) == {k: _wire_value(v) for k, v in vector["fields"].items()}
    cls = c.MESSAGE_TYPES[decoded.message.TYPE]
    rebuilt = cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in vector["fields"].items()})
    assert c.encode_frame(rebuilt, vector["seq"]).hex() == vector["hex"]


@pytest.mark.parametrize("vector", VECTORS["invalid"], ids=lambda v: v["name"])
def test_golden_invalid_vector_is_counted_and_skipped(vector):
    decoder = c.FrameDecoder()
    assert decoder.feed(bytes.fromhex(vector["hex"])) == []
    expected = (1, 0) if vector["expect"] == "bad_frame" else (0, 1)
    assert (decoder.bad_frames, decoder.bad_messages) == expected


def test_every_message_type_has_a_golden_vector():
    assert {v["message"] for v in VECTORS["valid"]} == {cls.__name__ for cls in c.MESSAGE_TYPES.values()}
    assert VECTORS["protocol_version"] == c.PROTOCOL_VERSION


def test_golden_file_is_what_its_script_writes():
    make_vectors = load_script(FIRMWARE_DIR / "golden" / "make_vectors.py")
    assert make_vectors.build() == VECTORS


def test_set_limits_frame_built_by_hand_from_protocol_md():
    # PROTOCOL.md: [type][seq u16][payload][crc u16 over the rest], COBS, 0x00. SET_LIMITS = 0x0A,
    # payload tension_limit_n f32 + watchdog_timeout_ms u16 + loadcell_gain_counts_per_n f32.
    body = bytes([0x0A]) + struct.pack("<H", 12) + struct.pack("<fHf", 6.0, 250, 45000.0)
    raw = body + struct.pack("<H", binascii.crc_hqx(body, 0xFFFF))
    assert raw.hex() == "0a0c000000c040fa0000c82f4742df"
    cobs = bytes.fromhex("030a0c010104c040fa0106c82f4742df")  # zeros at bytes 2, 3, 4, 8 and 9 stuffed by hand
    assert c.cobs_decode(cobs) == raw
    assert c.encode_frame(c.SetLimits(6.0, 250, 45000.0), seq=12) == cobs + b"\x00"


def test_crc_check_value():
    assert c.crc16(b"123456789") == 0x29B1


@pytest.mark.parametrize(
    "data, encoded",
    [
        ("00", "0101"),
        ("0000", "010101"),
        ("11220033", "0311220233"),
        ("11223344", "0511223344"),
        ("11000000", "0211010101"),
        (bytes(range(1, 255)).hex(), "ff" + bytes(range(1, 255)).hex()),
        (bytes(range(1, 256)).hex(), "ff" + bytes(range(1, 255)).hex() + "02ff"),
        ("00" + bytes(range(1, 255)).hex(), "01ff" + bytes(range(1, 255)).hex()),
    ],
)
def test_cobs_reference_examples(data, encoded):
    assert c.cobs_encode(bytes.fromhex(data)).hex() == encoded
    assert c.cobs_decode(bytes.fromhex(encoded)).hex() == data


def test_cobs_round_trips_random_data():
    rng = np.random.default_rng(1)
    for size in [0, 1, 2, 253, 254, 255, 508, 600]:
        for zero_fraction in (0.0, 0.1, 0.9):
            data = rng.integers(1, 256, size).astype(np.uint8)
            data[rng.random(size) < zero_fraction] = 0
            encoded = c.cobs_encode(data.tobytes())
            assert 0 not in encoded and len(encoded) <= size + size // 254 + 1
            assert c.cobs_decode(encoded) == data.tobytes()


@pytest.mark.parametrize("bad, code", [("00", 0), ("0511", 5), ("031100", 3), ("02", 2)])
def test_cobs_rejects_invalid_input(bad, code):
    with pytest.raises(c.FrameError, match=f"code {code} at byte 0"):
        c.cobs_decode(bytes.fromhex(bad))


def _random_message(cls: type[c.Message], rng: np.random.Generator) -> c.Message:
    """A message of ``cls`` with random fields; one sized by the channel count gets a random count."""
    channels = int(rng.integers(1, c.MAX_CHANNELS + 1))
    ranges = {"B": (0, 2**8), "H": (0, 2**16), "I": (0, 2**32), "Q": (0, 2**64), "i": (-(2**31), 2**31),
              "h": (-(2**15), 2**15), "m": (0, 2**channels)}
    fields = {}
    for name, code in cls.LAYOUT:
        if code[0] == "*":
            count, kind = channels, code[1:]
        elif code[0] == "#":
            count, kind = c.TELEMETRY_TICKS * channels, code[1:]
        else:
            count, kind = (int(code[:-1]), code[-1]) if code[0].isdigit() else (None, code)
        if name == "channels" and cls.TYPE != c.MsgType.HELLO_REPLY:
            fields[name] = channels
            continue
        def one():
            if kind == "f":
                return _f32(float(rng.normal(0.0, 10.0)))
            lo, hi = ranges[kind]
            return int(rng.integers(lo, hi, dtype=np.uint64 if kind == "Q" else np.int64))
        fields[name] = tuple(one() for _ in range(count)) if count else one()
    return cls(**fields)


@pytest.mark.parametrize("cls", list(c.MESSAGE_TYPES.values()), ids=lambda cls: cls.__name__)
def test_every_message_round_trips(cls):
    rng = np.random.default_rng(cls.TYPE)
    for k in range(20):
        message = _random_message(cls, rng)
        seq = int(rng.integers(0, 2**16))
        frame = c.encode_frame(message, seq)
        assert c.decode_frame(frame[:-1]) == c.Frame(seq, message)


def test_encode_names_the_bad_value():
    with pytest.raises(c.CodecError, match="seq = 70000"):
        c.encode_frame(c.Ping(), 70000)
    with pytest.raises(c.CodecError, match="must have 4 entries"):
        c.encode_frame(c.SetSetpoints(0, (1.0, 2.0)), 1)
    with pytest.raises(c.CodecError, match="lengths_m"):
        c.SetSetpoints.lengths([0.0, 0.0, 0.0])
    with pytest.raises(c.CodecError, match="Tare"):
        c.encode_frame(c.Tare(loadcell_mask=300), 1)


def _golden_frames() -> list[bytes]:
    return [bytes.fromhex(v["hex"]) for v in VECTORS["valid"]]


def test_stream_in_random_chunks_yields_every_frame():
    rng = np.random.default_rng(2)
    frames = _golden_frames() * 5
    stream = b"\x00".join([b"\x07\x08\x09garbage"] + frames)
    decoder = c.FrameDecoder()
    out = []
    cuts = np.sort(rng.integers(0, len(stream), 60))
    for chunk in np.split(np.frombuffer(stream, np.uint8), cuts):
        out += decoder.feed(chunk.tobytes())
    # The garbage runs into the first frame up to its delimiter; the sender can lead with 0x00.
    assert [f.seq for f in out] == [v["seq"] for v in VECTORS["valid"]] * 5
    assert decoder.bad_frames == 1


def _mutate(frame: bytes, rng: np.random.Generator) -> bytes:
    """One random corruption of an encoded frame (delimiter kept at the end)."""
    body = bytearray(frame[:-1])
    kind = rng.integers(0, 6)
    pos = int(rng.integers(0, len(body)))
    if kind == 0:
        body[pos] ^= 1 << int(rng.integers(0, 8))  # bit flip
    elif kind == 1:
        body[pos] = (body[pos] + int(rng.integers(1, 256))) % 256  # byte substitution, may be 0x00
    elif kind == 2:
        del body[pos]  # dropped byte
    elif kind == 3:
        body.insert(pos, int(rng.integers(0, 256)))  # inserted byte
    elif kind == 4:
        body = body[:pos]  # truncated
    else:
        for p in rng.integers(0, len(body), 3):  # a burst of three random bytes
            body[int(p)] = int(rng.integers(0, 256))
    return bytes(body) + b"\x00"


def test_mutated_frames_are_never_accepted_by_either_codec():
    rng = np.random.default_rng(3)
    golden = _golden_frames()
    mutations = false_accepts_py = false_accepts_cpp = 0
    for _ in range(4000):
        frame = golden[int(rng.integers(0, len(golden)))]
        mutated = _mutate(frame, rng)
        if mutated == frame:
            continue
        mutations += 1
        original = c.decode_frame(frame[:-1])
        py, cpp = c.FrameDecoder(), FirmwareFrameDecoder()
        false_accepts_py += sum(f != original for f in py.feed(mutated))
        raw = c.cobs_decode(frame[:-1])
        false_accepts_cpp += sum((t, s, p) != (raw[0], raw[1] | raw[2] << 8, raw[3:-2]) for t, s, p in cpp.feed(mutated))
        # Same algorithm, same verdict: every fragment the C++ decoder rejects, Python rejects.
        assert cpp.bad_frames == py.bad_frames, mutated.hex()
    assert mutations > 3900
    assert false_accepts_py == 0 and false_accepts_cpp == 0


def test_random_bytes_never_crash_and_are_counted():
    rng = np.random.default_rng(4)
    stream = rng.integers(0, 256, 300_000).astype(np.uint8)
    stream[rng.random(stream.size) < 0.05] = 0  # many short candidate frames
    data = stream.tobytes()
    py, cpp = c.FrameDecoder(), FirmwareFrameDecoder()
    py_frames, cpp_frames = [], []
    for start in range(0, len(data), 4096):
        py_frames += py.feed(data[start : start + 4096])
        cpp_frames += cpp.feed(data[start : start + 4096])
    candidates = data.count(0)
    assert py.bad_frames > 0.9 * candidates
    assert cpp.bad_frames == py.bad_frames
    # ~14,000 candidates, each passing the CRC with p = 2^-16: none expected for this seed.
    assert py_frames == [] and cpp_frames == []


def test_golden_vectors_pin_every_sized_message_at_two_channel_counts_or_more():
    sized = {cls.__name__ for cls in c.MESSAGE_TYPES.values() if cls.LAYOUT[:1] == (("channels", "B"),)}
    assert sized == {"Tare", "SetSetpoints", "SetCalibration", "TelemetryMessage"}
    for name in sized | {"HelloReply"}:
        counts = {v["fields"]["channels"] for v in VECTORS["valid"] if v["message"] == name}
        assert {3, 4, 8} <= counts, name


def test_a_sized_message_is_decoded_by_the_count_it_carries():
    for channels in (1, 3, 4, 8, c.MAX_CHANNELS):
        message = c.TelemetryMessage(channels=channels, encoder_counts=tuple(range(channels)),
                                     lengths_m=(0.5,) * channels, raw_counts=(-1,) * channels,
                                     tensions_n=(0.25,) * channels, targets=(0.0,) * channels,
                                     duty=(-1.0,) * channels, drive_modes=(c.Drive.BRAKE,) * channels,
                                     stale_mask=1 << (channels - 1),
                                     encoder_history=tuple(range(-c.TELEMETRY_TICKS * channels, 0)))
        payload = c.encode_payload(message)
        # PROTOCOL.md's sizes: 27 + 25 N + M, and 2 bytes per tick and channel of the encoder history.
        assert len(payload) == c.payload_size(c.MsgType.TELEMETRY, channels) == (
            27 + 25 * channels + c.mask_bytes(channels) + 2 * c.TELEMETRY_TICKS * channels)
        assert c.decode_payload(c.MsgType.TELEMETRY, payload) == message
        assert message.drives() == (c.Drive.BRAKE,) * channels
    # The longest payload is the telemetry of the most channels.
    assert c.MAX_PAYLOAD_BYTES == c.payload_size(c.MsgType.TELEMETRY, c.MAX_CHANNELS)
    assert max(c.payload_size(t, c.MAX_CHANNELS) for t in c.MESSAGE_TYPES) == c.MAX_PAYLOAD_BYTES


def test_a_count_beyond_the_protocols_or_one_its_length_does_not_fit_is_a_bad_message():
    payload = bytearray(c.encode_payload(c.Tare(loadcell_mask=1, channels=4)))
    payload[0] = c.MAX_CHANNELS + 1
    with pytest.raises(c.MessageError, match="Tare.channels = 13: must be in 1..12"):
        c.decode_payload(c.MsgType.TARE, bytes(payload))
    payload[0] = 0
    with pytest.raises(c.MessageError, match="Tare.channels = 0"):
        c.decode_payload(c.MsgType.TARE, bytes(payload))
    telemetry = bytearray(c.encode_payload(c.TelemetryMessage()))
    telemetry[0] = 3
    with pytest.raises(c.MessageError, match="payload is 168 bytes, expected 133 for 3 channels"):
        c.decode_payload(c.MsgType.TELEMETRY, bytes(telemetry))
    with pytest.raises(c.CodecError, match="channels = 13: must be in 1..12"):
        c.encode_payload(c.SetSetpoints(values=(0.0,) * 13, channels=13))
    with pytest.raises(c.CodecError, match="must have 3 entries"):
        c.encode_payload(c.SetCalibration(channels=3))


def test_a_hello_reply_names_one_to_max_channels():
    for channels in (1, 3, 8, c.MAX_CHANNELS):
        c.check_fields(c.HelloReply(channels=channels))
    for channels in (0, c.MAX_CHANNELS + 1):
        with pytest.raises(c.MessageError, match=f"HelloReply.channels = {channels}"):
            c.check_fields(c.HelloReply(channels=channels))


def test_pairs_couple_tendon_k_with_k_plus_half():
    assert c.SetSetpoints.pairs([0.001, -0.002], channels=4).values == (0.001, -0.002, 0.0, 0.0)
    assert c.SetSetpoints.pairs([0.001, 0.0, 0.5], channels=6).values == (0.001, 0.0, 0.5, 0.0, 0.0, 0.0)
    assert [c.pairs_possible(n) for n in (1, 2, 3, 4, 5, 6)] == [False, True, False, True, False, True]
    with pytest.raises(c.CodecError, match="pair_lengths_m"):
        c.SetSetpoints.pairs([0.001], channels=4)


def test_a_telemetry_frame_carries_the_ticks_of_one_telemetry_period():
    config = (FIRMWARE_DIR / "core" / "config.h").read_text()

    def us(name):
        return int(re.search(rf"constexpr uint32_t {name} = (\d+);", config).group(1))

    assert c.TELEMETRY_TICKS == us("kTelemetryPeriodUs") // us("kTickPeriodUs") == 5
    assert us("kTickPeriodUs") * 1e-6 == TICK_S


def test_the_host_sees_the_encoder_history_as_counts_of_each_tick():
    vector = next(v for v in VECTORS["valid"] if v["name"] == "telemetry")
    message = c.decode_frame(bytes.fromhex(vector["hex"])[:-1]).message
    sample = Telemetry.from_message(message, received_s=0.0)
    counts = np.array(vector["fields"]["encoder_counts"])
    differences = np.array(vector["fields"]["encoder_history"]).reshape(c.TELEMETRY_TICKS, 4)
    assert sample.encoder_history_counts.shape == (5, 4) and sample.encoder_history_counts.dtype == np.int64
    assert np.array_equal(sample.encoder_history_counts, counts + differences)
    assert np.array_equal(sample.encoder_history_counts[-1], sample.encoder_counts)
    # Channel 4 (−2,000,000 counts) beyond the int16 range at the oldest ticks: saturated.
    assert sample.encoder_history_counts[0].tolist() == [21709 - 40, -1 + 12, 0, -2_000_000 - 32768]


@pytest.mark.parametrize("message, field", [
    # Before: taken as telemetry with a fault the host had no name for.
    (c.TelemetryMessage(channels=3, fault_flags=int(c.Fault.TENSION_CHANNEL_4)), "fault_flags"),
    (c.TelemetryMessage(fault_flags=1 << 4), "fault_flags"),
    # Before: not counted.
    (c.Nack(acked_type=c.MsgType.ENABLE, error=99), "error"),
    (c.Ack(acked_type=0xEE), "acked_type"),
])
def test_a_field_the_protocol_does_not_define_is_counted_bad_and_skipped(message, field):
    channels = getattr(message, "channels", c.DEFAULT_CHANNELS)
    if isinstance(message, c.TelemetryMessage):
        n = channels
        message = dataclasses.replace(message, encoder_counts=(0,) * n, lengths_m=(0.0,) * n, raw_counts=(0,) * n,
                                      tensions_n=(0.0,) * n, targets=(0.0,) * n, duty=(0.0,) * n,
                                      drive_modes=(c.Drive.COAST,) * n, encoder_history=(0,) * (c.TELEMETRY_TICKS * n))
    with pytest.raises(c.MessageError, match=field):
        c.check_fields(message)
    decoder = c.FrameDecoder()
    assert decoder.feed(c.encode_frame(message, 1)) == [] and decoder.bad_messages == 1
    good = c.TelemetryMessage(fault_flags=int(c.Fault.WATCHDOG | c.Fault.TENSION_CHANNEL_4 | c.Fault.IMPLAUSIBLE_CHANNEL_1))
    assert len(decoder.feed(c.encode_frame(good, 2))) == 1
