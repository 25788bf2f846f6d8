#include "frame.h"

#include <cstring>

#include "crc16.h"

namespace twinfw {

size_t encode_frame(uint8_t type, uint16_t seq, const uint8_t* payload, size_t payload_size,
                    uint8_t* out, size_t capacity) {
  if (payload_size > kMaxPayloadBytes) return 0;
  uint8_t raw[kMaxRawFrameBytes];
  raw[0] = type;
  raw[1] = static_cast<uint8_t>(seq);
  raw[2] = static_cast<uint8_t>(seq >> 8);
  if (payload_size > 0) std::memcpy(raw + kFrameHeaderBytes, payload, payload_size);
  const size_t body = kFrameHeaderBytes + payload_size;
  const uint16_t crc = crc16_ccitt_false(raw, body);
  raw[body] = static_cast<uint8_t>(crc);
  raw[body + 1] = static_cast<uint8_t>(crc >> 8);
  if (capacity == 0) return 0;
  const size_t encoded = cobs_encode(raw, body + kFrameCrcBytes, out, capacity - 1);
  if (encoded == 0) return 0;
  out[encoded] = 0x00;
  return encoded + 1;
}

bool FrameDecoder::push(uint8_t byte) {
  if (byte != 0x00) {
    if (size_ < sizeof encoded_) {
      encoded_[size_++] = byte;
    } else {
      overflow_ = true;
    }
    return false;
  }
  const bool valid = finish();
  size_ = 0;
  overflow_ = false;
  return valid;
}

bool FrameDecoder::finish() {
  if (size_ == 0 && !overflow_) return false;
  const size_t n = overflow_ ? 0 : cobs_decode(encoded_, size_, raw_, sizeof raw_);
  if (n < kFrameHeaderBytes + kFrameCrcBytes) {
    ++bad_frames_;
    return false;
  }
  const size_t body = n - kFrameCrcBytes;
  const uint16_t crc = static_cast<uint16_t>(raw_[body] | (raw_[body + 1] << 8));
  if (crc != crc16_ccitt_false(raw_, body)) {
    ++bad_frames_;
    return false;
  }
  frame_.type = raw_[0];
  frame_.seq = static_cast<uint16_t>(raw_[1] | (raw_[2] << 8));
  frame_.payload = raw_ + kFrameHeaderBytes;
  frame_.payload_size = body - kFrameHeaderBytes;
  return true;
}

}  // namespace twinfw
