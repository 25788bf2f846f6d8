#include "cobs.h"

namespace twinfw {

size_t cobs_encode(const uint8_t* data, size_t size, uint8_t* out, size_t capacity) {
  if (capacity < cobs_max_encoded_size(size)) return 0;
  size_t code_pos = 0;
  size_t pos = 1;
  uint8_t code = 1;
  for (size_t i = 0; i < size; ++i) {
    if (data[i] == 0) {
      out[code_pos] = code;
      code_pos = pos++;
      code = 1;
      continue;
    }
    out[pos++] = data[i];
    // A full block ends here; a new one starts only if data follows (canonical COBS).
    if (++code == 0xFF && i + 1 < size) {
      out[code_pos] = code;
      code_pos = pos++;
      code = 1;
    }
  }
  out[code_pos] = code;
  return pos;
}

size_t cobs_decode(const uint8_t* data, size_t size, uint8_t* out, size_t capacity) {
  size_t in = 0;
  size_t n = 0;
  while (in < size) {
    const uint8_t code = data[in++];
    if (code == 0 || in + code - 1 > size) return 0;
    for (uint8_t i = 1; i < code; ++i) {
      if (data[in] == 0 || n >= capacity) return 0;
      out[n++] = data[in++];
    }
    // A block shorter than 254 data bytes stands for a zero, except at the very end.
    if (code != 0xFF && in < size) {
      if (n >= capacity) return 0;
      out[n++] = 0;
    }
  }
  return n;
}

}  // namespace twinfw
