#include "crc16.h"

namespace twinfw {

// Bitwise rather than table-driven: frames are ~130 bytes at 40 Hz, and 512 bytes of table
// would buy nothing measurable on a 120 MHz Cortex-M4.
uint16_t crc16_ccitt_false(const uint8_t* data, size_t size) {
  uint16_t crc = 0xFFFF;
  for (size_t i = 0; i < size; ++i) {
    crc ^= static_cast<uint16_t>(data[i]) << 8;
    for (int bit = 0; bit < 8; ++bit) {
      crc = (crc & 0x8000) ? static_cast<uint16_t>((crc << 1) ^ 0x1021) : static_cast<uint16_t>(crc << 1);
    }
  }
  return crc;
}

}  // namespace twinfw
