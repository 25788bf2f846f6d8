// CRC-16/CCITT-FALSE: polynomial 0x1021, initial value 0xFFFF, no reflection, no final XOR
// (Python: binascii.crc_hqx(data, 0xFFFF)). Detects every error burst up to 16 bits long.
#pragma once

#include <cstddef>
#include <cstdint>

namespace twinfw {

uint16_t crc16_ccitt_false(const uint8_t* data, size_t size);

}  // namespace twinfw
