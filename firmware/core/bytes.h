// Little-endian field writer and reader over a caller-owned buffer; out-of-range access sets a
// flag instead of writing past the end, so a short or long payload is a checked error.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>

namespace twinfw {

// The first `count` entries of an array of `capacity`: a per-channel field, as many entries as
// the message's channel count (read before it). A count beyond the capacity fails the read or
// write.
template <class T>
struct Span {
  T* data;
  size_t count;
  size_t capacity;
};
template <class T, size_t N>
Span<T> first(T (&values)[N], size_t count) {
  return Span<T>{values, count, N};
}
template <class T, size_t N>
Span<const T> first(const T (&values)[N], size_t count) {
  return Span<const T>{values, count, N};
}

// A bit per channel in ceil(channels / 8) bytes, channel 0 in bit 0 of the first byte; more
// channels than `capacity` fail the read or write.
template <class T>
struct Bits {
  T* bits;
  size_t channels;
  size_t capacity;
};
template <class T>
Bits<T> bits_of(T& bits, size_t channels, size_t capacity) {
  return Bits<T>{&bits, channels, capacity};
}
constexpr size_t mask_bytes(size_t channels) { return (channels + 7) / 8; }
// Whether a mask of `mask.channels` fits its capacity and its integer.
template <class T>
bool mask_fits(const Bits<T>& mask) {
  return mask.channels <= mask.capacity && mask_bytes(mask.channels) <= sizeof(T);
}

// Gives each entry of `values` to the visitor `v`; false, visiting none, when its count exceeds
// its capacity.
template <class V, class T>
bool visit_each(V& v, const Span<T>& values) {
  if (values.count > values.capacity) return false;
  for (size_t i = 0; i < values.count; ++i) v(values.data[i]);
  return true;
}

class ByteWriter {
 public:
  ByteWriter(uint8_t* buf, size_t capacity) : buf_(buf), capacity_(capacity) {}

  void operator()(uint8_t v) { put(v, 1); }
  void operator()(uint16_t v) { put(v, 2); }
  void operator()(uint32_t v) { put(v, 4); }
  void operator()(uint64_t v) { put(v, 8); }
  void operator()(int32_t v) { put(static_cast<uint32_t>(v), 4); }
  void operator()(int16_t v) { put(static_cast<uint16_t>(v), 2); }
  void operator()(float v) {
    uint32_t bits;
    std::memcpy(&bits, &v, sizeof bits);
    put(bits, 4);
  }
  template <class T, size_t N>
  void operator()(const T (&values)[N]) {
    for (const T& v : values) (*this)(v);
  }
  template <class T>
  void operator()(const Span<T>& values) {
    if (!visit_each(*this, values)) ok_ = false;
  }
  template <class T>
  void operator()(const Bits<T>& mask) {
    const size_t n = mask_bytes(mask.channels);
    // A bit beyond the mask's bytes cannot be carried: refused, not dropped.
    if (mask_fits(mask) && (n == sizeof(T) || (static_cast<uint64_t>(*mask.bits) >> (8 * n)) == 0)) {
      put(*mask.bits, n);
    } else {
      ok_ = false;
    }
  }

  size_t size() const { return size_; }
  bool ok() const { return ok_; }

 private:
  void put(uint64_t v, size_t n) {
    if (size_ + n > capacity_) {
      ok_ = false;
      return;
    }
    for (size_t i = 0; i < n; ++i) buf_[size_++] = static_cast<uint8_t>(v >> (8 * i));
  }

  uint8_t* buf_;
  size_t capacity_;
  size_t size_ = 0;
  bool ok_ = true;
};

class ByteReader {
 public:
  ByteReader(const uint8_t* buf, size_t size) : buf_(buf), size_(size) {}

  void operator()(uint8_t& v) { v = static_cast<uint8_t>(get(1)); }
  void operator()(uint16_t& v) { v = static_cast<uint16_t>(get(2)); }
  void operator()(uint32_t& v) { v = static_cast<uint32_t>(get(4)); }
  void operator()(uint64_t& v) { v = get(8); }
  void operator()(int32_t& v) { v = static_cast<int32_t>(static_cast<uint32_t>(get(4))); }
  void operator()(int16_t& v) { v = static_cast<int16_t>(static_cast<uint16_t>(get(2))); }
  void operator()(float& v) {
    const uint32_t bits = static_cast<uint32_t>(get(4));
    std::memcpy(&v, &bits, sizeof v);
  }
  template <class T, size_t N>
  void operator()(T (&values)[N]) {
    for (T& v : values) (*this)(v);
  }
  template <class T>
  void operator()(const Span<T>& values) {
    if (!visit_each(*this, values)) ok_ = false;
  }
  template <class T>
  void operator()(const Bits<T>& mask) {
    if (mask_fits(mask)) {
      *mask.bits = static_cast<T>(get(mask_bytes(mask.channels)));
    } else {
      ok_ = false;
    }
  }

  // True when every field was present and no byte is left over.
  bool consumed_exactly() const { return ok_ && pos_ == size_; }

 private:
  uint64_t get(size_t n) {
    if (pos_ + n > size_) {
      ok_ = false;
      return 0;
    }
    uint64_t v = 0;
    for (size_t i = 0; i < n; ++i) v |= static_cast<uint64_t>(buf_[pos_++]) << (8 * i);
    return v;
  }

  const uint8_t* buf_;
  size_t size_;
  size_t pos_ = 0;
  bool ok_ = true;
};

}  // namespace twinfw
