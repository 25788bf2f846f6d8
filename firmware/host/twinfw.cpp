// C API of twinfw.h. The core never allocates; this host-only wrapper owns its objects on the
// heap so that callers only hold opaque pointers.
#include "twinfw.h"

#include <cstring>
#include <new>

#include "firmware.h"

static_assert(TWINFW_MAX_CHANNELS == twinfw::kMaxChannels, "C API and core disagree on the most channels");

struct twinfw_board {
  twinfw::Firmware firmware;
};

struct twinfw_decoder {
  twinfw::FrameDecoder decoder;
  uint32_t overflows = 0;
};

#define TWINFW_EXPORT extern "C" __attribute__((visibility("default")))

TWINFW_EXPORT uint32_t twinfw_abi_version(void) { return TWINFW_ABI_VERSION; }

TWINFW_EXPORT uint32_t twinfw_protocol_version(void) { return twinfw::kProtocolVersion; }

TWINFW_EXPORT uint32_t twinfw_max_channels(void) { return twinfw::kMaxChannels; }

TWINFW_EXPORT twinfw_board* twinfw_create(uint32_t channels) {
  if (channels < 1 || channels > twinfw::kMaxChannels) return nullptr;
  return new (std::nothrow) twinfw_board{twinfw::Firmware(channels)};
}

TWINFW_EXPORT twinfw_board* twinfw_create_rig(uint32_t channels, float tendon_m_per_count) {
  if (channels < 1 || channels > twinfw::kMaxChannels) return nullptr;
  if (!(tendon_m_per_count > 0.0f && tendon_m_per_count < 1.0f)) return nullptr;  // NaN fails too
  return new (std::nothrow) twinfw_board{twinfw::Firmware(channels, tendon_m_per_count)};
}

TWINFW_EXPORT uint32_t twinfw_channels(const twinfw_board* fw) {
  return static_cast<uint32_t>(fw->firmware.channels());
}

TWINFW_EXPORT void twinfw_destroy(twinfw_board* fw) { delete fw; }

TWINFW_EXPORT void twinfw_receive(twinfw_board* fw, const uint8_t* data, size_t size) {
  fw->firmware.receive(data, size);
}

TWINFW_EXPORT void twinfw_tick(twinfw_board* fw, uint64_t now_us, const int32_t* encoder_counts,
                               const int32_t* raw_counts, uint32_t new_sample_mask, float* duty_out,
                               uint8_t* drive_out) {
  twinfw::Inputs in{};
  const size_t channels = fw->firmware.channels();
  std::memcpy(in.encoder_counts, encoder_counts, channels * sizeof in.encoder_counts[0]);
  std::memcpy(in.raw_counts, raw_counts, channels * sizeof in.raw_counts[0]);
  in.new_sample_mask = static_cast<twinfw::ChannelMask>(new_sample_mask & ((1u << channels) - 1));
  // The core runs on a wrapping 32-bit microsecond clock like the Teensy's micros().
  const twinfw::Outputs& out = fw->firmware.tick(static_cast<uint32_t>(now_us), in);
  for (size_t i = 0; i < channels; ++i) {
    duty_out[i] = out.duty[i];
    drive_out[i] = static_cast<uint8_t>(out.drive[i]);
  }
}

TWINFW_EXPORT size_t twinfw_tx_pending(const twinfw_board* fw) { return fw->firmware.tx_pending(); }

TWINFW_EXPORT size_t twinfw_take_tx(twinfw_board* fw, uint8_t* out, size_t capacity) {
  return fw->firmware.take_tx(out, capacity);
}

TWINFW_EXPORT twinfw_decoder* twinfw_decoder_create(void) { return new (std::nothrow) twinfw_decoder(); }

TWINFW_EXPORT void twinfw_decoder_destroy(twinfw_decoder* decoder) { delete decoder; }

TWINFW_EXPORT size_t twinfw_decoder_feed(twinfw_decoder* decoder, const uint8_t* data, size_t size,
                                         uint8_t* out, size_t capacity) {
  size_t written = 0;
  for (size_t i = 0; i < size; ++i) {
    if (!decoder->decoder.push(data[i])) continue;
    const twinfw::RawFrame& f = decoder->decoder.frame();
    const size_t record = 2 + twinfw::kFrameHeaderBytes + f.payload_size;
    if (written + record > capacity) {
      ++decoder->overflows;
      continue;
    }
    out[written] = static_cast<uint8_t>(record - 2);
    out[written + 1] = static_cast<uint8_t>((record - 2) >> 8);
    out[written + 2] = f.type;
    out[written + 3] = static_cast<uint8_t>(f.seq);
    out[written + 4] = static_cast<uint8_t>(f.seq >> 8);
    std::memcpy(out + written + 5, f.payload, f.payload_size);
    written += record;
  }
  return written;
}

TWINFW_EXPORT uint32_t twinfw_decoder_bad_frames(const twinfw_decoder* decoder) {
  return decoder->decoder.bad_frames();
}

TWINFW_EXPORT uint32_t twinfw_decoder_overflows(const twinfw_decoder* decoder) { return decoder->overflows; }
