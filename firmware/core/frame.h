// Frames: [type u8][seq u16][payload][crc u16], all little-endian, the CRC taken over everything
// before it, then COBS-encoded and terminated by 0x00 (firmware/PROTOCOL.md §Framing).
#pragma once

#include <cstddef>
#include <cstdint>

#include "cobs.h"
#include "messages.h"

namespace twinfw {

constexpr size_t kFrameHeaderBytes = 3;
constexpr size_t kFrameCrcBytes = 2;
// The longest payload: TELEMETRY of kMaxChannels channels, 27 + 25 per channel + the stale mask
// + the encoder history (2 bytes per tick and channel).
constexpr size_t kMaxPayloadBytes =
    27 + 25 * kMaxChannels + mask_bytes(kMaxChannels) + 2 * kTelemetryTicks * kMaxChannels;
constexpr size_t kMaxRawFrameBytes = kFrameHeaderBytes + kMaxPayloadBytes + kFrameCrcBytes;
// Encoded frame including its 0x00 delimiter.
constexpr size_t kMaxEncodedFrameBytes = cobs_max_encoded_size(kMaxRawFrameBytes) + 1;

// Encodes one frame with its delimiter into `out`; returns its size, or 0 if the payload is
// larger than kMaxPayloadBytes or `capacity` is too small.
size_t encode_frame(uint8_t type, uint16_t seq, const uint8_t* payload, size_t payload_size,
                    uint8_t* out, size_t capacity);

template <class T>
size_t encode_message(const T& message, uint16_t seq, uint8_t* out, size_t capacity) {
  uint8_t payload[kMaxPayloadBytes] = {};
  size_t size = 0;
  if (!write_payload(message, payload, sizeof payload, size)) return 0;
  return encode_frame(static_cast<uint8_t>(T::kType), seq, payload, size, out, capacity);
}

// A frame that passed COBS and CRC; `payload` points into the decoder and is valid until the
// next byte is pushed.
struct RawFrame {
  uint8_t type;
  uint16_t seq;
  const uint8_t* payload;
  size_t payload_size;
};

// Streaming receiver: push bytes one at a time as they arrive in any chunking. Anything that
// is not a complete, valid frame is counted and dropped, and reception resynchronises on the
// next 0x00. Empty frames (repeated delimiters) are ignored, so a sender may lead with 0x00
// to flush a partial frame left on the line.
class FrameDecoder {
 public:
  // True when `byte` completed a valid frame; read it with frame().
  bool push(uint8_t byte);
  const RawFrame& frame() const { return frame_; }
  uint32_t bad_frames() const { return bad_frames_; }

 private:
  bool finish();

  uint8_t encoded_[kMaxEncodedFrameBytes];
  uint8_t raw_[kMaxRawFrameBytes];
  size_t size_ = 0;
  bool overflow_ = false;
  uint32_t bad_frames_ = 0;
  RawFrame frame_{};
};

}  // namespace twinfw
