// Consistent Overhead Byte Stuffing (Cheshire & Baker 1999): removes every 0x00 from a frame
// so that 0x00 can delimit frames and a receiver can resynchronise on the next one.
#pragma once

#include <cstddef>
#include <cstdint>

namespace twinfw {

// Worst-case encoded size of `size` bytes (without the delimiter).
constexpr size_t cobs_max_encoded_size(size_t size) { return size + size / 254 + 1; }

// Encodes `size` bytes into `out` (no delimiter appended); returns the encoded size, or 0 if
// `capacity` is too small.
size_t cobs_encode(const uint8_t* data, size_t size, uint8_t* out, size_t capacity);

// Decodes one frame (without its delimiter); returns the decoded size, or 0 if the input is not
// valid COBS (a zero byte, a block running past the end) or does not fit in `capacity`.
size_t cobs_decode(const uint8_t* data, size_t size, uint8_t* out, size_t capacity);

}  // namespace twinfw
