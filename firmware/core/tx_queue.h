// Byte ring buffer for outgoing frames. A frame goes in whole or not at all, so a full queue
// drops frames (counted) instead of sending a truncated one the host would have to resync on.
#pragma once

#include <cstddef>
#include <cstdint>

namespace twinfw {

template <size_t Capacity>
class TxQueue {
 public:
  // Appends `size` bytes; false (and counted) if they do not all fit.
  bool push(const uint8_t* data, size_t size) {
    if (size > Capacity - size_) {
      ++dropped_;
      return false;
    }
    for (size_t i = 0; i < size; ++i) buf_[(head_ + size_ + i) % Capacity] = data[i];
    size_ += size;
    return true;
  }

  // Moves up to `capacity` bytes into `out`; returns how many.
  size_t take(uint8_t* out, size_t capacity) {
    const size_t n = size_ < capacity ? size_ : capacity;
    for (size_t i = 0; i < n; ++i) out[i] = buf_[(head_ + i) % Capacity];
    head_ = (head_ + n) % Capacity;
    size_ -= n;
    return n;
  }

  size_t size() const { return size_; }
  uint32_t dropped() const { return dropped_; }

 private:
  uint8_t buf_[Capacity];
  size_t head_ = 0;
  size_t size_ = 0;
  uint32_t dropped_ = 0;
};

}  // namespace twinfw
