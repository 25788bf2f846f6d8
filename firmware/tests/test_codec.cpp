#include <cstring>

#include "check.h"
#include "cobs.h"
#include "crc16.h"
#include "frame.h"
#include "golden_vectors.h"
#include "suites.h"

using namespace twinfw;

namespace {

size_t from_hex(const char* hex, uint8_t* out, size_t capacity) {
  size_t n = 0;
  auto nibble = [](char c) { return c <= '9' ? c - '0' : c - 'a' + 10; };
  for (; hex[0] && hex[1] && n < capacity; hex += 2) out[n++] = static_cast<uint8_t>(nibble(hex[0]) << 4 | nibble(hex[1]));
  return n;
}

bool cobs_case(const uint8_t* data, size_t size, const uint8_t* expected, size_t expected_size) {
  uint8_t enc[300];
  uint8_t dec[300];
  const size_t n = cobs_encode(data, size, enc, sizeof enc);
  const size_t m = cobs_decode(enc, n, dec, sizeof dec);
  return n == expected_size && std::memcmp(enc, expected, n) == 0 && m == size &&
         std::memcmp(dec, data, size) == 0;
}

void crc_check_value() {
  const uint8_t text[] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
  CHECK(crc16_ccitt_false(text, sizeof text) == 0x29B1);  // the catalogued check value
}

void cobs_reference_examples() {
  // Cheshire & Baker / Wikipedia examples.
  const uint8_t z1[] = {0x00}, e1[] = {0x01, 0x01};
  const uint8_t z2[] = {0x00, 0x00}, e2[] = {0x01, 0x01, 0x01};
  const uint8_t d3[] = {0x11, 0x22, 0x00, 0x33}, e3[] = {0x03, 0x11, 0x22, 0x02, 0x33};
  const uint8_t d4[] = {0x11, 0x22, 0x33, 0x44}, e4[] = {0x05, 0x11, 0x22, 0x33, 0x44};
  const uint8_t d5[] = {0x11, 0x00, 0x00, 0x00}, e5[] = {0x02, 0x11, 0x01, 0x01, 0x01};
  CHECK(cobs_case(z1, 1, e1, 2));
  CHECK(cobs_case(z2, 2, e2, 3));
  CHECK(cobs_case(d3, 4, e3, 5));
  CHECK(cobs_case(d4, 4, e4, 5));
  CHECK(cobs_case(d5, 4, e5, 5));
  // 01..FE (254 bytes) → FF 01..FE; 01..FF (255 bytes) → FF 01..FE 02 FF.
  uint8_t run[255], expected[257];
  for (int i = 0; i < 255; ++i) run[i] = static_cast<uint8_t>(i + 1);
  expected[0] = 0xFF;
  std::memcpy(expected + 1, run, 254);
  CHECK(cobs_case(run, 254, expected, 255));
  expected[255] = 0x02;
  expected[256] = 0xFF;
  CHECK(cobs_case(run, 255, expected, 257));
  // Invalid: a block running past the end, a zero inside.
  const uint8_t past_end[] = {0x05, 0x11, 0x22};
  const uint8_t zero_inside[] = {0x03, 0x11, 0x00};
  uint8_t out[8];
  CHECK(cobs_decode(past_end, sizeof past_end, out, sizeof out) == 0);
  CHECK(cobs_decode(zero_inside, sizeof zero_inside, out, sizeof out) == 0);
}

struct ValidVectorCheck {
  int vectors = 0;
  template <class T>
  void operator()(const char* name, uint16_t seq, const T& message, const char* hex) {
    ++vectors;
    uint8_t golden[kMaxEncodedFrameBytes];
    const size_t golden_size = from_hex(hex, golden, sizeof golden);
    uint8_t encoded[kMaxEncodedFrameBytes];
    const size_t n = encode_message(message, seq, encoded, sizeof encoded);
    if (!CHECK(n == golden_size && std::memcmp(encoded, golden, n) == 0)) std::printf("     encode %s\n", name);
    // Decode the golden bytes and encode the result again: the same bytes must come back.
    FrameDecoder decoder;
    int frames = 0;
    for (size_t i = 0; i < golden_size; ++i) {
      if (!decoder.push(golden[i])) continue;
      ++frames;
      const RawFrame& f = decoder.frame();
      T decoded{};
      const bool ok = f.type == static_cast<uint8_t>(T::kType) && f.seq == seq &&
                      read_payload(f.payload, f.payload_size, decoded);
      const size_t m = ok ? encode_message(decoded, f.seq, encoded, sizeof encoded) : 0;
      if (!CHECK(m == golden_size && std::memcmp(encoded, golden, m) == 0)) std::printf("     decode %s\n", name);
    }
    CHECK(frames == 1 && decoder.bad_frames() == 0);
  }
};

template <class T>
bool decodes_as(const RawFrame& f) {
  T message{};
  return f.type == static_cast<uint8_t>(T::kType) && read_payload(f.payload, f.payload_size, message);
}

// Intact-but-invalid frames must fail message decoding as the type they claim: a short payload,
// or one sized for another channel count than it says.
bool decodes_as_any_command(const RawFrame& f) {
  return decodes_as<msg::SetMode>(f) || decodes_as<msg::Tare>(f) || decodes_as<msg::SetSetpoints>(f) ||
         decodes_as<msg::SetCalibration>(f) || decodes_as<msg::TelemetryMessage>(f);
}

void golden_vectors() {
  ValidVectorCheck valid;
  golden::for_each_valid(valid);
  CHECK(valid.vectors >= 14);
  CHECK(golden::kProtocolVersion == kProtocolVersion);
  for (const golden::Invalid& v : golden::kInvalid) {
    uint8_t bytes[512];
    const size_t n = from_hex(v.hex, bytes, sizeof bytes);
    FrameDecoder decoder;
    int accepted = 0;
    bool any_valid_message = false;
    for (size_t i = 0; i < n; ++i) {
      if (decoder.push(bytes[i])) {
        ++accepted;
        any_valid_message = any_valid_message || decodes_as_any_command(decoder.frame());
      }
    }
    const bool ok = v.intact ? (accepted == 1 && !any_valid_message && decoder.bad_frames() == 0)
                             : (accepted == 0 && decoder.bad_frames() == 1);
    if (!CHECK(ok)) std::printf("     invalid vector %s\n", v.name);
  }
}

size_t encode_ping(uint16_t seq, uint8_t* out) { return encode_message(msg::Ping{}, seq, out, kMaxEncodedFrameBytes); }

void resynchronises_after_garbage() {
  uint8_t stream[2 * kMaxEncodedFrameBytes + 100];
  size_t n = 0;
  // Garbage runs into the next frame up to its delimiter: that frame is lost (a sender that
  // may have left a partial frame on the line leads with 0x00).
  for (int i = 0; i < 50; ++i) stream[n++] = static_cast<uint8_t>(0x30 + i);
  n += encode_ping(1, stream + n);
  stream[n++] = 0x00;  // an empty frame is ignored, not counted
  n += encode_ping(2, stream + n);
  for (size_t i = 0; i < kMaxEncodedFrameBytes + 10; ++i) stream[n++] = 0x55;  // an over-long run
  stream[n++] = 0x00;
  uint8_t truncated[kMaxEncodedFrameBytes];
  const size_t t = encode_ping(3, truncated);
  std::memcpy(stream + n, truncated, t - 3);  // cut before the end, then a delimiter
  n += t - 3;
  stream[n++] = 0x00;
  n += encode_ping(4, stream + n);
  FrameDecoder decoder;
  uint16_t seqs[4];
  int frames = 0;
  for (size_t i = 0; i < n; ++i) {
    if (decoder.push(stream[i]) && frames < 4) seqs[frames++] = decoder.frame().seq;
  }
  CHECK(frames == 2 && seqs[0] == 2 && seqs[1] == 4);
  CHECK(decoder.bad_frames() == 3);
}

// Every single-bit error in every golden frame is rejected. In a data byte CRC-16 guarantees
// it; a flip in a COBS code byte re-blocks the frame and a flip to 0x00 splits it, which the
// CRC catches with probability 1 − 2^-16: checked here for all golden frames.
void single_bit_errors_never_accepted() {
  int mutations = 0;
  int false_accepts = 0;
  golden::for_each_valid([&](const char*, uint16_t, const auto&, const char* hex) {
    uint8_t golden[kMaxEncodedFrameBytes];
    const size_t n = from_hex(hex, golden, sizeof golden);
    for (size_t pos = 0; pos + 1 < n; ++pos) {
      for (int bit = 0; bit < 8; ++bit) {
        uint8_t mutated[kMaxEncodedFrameBytes];
        std::memcpy(mutated, golden, n);
        mutated[pos] = static_cast<uint8_t>(mutated[pos] ^ (1u << bit));
        ++mutations;
        FrameDecoder decoder;
        for (size_t i = 0; i < n; ++i) {
          if (decoder.push(mutated[i])) ++false_accepts;
        }
      }
    }
  });
  CHECK(mutations > 2500);
  CHECK(false_accepts == 0);
}

void random_bytes_do_not_decode() {
  uint32_t state = 12345u;
  FrameDecoder decoder;
  int accepted = 0;
  for (int i = 0; i < 200000; ++i) {
    state = state * 1664525u + 1013904223u;
    // Bias towards 0x00 so that many short candidate frames reach the CRC check.
    const uint8_t byte = (state >> 24) < 16 ? 0 : static_cast<uint8_t>(state >> 16);
    if (decoder.push(byte)) ++accepted;
  }
  CHECK(decoder.bad_frames() > 10000);
  CHECK(accepted <= 1);  // ~12,000 candidates at 2^-16 each
}

}  // namespace

void test_codec() {
  crc_check_value();
  cobs_reference_examples();
  golden_vectors();
  resynchronises_after_garbage();
  single_bit_errors_never_accepted();
  random_bytes_do_not_decode();
}
