// Safety state machine, after ODrive: DISABLED → (ENABLE) → ENABLED → (fault) → FAULT.
// A watchdog fed by valid host commands and a per-channel tension limit latch a fault that
// only ENABLE clears; DISABLE returns to DISABLED from any state and keeps the fault flags for
// the host to read. While any load cell is stale the tension limit cannot be enforced, so
// motion is held (a live flag, not a latch).
#pragma once

#include <cstdint>

#include "config.h"
#include "messages.h"

namespace twinfw {

class Safety {
 public:
  // The safety of `channels` motors (1..kMaxChannels).
  explicit Safety(size_t channels = kDefaultChannels)
      : channels_(channels < 1 ? 1 : (channels > kMaxChannels ? kMaxChannels : channels)) {}

  State state() const { return state_; }
  uint32_t faults() const { return faults_; }
  float tension_limit_n() const { return tension_limit_n_; }

  // Enters ENABLED, clears the fault flags and arms the watchdog at `now_us`.
  void enable(uint64_t now_us);
  void disable() { state_ = State::kDisabled; }
  // A valid host command arrived at `now_us`.
  void feed(uint64_t now_us) { last_feed_us_ = now_us; }
  void set_limits(float tension_limit_n, uint16_t watchdog_timeout_ms);

  // Checks the watchdog and the tension limit of the fresh channels (bits of `stale_mask` are
  // stale ones); returns whether the motors may move.
  bool update(uint64_t now_us, const float* tensions_n, ChannelMask stale_mask);

  // Enters FAULT with `flags` added to the latched ones.
  void trip(uint32_t flags);

  size_t channels_;
  State state_ = State::kDisabled;
  uint32_t faults_ = 0;
  uint64_t last_feed_us_ = 0;
  float tension_limit_n_ = kDefaultTensionLimitN;
  uint16_t watchdog_timeout_ms_ = kDefaultWatchdogMs;
};

}  // namespace twinfw
