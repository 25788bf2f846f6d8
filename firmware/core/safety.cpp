#include "safety.h"

namespace twinfw {

void Safety::enable(uint64_t now_us) {
  state_ = State::kEnabled;
  faults_ = 0;
  last_feed_us_ = now_us;
}

void Safety::set_limits(float tension_limit_n, uint16_t watchdog_timeout_ms) {
  tension_limit_n_ = tension_limit_n;
  watchdog_timeout_ms_ = watchdog_timeout_ms;
}

bool Safety::update(uint64_t now_us, const float* tensions_n, ChannelMask stale_mask) {
  if (state_ != State::kEnabled) {
    faults_ &= ~fault::kLoadcellStale;
    return false;
  }
  if (now_us > last_feed_us_ &&
      now_us - last_feed_us_ > static_cast<uint64_t>(watchdog_timeout_ms_) * 1000u) {
    trip(fault::kWatchdog);
  }
  for (size_t i = 0; i < channels_; ++i) {
    const bool fresh = (stale_mask & (1u << i)) == 0;
    if (fresh && tensions_n[i] > tension_limit_n_) {
      trip(fault::kTensionLimit | fault::tension_channel(i));
    }
  }
  if (state_ != State::kEnabled) return false;
  if (stale_mask != 0) {
    faults_ |= fault::kLoadcellStale;
    return false;
  }
  faults_ &= ~fault::kLoadcellStale;
  return true;
}

void Safety::trip(uint32_t flags) {
  state_ = State::kFault;
  faults_ |= flags;
}

}  // namespace twinfw
