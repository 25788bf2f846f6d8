// Firmware command handlers: each validates its message against the current state and either
// acts on it whole or refuses it with a NACK naming the reason; nothing is half-applied.
#include <cmath>

#include "firmware.h"

namespace twinfw {

namespace {

constexpr uint8_t kAck = 0;
constexpr uint8_t kReplied = 0xFF;  // the handler sent its own reply (HELLO)

constexpr uint8_t nack(NackError e) { return static_cast<uint8_t>(e); }

bool all_finite(const float* values, size_t n) {
  for (size_t i = 0; i < n; ++i) {
    if (!std::isfinite(values[i])) return false;
  }
  return true;
}

bool valid_mode(uint8_t mode) { return mode < kModes; }

bool within(float x, float lowest, float highest) { return x >= lowest && x <= highest; }

// The PID gains SET_GAINS accepts for `mode` (config.h); NaN fails every comparison.
bool valid_gains(Mode mode, const msg::SetGains& m) {
  const bool tension = mode == Mode::kTension;
  return within(m.kp, 0.0f, tension ? kMaxTensionKp : kMaxLengthKp) &&
         within(m.ki, 0.0f, tension ? kMaxTensionKi : kMaxLengthKi) &&
         within(m.kd, 0.0f, tension ? kMaxTensionKd : kMaxLengthKd) && m.output_limit > 0.0f &&
         m.output_limit <= 1.0f;
}

// A calibration channel SET_CALIBRATION accepts (config.h, firmware/PROTOCOL.md): counts rise
// with tension within kGainTolerance of the cells' rated sensitivity, and the offset leaves the
// tension limit inside the 24-bit range. Compared as counts per N, so that the bounds are the
// datasheet-like numbers.
bool valid_calibration(float gain_n_per_count, float offset_counts, float rated_counts_per_n) {
  if (!(gain_n_per_count > 0.0f)) return false;
  return within(1.0f / gain_n_per_count, rated_counts_per_n / kGainTolerance, rated_counts_per_n * kGainTolerance) &&
         within(offset_counts, -kMaxOffsetCounts, kMaxOffsetCounts);
}

}  // namespace

// A message sized for another channel count than this board's has another layout: refused
// as BAD_LENGTH, as a payload of the wrong size is.
bool Firmware::sized_for_board(uint8_t channels) const { return channels == channels_; }

void Firmware::handle(const RawFrame& frame) {
  uint8_t result;
  switch (static_cast<MsgType>(frame.type)) {
    case MsgType::kHello: result = dispatch(frame, &Firmware::on_hello); break;
    case MsgType::kPing: result = dispatch(frame, &Firmware::on_ping); break;
    case MsgType::kEnable: result = dispatch(frame, &Firmware::on_enable); break;
    case MsgType::kDisable: result = dispatch(frame, &Firmware::on_disable); break;
    case MsgType::kTare: result = dispatch(frame, &Firmware::on_tare); break;
    case MsgType::kSetMode: result = dispatch(frame, &Firmware::on_set_mode); break;
    case MsgType::kSetSetpoints: result = dispatch(frame, &Firmware::on_set_setpoints); break;
    case MsgType::kSetGains: result = dispatch(frame, &Firmware::on_set_gains); break;
    case MsgType::kSetCalibration: result = dispatch(frame, &Firmware::on_set_calibration); break;
    case MsgType::kSetLimits: result = dispatch(frame, &Firmware::on_set_limits); break;
    case MsgType::kSetMotors: result = dispatch(frame, &Firmware::on_set_motors); break;
    default: result = nack(NackError::kUnknownType); break;
  }
  if (result == kReplied) return;
  if (result == kAck) {
    send(msg::Ack{frame.seq, frame.type});
  } else {
    send(msg::Nack{frame.seq, frame.type, result});
  }
}

// Decodes the payload, feeds the watchdog (a well-formed command proves the host is alive,
// even one refused for the current state) and runs the handler.
template <class T>
uint8_t Firmware::dispatch(const RawFrame& frame, uint8_t (Firmware::*handler)(const T&)) {
  T message{};
  if (!read_payload(frame.payload, frame.payload_size, message)) return nack(NackError::kBadLength);
  safety_.feed(time_us_);
  return (this->*handler)(message);
}

// Any HELLO starts a new session and so stops the motors (end_session); one of another version
// also withdraws the handshake. Either way it is answered with this board's version, so that a
// host of another version can say which one to flash.
uint8_t Firmware::on_hello(const msg::Hello& m) {
  end_session();
  handshake_ok_ = m.protocol_version == kProtocolVersion;
  send(msg::HelloReply{kProtocolVersion,
                       {kFirmwareVersionMajor, kFirmwareVersionMinor, kFirmwareVersionPatch},
                       static_cast<uint8_t>(channels_),
                       kControlPeriodUs,
                       kTelemetryPeriodUs,
                       tendon_m_per_count_});
  return kReplied;
}

uint8_t Firmware::on_ping(const msg::Ping&) { return kAck; }

uint8_t Firmware::on_enable(const msg::Enable&) {
  if (!handshake_ok_) return nack(NackError::kNoHandshake);
  if (safety_.state() == State::kEnabled) return kAck;
  if (controller_.mode() == Mode::kTension && !calibrated_) return nack(NackError::kNotCalibrated);
  safety_.enable(time_us_);
  controller_.hold(measure(), safety_.tension_limit_n());
  motion_held_ = false;
  return kAck;
}

uint8_t Firmware::on_disable(const msg::Disable&) {
  safety_.disable();
  set_outputs(false);
  return kAck;
}

uint8_t Firmware::on_tare(const msg::Tare& m) {
  if (!sized_for_board(m.channels)) return nack(NackError::kBadLength);
  if (safety_.state() == State::kEnabled) return nack(NackError::kNotWhileEnabled);
  if ((m.loadcell_mask | m.length_mask) & ~all_channels()) return nack(NackError::kBadValue);
  if (m.loadcell_mask & stale_mask()) return nack(NackError::kBadValue);
  for (size_t i = 0; i < channels_; ++i) {
    const bool tared = (m.loadcell_mask & (1u << i)) != 0;
    if (tared && !within(static_cast<float>(raw_counts_[i]), -kMaxOffsetCounts, kMaxOffsetCounts)) {
      return nack(NackError::kBadValue);
    }
  }
  for (size_t i = 0; i < channels_; ++i) {
    if (m.loadcell_mask & (1u << i)) offset_counts_[i] = static_cast<float>(raw_counts_[i]);
    if (m.length_mask & (1u << i)) origin_counts_[i] = counts_[i];
  }
  return kAck;
}

uint8_t Firmware::on_set_mode(const msg::SetMode& m) {
  if (!valid_mode(m.mode)) return nack(NackError::kBadValue);
  const Mode mode = static_cast<Mode>(m.mode);
  if (mode == Mode::kPairs && !pairs_possible(channels_)) return nack(NackError::kBadValue);
  if (mode == Mode::kTension && !calibrated_) return nack(NackError::kNotCalibrated);
  controller_.set_mode(mode, measure(), safety_.tension_limit_n());
  return kAck;
}

uint8_t Firmware::on_set_setpoints(const msg::SetSetpoints& m) {
  if (!sized_for_board(m.channels)) return nack(NackError::kBadLength);
  if (safety_.state() != State::kEnabled) return nack(NackError::kNotEnabled);
  if (m.mode != static_cast<uint8_t>(controller_.mode())) return nack(NackError::kWrongMode);
  if (!all_finite(m.values, channels_)) return nack(NackError::kBadValue);
  for (size_t i = 0; i < channels_; ++i) {
    const float v = m.values[i];
    bool ok = false;
    switch (controller_.mode()) {
      case Mode::kLengths: ok = std::fabs(v) <= kMaxLengthSetpointM; break;
      case Mode::kPairs: ok = i < channels_ / 2 ? std::fabs(v) <= kMaxLengthSetpointM : v == 0.0f; break;
      case Mode::kTension: ok = v >= 0.0f && v <= safety_.tension_limit_n(); break;
    }
    if (!ok) return nack(NackError::kBadValue);
  }
  controller_.set_setpoints(m.values);
  return kAck;
}

uint8_t Firmware::on_set_gains(const msg::SetGains& m) {
  if (!valid_mode(m.mode)) return nack(NackError::kBadValue);
  if (!valid_gains(static_cast<Mode>(m.mode), m)) return nack(NackError::kBadValue);
  controller_.set_gains(static_cast<Mode>(m.mode), PidGains{m.kp, m.ki, m.kd, m.output_limit});
  return kAck;
}

uint8_t Firmware::on_set_calibration(const msg::SetCalibration& m) {
  if (!sized_for_board(m.channels)) return nack(NackError::kBadLength);
  if (safety_.state() == State::kEnabled) return nack(NackError::kNotWhileEnabled);
  if (!all_finite(m.gain_n_per_count, channels_) || !all_finite(m.offset_counts, channels_)) {
    return nack(NackError::kBadValue);
  }
  for (size_t i = 0; i < channels_; ++i) {
    if (!valid_calibration(m.gain_n_per_count[i], m.offset_counts[i], rated_counts_per_n_)) {
      return nack(NackError::kBadValue);
    }
  }
  for (size_t i = 0; i < channels_; ++i) {
    gain_n_per_count_[i] = m.gain_n_per_count[i];
    offset_counts_[i] = m.offset_counts[i];
  }
  calibrated_ = true;
  return kAck;
}

uint8_t Firmware::on_set_limits(const msg::SetLimits& m) {
  if (!(std::isfinite(m.tension_limit_n) && m.tension_limit_n > 0.0f && m.tension_limit_n <= kMaxTensionLimitN)) {
    return nack(NackError::kBadValue);
  }
  if (m.watchdog_timeout_ms < kMinWatchdogMs || m.watchdog_timeout_ms > kMaxWatchdogMs) {
    return nack(NackError::kBadValue);
  }
  if (!within(m.loadcell_gain_counts_per_n, kMinRatedGainCountsPerN, kMaxRatedGainCountsPerN)) {
    return nack(NackError::kBadValue);
  }
  // Other load cells: the calibration of the ones before does not hold for them. Not while
  // driving, which the readings' scale changing under the tension loop would upset.
  if (m.loadcell_gain_counts_per_n != rated_counts_per_n_) {
    if (safety_.state() == State::kEnabled) return nack(NackError::kNotWhileEnabled);
    set_rated_gain(m.loadcell_gain_counts_per_n);
  }
  safety_.set_limits(m.tension_limit_n, m.watchdog_timeout_ms);
  set_tension_limit(m.tension_limit_n);
  return kAck;
}

// Other motors (firmware/PROTOCOL.md, SET_MOTORS): within the bounds of config.h, and not while
// driving, where the bounds on the motors' pull and speed would change under the loop.
uint8_t Firmware::on_set_motors(const msg::SetMotors& m) {
  if (!within(m.stall_force_n, kMinStallForceN, kMaxStallForceN) ||
      !within(m.no_load_speed_m_per_s, kMinNoLoadSpeedMPerS, kMaxNoLoadSpeedMPerS) ||
      !within(m.reflected_mass_kg, kMinReflectedMassKg, kMaxReflectedMassKg)) {
    return nack(NackError::kBadValue);
  }
  const bool same = m.stall_force_n == motors_.stall_force_n && m.no_load_speed_m_per_s == motors_.no_load_speed_m_per_s &&
                    m.reflected_mass_kg == motors_.reflected_mass_kg;
  if (same) return kAck;
  if (safety_.state() == State::kEnabled) return nack(NackError::kNotWhileEnabled);
  set_motors(m);
  return kAck;
}

}  // namespace twinfw
