#include "firmware.h"

#include "units.h"

namespace twinfw {

Firmware::Firmware(size_t channels, float tendon_m_per_count)
    : channels_(channels < 1 ? 1 : (channels > kMaxChannels ? kMaxChannels : channels)),
      tendon_m_per_count_(tendon_m_per_count),
      controller_(channels_),
      safety_(channels_),
      guard_(channels_, tendon_m_per_count) {
  set_rated_gain(1.0f / kDefaultGainNPerCount);
  set_tension_limit(kDefaultTensionLimitN);
}

void Firmware::receive(const uint8_t* data, size_t size) {
  for (size_t i = 0; i < size; ++i) {
    if (rx_.push(data[i])) handle(rx_.frame());
  }
}

const Outputs& Firmware::tick(uint32_t now_us, const Inputs& inputs) {
  advance_clock(now_us);
  for (size_t i = 0; i < channels_; ++i) {
    counts_[i] = inputs.encoder_counts[i];
    if (inputs.new_sample_mask & (1u << i)) {
      raw_counts_[i] = inputs.raw_counts[i];
      last_sample_us_[i] = time_us_;
      sampled_mask_ = static_cast<ChannelMask>(sampled_mask_ | (1u << i));
    }
  }
  const Measurements now = measure();
  const ChannelMask stale = stale_mask();
  guard_.observe(time_us_, counts_, now.tensions_n, stale);
  bool may_move = safety_.update(time_us_, now.tensions_n, stale);
  if (may_move) {
    const uint32_t faults = guard_faults(stale);
    if (faults != 0) {
      safety_.trip(faults);
      may_move = false;
    }
  }
  if (due(next_control_us_, kControlPeriodUs) && may_move) {
    if (motion_held_) controller_.restart(now);
    motion_held_ = false;
    // The PIDs ask only for what the guard will give: no integral winds up against it.
    float lowest[kMaxChannels];
    for (size_t i = 0; i < channels_; ++i) lowest[i] = guard_.lowest_duty(i);
    controller_.step(now, kControlPeriodS, lowest, command_);
  }
  set_outputs(may_move);
  guard_.applied(outputs_.drive);
  // The encoders are recorded every kTickPeriodUs (each tick of the Teensy and the emulated
  // board) and at each frame, whose own counts are so always its history's last row; the
  // schedule restarts from the frame.
  const bool telemetry_due = due(next_telemetry_us_, kTelemetryPeriodUs);
  if (due(next_history_us_, kTickPeriodUs) || telemetry_due) record_history();
  if (telemetry_due) {
    next_history_us_ = time_us_ + kTickPeriodUs;
    send_telemetry(now, stale);
  }
  return outputs_;
}

void Firmware::advance_clock(uint32_t now_us) {
  if (started_) time_us_ += static_cast<uint32_t>(now_us - last_now_us_);
  started_ = true;
  last_now_us_ = now_us;
}

// True when `deadline_us` has passed; then moves it one period on, or one period past now after
// a long gap, so that a stalled caller does not get a burst of catch-up steps.
bool Firmware::due(uint64_t& deadline_us, uint32_t period_us) const {
  if (time_us_ < deadline_us) return false;
  deadline_us += period_us;
  if (deadline_us <= time_us_) deadline_us = time_us_ + period_us;
  return true;
}

// Driving, held (ENABLED with a stale load cell: brake) or let go (DISABLED, FAULT: brake until
// the spool stands still, then coast); the guard bounds what the motors get in every case.
void Firmware::set_outputs(bool may_move) {
  if (may_move) {
    guard_.drive(command_, outputs_.duty, outputs_.drive);
    return;
  }
  motion_held_ = true;
  for (float& c : command_) c = 0.0f;
  if (safety_.state() == State::kEnabled) {
    guard_.hold(outputs_.duty, outputs_.drive);
  } else {
    guard_.release(outputs_.duty, outputs_.drive);
  }
}

// Fault flags of what the guard sees (Guard::faults) and of fresh load-cell readings at either
// end of the HX711's range (saturated: the tension could be anything).
uint32_t Firmware::guard_faults(ChannelMask stale_mask) {
  uint32_t flags = guard_.faults(time_us_, outputs_.duty, outputs_.drive, controller_.beyond_lowest());
  for (size_t i = 0; i < channels_; ++i) {
    const bool fresh = (stale_mask & (1u << i)) == 0;
    if (fresh && (raw_counts_[i] >= kLoadcellMaxCounts || raw_counts_[i] <= kLoadcellMinCounts)) {
      flags |= fault::kLoadcellImplausible | fault::implausible_channel(i);
    }
  }
  return flags;
}

// Length references ramp at the winding speed limit, paying out too: a tendon paid out faster
// than its antagonist winds in goes slack, and the rod snaps it taut. Tension references ramp
// at kTensionRatePerS times the limit per second.
// The load cells' rated sensitivity (counts/N): it converts the readings until a calibration
// arrives, and bounds the calibrations accepted.
void Firmware::set_rated_gain(float counts_per_n) {
  rated_counts_per_n_ = counts_per_n;
  for (float& g : gain_n_per_count_) g = 1.0f / counts_per_n;
  calibrated_ = false;
}

// The motors the guard and the feedforward derive from; the speed limits follow.
void Firmware::set_motors(const msg::SetMotors& m) {
  motors_ = m;
  guard_.set_motors(m.stall_force_n, m.no_load_speed_m_per_s, m.reflected_mass_kg);
  controller_.set_no_load_speed(m.no_load_speed_m_per_s);
  controller_.use_default_gains(m.stall_force_n);
  set_tension_limit(safety_.tension_limit_n());
}

void Firmware::set_tension_limit(float tension_limit_n) {
  guard_.set_tension_limit(tension_limit_n);
  const float rate = guard_.winding_speed_limit();
  controller_.set_length_rate(rate < kMaxLengthRateMPerS ? rate : kMaxLengthRateMPerS);
  controller_.set_tension_rate(kTensionRatePerS * tension_limit_n);
  controller_.set_tension_limit(tension_limit_n);
}

// A HELLO starts a host's session: whatever the last host left driving stops (FAULT stays, so
// its flags can be read).
void Firmware::end_session() {
  if (safety_.state() == State::kEnabled) {
    safety_.disable();
    set_outputs(false);
  }
}

Measurements Firmware::measure() const {
  Measurements m{};
  for (size_t i = 0; i < channels_; ++i) {
    m.lengths_m[i] = counts_to_length_m(counts_[i], origin_counts_[i], tendon_m_per_count_);
    m.tensions_n[i] = raw_to_tension_n(raw_counts_[i], gain_n_per_count_[i], offset_counts_[i]);
  }
  return m;
}

ChannelMask Firmware::stale_mask() const {
  ChannelMask mask = 0;
  for (size_t i = 0; i < channels_; ++i) {
    const bool never = (sampled_mask_ & (1u << i)) == 0;
    if (never || time_us_ - last_sample_us_[i] > kLoadcellStaleUs) mask = static_cast<ChannelMask>(mask | (1u << i));
  }
  return mask;
}

void Firmware::record_history() {
  if (!history_started_) {
    for (auto& row : history_) {
      for (size_t i = 0; i < channels_; ++i) row[i] = counts_[i];
    }
    history_started_ = true;
    return;
  }
  for (size_t i = 0; i < channels_; ++i) history_[history_head_][i] = counts_[i];
  history_head_ = (history_head_ + 1) % kTelemetryTicks;
}

// A count's difference from `reference`, saturated to the int16 range (±32767 counts, 31 mm of
// tendon: more than an unloaded spool, 0.51 m/s, travels in a 25 ms frame period).
static int16_t count_difference(int32_t count, int32_t reference) {
  const int64_t d = static_cast<int64_t>(count) - static_cast<int64_t>(reference);
  return static_cast<int16_t>(d > INT16_MAX ? INT16_MAX : (d < INT16_MIN ? INT16_MIN : d));
}

void Firmware::send_telemetry(const Measurements& now, ChannelMask stale_mask) {
  msg::TelemetryMessage t{};
  t.channels = static_cast<uint8_t>(channels_);
  t.time_us = time_us_;
  t.sample_seq = telemetry_seq_++;
  for (size_t i = 0; i < channels_; ++i) {
    t.encoder_counts[i] = counts_[i];
    t.lengths_m[i] = now.lengths_m[i];
    t.raw_counts[i] = raw_counts_[i];
    t.tensions_n[i] = now.tensions_n[i];
    t.targets[i] = controller_.targets()[i];
    t.duty[i] = outputs_.duty[i];
    t.drive_modes[i] = static_cast<uint8_t>(outputs_.drive[i]);
  }
  t.state = static_cast<uint8_t>(safety_.state());
  t.mode = static_cast<uint8_t>(controller_.mode());
  t.fault_flags = safety_.faults();
  t.stale_mask = stale_mask;
  t.rx_bad_frames = rx_.bad_frames();
  t.tx_dropped_frames = tx_.dropped();
  for (size_t k = 0; k < kTelemetryTicks; ++k) {
    const int32_t* row = history_[(history_head_ + k) % kTelemetryTicks];
    for (size_t i = 0; i < channels_; ++i) t.encoder_history[k][i] = count_difference(row[i], counts_[i]);
  }
  send(t);
}

}  // namespace twinfw
