// The whole board logic as one object stepped with explicit time, so that the same code runs
// on the Teensy (firmware/teensy), in host unit tests, under QEMU and in the emulated board.
// Commands are acted on inside receive() at the time of the latest tick; tick() runs the
// safety checks every call, the control loop every kControlPeriodUs and queues telemetry every
// kTelemetryPeriodUs, whatever the calling rate.
#pragma once

#include <cstddef>
#include <cstdint>

#include "config.h"
#include "controller.h"
#include "frame.h"
#include "guard.h"
#include "messages.h"
#include "safety.h"
#include "tx_queue.h"

namespace twinfw {

// Arrays hold kMaxChannels; the firmware reads and writes its channels() first entries.
struct Inputs {
  int32_t encoder_counts[kMaxChannels];
  int32_t raw_counts[kMaxChannels];  // HX711 readings; only channels set in new_sample_mask are read
  ChannelMask new_sample_mask;       // bit i: raw_counts[i] is a sample taken since the last tick
};

struct Outputs {
  float duty[kMaxChannels];  // in [-1, 1]; positive pays tendon out. 0 unless drive is kDrive
  Drive drive[kMaxChannels];
};

class Firmware {
 public:
  static constexpr size_t kTxQueueBytes = 1024;

  // A board of `channels` motors and load cells (1..kMaxChannels; clamped into that range),
  // as after power-up. HELLO_REPLY reports the count, and every message sized by it must
  // carry it.
  explicit Firmware(size_t channels = kDefaultChannels, float tendon_m_per_count = kTendonMPerCount);

  size_t channels() const { return channels_; }

  // Host bytes in any chunking; each complete valid command is acted on and answered.
  void receive(const uint8_t* data, size_t size);

  // One step at `now_us` (a wrapping microsecond clock such as micros()).
  const Outputs& tick(uint32_t now_us, const Inputs& inputs);

  // Moves up to `capacity` queued outgoing bytes into `out`; returns how many.
  size_t take_tx(uint8_t* out, size_t capacity) { return tx_.take(out, capacity); }
  size_t tx_pending() const { return tx_.size(); }

  State state() const { return safety_.state(); }
  const Controller& controller() const { return controller_; }
  uint32_t faults() const { return safety_.faults(); }
  uint32_t rx_bad_frames() const { return rx_.bad_frames(); }

 private:
  void handle(const RawFrame& frame);
  bool sized_for_board(uint8_t channels) const;
  template <class T>
  uint8_t dispatch(const RawFrame& frame, uint8_t (Firmware::*handler)(const T&));
  uint8_t on_hello(const msg::Hello& m);
  uint8_t on_ping(const msg::Ping& m);
  uint8_t on_enable(const msg::Enable& m);
  uint8_t on_disable(const msg::Disable& m);
  uint8_t on_tare(const msg::Tare& m);
  uint8_t on_set_mode(const msg::SetMode& m);
  uint8_t on_set_setpoints(const msg::SetSetpoints& m);
  uint8_t on_set_gains(const msg::SetGains& m);
  uint8_t on_set_calibration(const msg::SetCalibration& m);
  uint8_t on_set_limits(const msg::SetLimits& m);
  uint8_t on_set_motors(const msg::SetMotors& m);

  template <class T>
  void send(const T& message);
  void send_telemetry(const Measurements& now, ChannelMask stale_mask);
  void record_history();

  void advance_clock(uint32_t now_us);
  bool due(uint64_t& deadline_us, uint32_t period_us) const;
  Measurements measure() const;
  ChannelMask stale_mask() const;
  ChannelMask all_channels() const { return static_cast<ChannelMask>((1u << channels_) - 1u); }
  uint32_t guard_faults(ChannelMask stale_mask);
  void set_outputs(bool may_move);
  void set_tension_limit(float tension_limit_n);
  void set_rated_gain(float counts_per_n);
  void set_motors(const msg::SetMotors& m);
  void end_session();

  size_t channels_;
  float tendon_m_per_count_;  // the encoders' tendon per count, as HELLO_REPLY says
  FrameDecoder rx_;
  TxQueue<kTxQueueBytes> tx_;
  Controller controller_;
  Safety safety_;
  Guard guard_;
  float command_[kMaxChannels] = {};  // the PIDs' duties of the last control period
  Outputs outputs_{};

  bool started_ = false;
  uint32_t last_now_us_ = 0;
  uint64_t time_us_ = 0;  // device time: µs since the first tick, never wraps
  uint64_t next_control_us_ = 0;
  uint64_t next_telemetry_us_ = 0;

  int32_t counts_[kMaxChannels] = {};
  // The encoder counts of the last kTelemetryTicks recorded ticks, a ring whose oldest row is
  // history_head_; filled with the first tick's counts at the first tick.
  int32_t history_[kTelemetryTicks][kMaxChannels] = {};
  size_t history_head_ = 0;
  bool history_started_ = false;
  uint64_t next_history_us_ = 0;
  int32_t origin_counts_[kMaxChannels] = {};
  int32_t raw_counts_[kMaxChannels] = {};
  uint64_t last_sample_us_[kMaxChannels] = {};
  ChannelMask sampled_mask_ = 0;
  float gain_n_per_count_[kMaxChannels];
  float offset_counts_[kMaxChannels] = {};
  bool calibrated_ = false;
  float rated_counts_per_n_ = 0.0f;
  msg::SetMotors motors_{kDefaultStallForceN, kDefaultNoLoadSpeedMPerS, kDefaultReflectedMassKg};

  bool handshake_ok_ = false;
  bool motion_held_ = true;
  uint16_t tx_seq_ = 0;
  uint32_t telemetry_seq_ = 0;
};

template <class T>
void Firmware::send(const T& message) {
  uint8_t frame[kMaxEncodedFrameBytes];
  const size_t n = encode_message(message, tx_seq_, frame, sizeof frame);
  ++tx_seq_;
  tx_.push(frame, n);
}

}  // namespace twinfw
