#include <algorithm>
#include <cmath>
#include <cstring>

#include "bench.h"
#include "check.h"
#include "suites.h"

using namespace twinfw;
using bench::Bench;

namespace {

void handshake() {
  Bench b;
  b.send(msg::Enable{});
  CHECK(b.replies.nacks == 1 && b.replies.last_nack_error == static_cast<uint8_t>(NackError::kNoHandshake));
  b.send(msg::Hello{static_cast<uint16_t>(kProtocolVersion + 1)});
  CHECK(b.replies.hello_replies == 1 && b.replies.hello.protocol_version == kProtocolVersion);
  b.send(msg::Enable{});
  CHECK(b.replies.nacks == 2 && b.fw.state() == State::kDisabled);  // version mismatch
  b.send(msg::Hello{kProtocolVersion});
  CHECK(b.replies.hello.channels == 4 && b.replies.hello.control_period_us == 10000 &&
        b.replies.hello.telemetry_period_us == 25000);
  CHECK_NEAR(b.replies.hello.tendon_m_per_count, 9.4064859e-7, 1e-13);
  const uint16_t seq = b.send(msg::Enable{});
  CHECK(b.replies.acks == 1 && b.replies.last_acked_seq == seq && b.fw.state() == State::kEnabled);
}

void setpoint_gives_pwm_sign() {
  Bench b;
  b.counts[0] = 5000;  // enabling away from zero must not move anything
  CHECK(b.start());
  b.run(0.05);
  CHECK(b.out.drive[0] == Drive::kDrive);
  CHECK_NEAR(b.out.duty[0], 0.0, 1e-6);
  b.send(msg::SetSetpoints{4, 0, {b.length_m(0) + 0.001f, -0.001f, 0.0f, 0.0f}});
  b.run(0.011);
  CHECK(b.out.duty[0] > 0.0f && b.out.duty[1] < 0.0f);
  CHECK_NEAR(b.out.duty[2], 0.0, 1e-6);
  CHECK_NEAR(b.replies.last.targets[1], -0.001, 1e-7);
}

void telemetry_schedule() {
  const uint32_t tick_periods_us[] = {1000u, 5000u, 10000u};
  for (uint32_t tick_us : tick_periods_us) {
    Bench b;
    b.run(1.0, tick_us);
    // 40 Hz: the first at t = tick, then every 25 ms (rounded to ticks at 10 ms).
    CHECK(b.replies.telemetry == 40);
    CHECK(b.replies.last.sample_seq == 39);
    const double expected = tick_us == 10000u ? 980000.0 : 975000.0;
    CHECK_NEAR(static_cast<double>(b.replies.last.time_us), expected, 0.0);
  }
}

// Tendon 1 pays out 7 counts a tick, tendon 2 winds in ever faster, tendon 3 stands, tendon 4
// jumps beyond the int16 range once (its differences saturate).
int32_t history_count(size_t channel, int tick) {
  switch (channel) {
    case 0: return 7 * tick;
    case 1: return -tick * tick;
    case 2: return 0;
    default: return tick >= 30 ? 40000 : 0;
  }
}

int16_t saturated(int32_t d) { return static_cast<int16_t>(d > 32767 ? 32767 : (d < -32768 ? -32768 : d)); }

void telemetry_carries_every_ticks_encoder_counts() {
  static_assert(kTelemetryTicks == 5, "25 ms frames of 5 ms ticks");
  Bench b;
  int frames = 0;
  bool all_match = true;
  for (int tick = 1; tick <= 60; ++tick) {
    for (size_t i = 0; i < 4; ++i) b.counts[i] = history_count(i, tick);
    const int before = b.replies.telemetry;
    b.run(0.005, 5000);
    if (b.replies.telemetry == before) continue;
    ++frames;
    const msg::TelemetryMessage& t = b.replies.last;
    for (size_t k = 0; k < kTelemetryTicks; ++k) {
      // Oldest first; before the first tick the history holds the first tick's counts.
      const int at = tick - static_cast<int>(kTelemetryTicks - 1 - k);
      for (size_t i = 0; i < 4; ++i) {
        const int32_t expected = saturated(history_count(i, at < 1 ? 1 : at) - t.encoder_counts[i]);
        all_match = all_match && t.encoder_history[k][i] == expected;
      }
    }
    all_match = all_match && t.encoder_counts[0] == history_count(0, tick);
  }
  CHECK(frames == 12);
  CHECK(all_match);
  CHECK(b.replies.last.sample_seq == 11 && b.replies.last.encoder_history[0][1] == -(52 * 52) + 56 * 56);
  // Ticked every 1 ms, the board records every 5 ms: the frame's own tick and 5, 10, 15, 20 ms before.
  Bench fast;
  for (int ms = 1; ms <= 100; ++ms) {
    fast.counts[0] = ms;
    fast.run(0.001, 1000);
  }
  const msg::TelemetryMessage& t = fast.replies.last;
  CHECK(t.encoder_history[0][0] == -20 && t.encoder_history[1][0] == -15 && t.encoder_history[2][0] == -10 &&
        t.encoder_history[3][0] == -5 && t.encoder_history[4][0] == 0);
}

void control_runs_at_100_hz() {
  Bench b;
  CHECK(b.start());
  b.send(msg::SetSetpoints{4, 0, {0.003f, 0.0f, 0.0f, 0.0f}});
  int changes = 0;
  float last = b.out.duty[0];
  for (int i = 0; i < 100; ++i) {  // 100 ms at 1 kHz while the tendon moves
    b.run(0.001);
    if (b.out.duty[0] != last) ++changes;
    last = b.out.duty[0];
  }
  CHECK(changes >= 9 && changes <= 10);
}

void corrupted_command_is_not_acted_on() {
  Bench b;
  b.send(msg::Hello{kProtocolVersion});
  uint8_t frame[kMaxEncodedFrameBytes];
  const size_t n = encode_message(msg::Enable{}, 77, frame, sizeof frame);
  for (size_t pos = 0; pos + 1 < n; ++pos) {
    for (int bit = 0; bit < 8; ++bit) {
      uint8_t bad[kMaxEncodedFrameBytes];
      std::memcpy(bad, frame, n);
      bad[pos] = static_cast<uint8_t>(bad[pos] ^ (1u << bit));
      b.send_bytes(bad, n);
    }
  }
  CHECK(b.fw.state() == State::kDisabled && b.replies.acks == 0 && b.replies.nacks == 0);
  CHECK(b.fw.rx_bad_frames() >= (n - 1) * 8);
  b.run(0.03);
  CHECK(b.replies.last.rx_bad_frames == b.fw.rx_bad_frames());
  b.send_bytes(frame, n);  // the intact frame still works afterwards
  CHECK(b.fw.state() == State::kEnabled && b.replies.acks == 1);
}

void garbage_is_counted_and_ignored() {
  Bench b;
  b.send(msg::Hello{kProtocolVersion});
  uint32_t state = 7u;
  uint8_t chunk[97];
  for (int k = 0; k < 500; ++k) {
    for (uint8_t& byte : chunk) {
      state = state * 1664525u + 1013904223u;
      byte = (state >> 24) < 24 ? 0 : static_cast<uint8_t>(state >> 8);
    }
    b.send_bytes(chunk, sizeof chunk);
  }
  CHECK(b.fw.state() == State::kDisabled && b.replies.acks == 0 && b.replies.nacks == 0);
  CHECK(b.fw.rx_bad_frames() > 1000);
}

void commands_are_validated() {
  Bench b;
  b.send(msg::Hello{kProtocolVersion});
  auto last_error = [&b] { return static_cast<NackError>(b.replies.last_nack_error); };
  b.send(msg::SetSetpoints{4, 0, {0.001f, 0, 0, 0}});
  CHECK(last_error() == NackError::kNotEnabled);
  b.send(msg::SetMode{2});
  CHECK(last_error() == NackError::kNotCalibrated);
  b.send(msg::SetMode{3});
  CHECK(last_error() == NackError::kBadValue);
  b.run(0.05);
  b.send(msg::Enable{});
  const int nacks = b.replies.nacks;
  b.send(msg::SetSetpoints{4, 1, {0.001f, 0, 0, 0}});
  CHECK(last_error() == NackError::kWrongMode);
  b.send(msg::SetSetpoints{4, 0, {NAN, 0, 0, 0}});
  b.send(msg::SetSetpoints{4, 0, {2.0f, 0, 0, 0}});  // 2 m: a value in mm sent as m
  b.send(msg::SetGains{0, -1.0f, 0, 0, 1.0f});
  b.send(msg::SetGains{0, 1.0f, 0, 0, 1.5f});
  b.send(msg::SetLimits{0.0f, 250, 45000.0f});
  b.send(msg::SetLimits{6.0f, 5, 45000.0f});
  b.send(msg::Tare{4, 1, 0});
  b.send(msg::SetCalibration{4, {1, 1, 1, 1}, {0, 0, 0, 0}});
  CHECK(b.replies.nacks == nacks + 9);
  CHECK(last_error() == NackError::kNotWhileEnabled);
  b.run(0.03);
  CHECK_NEAR(b.replies.last.targets[0], 0.0, 0.0);  // nothing refused was applied
  // An intact frame of unknown type or wrong length is refused, not acted on.
  const uint8_t unknown_payload[1] = {0};
  uint8_t frame[kMaxEncodedFrameBytes];
  size_t n = encode_frame(0x42, 900, unknown_payload, 1, frame, sizeof frame);
  b.send_bytes(frame, n);
  CHECK(last_error() == NackError::kUnknownType && b.replies.last_acked_seq == 900);
  n = encode_frame(static_cast<uint8_t>(MsgType::kDisable), 901, unknown_payload, 1, frame, sizeof frame);
  b.send_bytes(frame, n);
  CHECK(last_error() == NackError::kBadLength && b.fw.state() == State::kEnabled);
}

void tare_sets_origins() {
  Bench b;
  b.counts[2] = 12345;
  b.extra_tension_n[1] = 0.5f;
  b.send(msg::Hello{kProtocolVersion});
  b.run(0.05);
  b.send(msg::Tare{4, 0b0010, 0b0100});
  b.run(0.03);
  CHECK(b.replies.acks == 1);
  CHECK_NEAR(b.replies.last.lengths_m[2], 0.0, 0.0);
  CHECK(b.replies.last.encoder_counts[2] == 12345);
  CHECK_NEAR(b.replies.last.tensions_n[1], 0.0, 1e-6);
  CHECK(b.replies.last.tensions_n[0] > 0.1f);  // untouched channel keeps its nominal offset 0
}

void calibrations_outside_physical_bounds_are_refused() {
  Bench b;
  b.send(msg::Hello{kProtocolVersion});
  auto refused = [&b](float gain_n_per_count, float offset_counts) {
    const int nacks = b.replies.nacks;
    b.send(msg::SetCalibration{4, {1 / Bench::kRawPerN, gain_n_per_count, 1 / Bench::kRawPerN, 1 / Bench::kRawPerN},
                               {Bench::kRawOffset, offset_counts, Bench::kRawOffset, Bench::kRawOffset}});
    return b.replies.nacks == nacks + 1 && b.replies.last_nack_error == static_cast<uint8_t>(NackError::kBadValue);
  };
  CHECK(refused(-1 / Bench::kRawPerN, 0.0f));  // counts falling with tension
  CHECK(refused(1e-30f, 0.0f));                // 1e30 counts/N
  CHECK(refused(1 / (10 * Bench::kRawPerN), 0.0f));  // reads a tenth of the tension
  CHECK(refused(10 / Bench::kRawPerN, 0.0f));        // reads ten times it
  CHECK(refused(1 / Bench::kRawPerN, 1e9f));         // offset beyond the 24-bit range
  CHECK(refused(1 / Bench::kRawPerN, -1.1e6f));
  CHECK(refused(0.0f, 0.0f));
  CHECK(refused(NAN, 0.0f));
  // The bounds themselves are accepted: 25 % either way of the rated 45,000 counts/N, ±2^20 counts.
  const int acks = b.replies.acks;
  const float low = 45000.0f / kGainTolerance, high = 45000.0f * kGainTolerance;
  b.send(msg::SetCalibration{4, {1 / low, 1 / high, 1 / Bench::kRawPerN, 1 / Bench::kRawPerN},
                             {kMaxOffsetCounts, -kMaxOffsetCounts, 0.0f, 0.0f}});
  CHECK(b.replies.acks == acks + 1);
}

// Another rig's load cells: the host's rated sensitivity sets the bounds, and converts the
// readings until a calibration arrives.
void the_rated_sensitivity_the_host_sends_bounds_the_calibrations() {
  Bench b;
  b.send(msg::Hello{kProtocolVersion});
  b.extra_tension_n[0] = 1.0f;  // the bench's cells give 45,000 counts/N
  b.run(0.05);
  CHECK_NEAR(b.replies.last.tensions_n[0] - b.replies.last.tensions_n[1], 1.0, 1e-3);
  auto calibrate = [&b](float counts_per_n) {
    const int acks = b.replies.acks;
    const float g = 1 / counts_per_n;
    b.send(msg::SetCalibration{4, {g, g, g, g}, {0, 0, 0, 0}});
    return b.replies.acks == acks + 1;
  };
  // A 5 kg cell rated at 9,000 counts/N: refused against the default 1 kg cell's bounds, ...
  CHECK(!calibrate(9000.0f));
  const int acked = b.replies.acks;
  b.send(msg::SetLimits{30.0f, 250, 9000.0f});
  CHECK(b.replies.acks == acked + 1);
  // ... accepted once the host said which cells these are; the readings are counts / 9,000.
  b.run(0.05);
  CHECK_NEAR(b.replies.last.tensions_n[0] - b.replies.last.tensions_n[1], 5.0, 5e-3);
  CHECK(calibrate(9000.0f * 1.2f));
  CHECK(!calibrate(45000.0f));         // the 1 kg cell's gain would read 5x low: blind to 30 N
  CHECK(!calibrate(9000.0f * 1.3f));
  // Rated sensitivities the 24-bit range cannot hold the limit with, or below a count per 10 mN.
  const int nacks = b.replies.nacks;
  b.send(msg::SetLimits{30.0f, 250, kMaxRatedGainCountsPerN * 1.01f});
  b.send(msg::SetLimits{30.0f, 250, 50.0f});
  b.send(msg::SetLimits{30.0f, 250, NAN});
  CHECK(b.replies.nacks == nacks + 3);
  // Not changed while driving; the same one is accepted (the host sends it before each ENABLE).
  b.send(msg::Enable{});
  b.send(msg::SetLimits{30.0f, 250, 9000.0f});
  CHECK(b.replies.nacks == nacks + 3);
  b.send(msg::SetLimits{30.0f, 250, 45000.0f});
  CHECK(b.replies.nacks == nacks + 4 && b.replies.last_nack_error == static_cast<uint8_t>(NackError::kNotWhileEnabled));
}

// The motors the host sends bound what the board drives: the pull limit of the duty, and the
// bounds of config.h on the values themselves; other motors are not taken while driving.
void the_motors_the_host_sends_bound_the_duty() {
  Bench b;
  b.send(msg::Hello{kProtocolVersion});
  const int nacks = b.replies.nacks;
  b.send(msg::SetMotors{kMinStallForceN * 0.99f, 0.5f, 2.0f});
  b.send(msg::SetMotors{kMaxStallForceN * 1.01f, 0.5f, 2.0f});
  b.send(msg::SetMotors{100.0f, kMaxNoLoadSpeedMPerS * 1.01f, 2.0f});
  b.send(msg::SetMotors{100.0f, kMinNoLoadSpeedMPerS * 0.99f, 2.0f});
  b.send(msg::SetMotors{100.0f, 0.5f, kMinReflectedMassKg * 0.99f});
  b.send(msg::SetMotors{100.0f, 0.5f, NAN});
  CHECK(b.replies.nacks == nacks + 6 && b.replies.last_nack_error == static_cast<uint8_t>(NackError::kBadValue));
  // A motor of half the thesis's stall force may wind in with twice the duty, and its default
  // gains ask twice the duty per unit of error (the same pull).
  const int acks = b.replies.acks;
  b.send(msg::SetMotors{0.5f * kDefaultStallForceN, kDefaultNoLoadSpeedMPerS, kDefaultReflectedMassKg});
  CHECK(b.replies.acks == acks + 1);
  CHECK_NEAR(b.fw.controller().gains(Mode::kLengths).kp, 120.0, 1e-3);
  CHECK_NEAR(b.fw.controller().gains(Mode::kTension).ki, 0.6, 1e-6);
  CHECK_NEAR(b.fw.controller().gains(Mode::kTension).output_limit, 0.4, 1e-6);
  b.send(msg::SetGains{0, 1.0e4f, 0.0f, 0.0f, 1.0f});
  b.send(msg::Enable{});
  b.send(msg::SetSetpoints{4, 0, {-0.01f, 0.0f, 0.0f, 0.0f}});
  float lowest = 0.0f;
  for (int i = 0; i < 20; ++i) {
    b.run(0.005);
    lowest = std::min(lowest, b.out.duty[0]);
  }
  CHECK_NEAR(lowest, -0.9 * 6.0 / (0.5 * kDefaultStallForceN), 1e-4);
  // The same motors again are acknowledged while driving; others are refused.
  b.send(msg::SetMotors{0.5f * kDefaultStallForceN, kDefaultNoLoadSpeedMPerS, kDefaultReflectedMassKg});
  CHECK(b.replies.acks == acks + 5);
  b.send(msg::SetMotors{kDefaultStallForceN, kDefaultNoLoadSpeedMPerS, kDefaultReflectedMassKg});
  CHECK(b.replies.nacks == nacks + 7 && b.replies.last_nack_error == static_cast<uint8_t>(NackError::kNotWhileEnabled));
}

void gains_beyond_their_bounds_are_refused() {
  Bench b;
  b.send(msg::Hello{kProtocolVersion});
  const int nacks = b.replies.nacks;
  b.send(msg::SetGains{0, 3e38f, 0.0f, 3e38f, 1.0f});  // finite, and a NaN duty once multiplied out
  b.send(msg::SetGains{0, kMaxLengthKp * 1.01f, 0.0f, 0.0f, 1.0f});
  b.send(msg::SetGains{1, 60.0f, kMaxLengthKi * 1.01f, 0.0f, 1.0f});
  b.send(msg::SetGains{2, kMaxTensionKp * 1.01f, 0.0f, 0.0f, 0.2f});
  b.send(msg::SetGains{2, 0.003f, 0.3f, kMaxTensionKd * 1.01f, 0.2f});
  CHECK(b.replies.nacks == nacks + 5 && b.replies.last_nack_error == static_cast<uint8_t>(NackError::kBadValue));
  const int acks = b.replies.acks;
  b.send(msg::SetGains{0, kMaxLengthKp, kMaxLengthKi, kMaxLengthKd, 1.0f});
  b.send(msg::SetGains{2, kMaxTensionKp, kMaxTensionKi, kMaxTensionKd, 1.0f});
  CHECK(b.replies.acks == acks + 2);
}

void hello_leaves_the_board_disabled() {
  Bench b;
  CHECK(b.start());
  b.send(msg::SetSetpoints{4, 0, {0.002f, 0.0f, 0.0f, 0.0f}});
  b.run_fed(0.1);
  // A new host says HELLO: whatever the last one left driving stops.
  b.send(msg::Hello{kProtocolVersion});
  CHECK(b.fw.state() == State::kDisabled && b.replies.hello_replies == 2);
  b.send(msg::Enable{});
  CHECK(b.fw.state() == State::kEnabled);
  // A host of another version: disabled too, and it cannot enable.
  b.send(msg::Hello{static_cast<uint16_t>(kProtocolVersion + 1)});
  CHECK(b.fw.state() == State::kDisabled && b.replies.hello.protocol_version == kProtocolVersion);
  b.send(msg::Enable{});
  CHECK(b.fw.state() == State::kDisabled && b.replies.last_nack_error == static_cast<uint8_t>(NackError::kNoHandshake));
  // A HELLO leaves a fault latched, for the new host to read.
  b.send(msg::Hello{kProtocolVersion});
  b.send(msg::Enable{});
  b.run(0.3);  // no PING: the watchdog trips
  CHECK(b.fw.state() == State::kFault);
  b.send(msg::Hello{kProtocolVersion});
  CHECK(b.fw.state() == State::kFault && (b.fw.faults() & fault::kWatchdog));
}

void a_tare_outside_the_offset_bound_is_refused() {
  Bench b;
  b.send(msg::Hello{kProtocolVersion});
  b.extra_tension_n[0] = 30.0f;  // 1.35 million counts over the 8200 offset
  b.run(0.05);
  b.send(msg::Tare{4, 0b0001, 0});
  CHECK(b.replies.nacks == 1 && b.replies.last_nack_error == static_cast<uint8_t>(NackError::kBadValue));
  b.send(msg::Tare{4, 0b0010, 0});
  CHECK(b.replies.acks == 1);
}

void a_saturated_load_cell_faults() {
  Bench b;
  CHECK(b.start());
  b.run_fed(0.1);
  // Below the HX711's negative rail (−2^23): a reading that says nothing about the tension. (At
  // the positive rail any accepted calibration reads far over the limit, which trips first.)
  b.extra_tension_n[3] = -200.0f;
  b.run(0.02);
  CHECK(b.fw.state() == State::kFault);
  CHECK(b.fw.faults() & fault::kLoadcellImplausible);
  CHECK(b.fw.faults() & fault::implausible_channel(3));
}

void a_length_step_is_driven_as_a_ramp() {
  Bench b;
  CHECK(b.start());
  b.send(msg::SetSetpoints{4, 0, {-0.01f, 0.0f, 0.0f, 0.0f}});
  b.run_fed(0.5);
  // No faster than the winding speed limit, 4.6 mm/s at 6 N: 2.3 mm of the 10 in 0.5 s.
  const double limit_m = 0.3 * 6.0 / kBlowImpedanceNsPerM * 0.5;
  CHECK(b.length_m(0) < 0.0f && b.length_m(0) > -limit_m - 5e-5);
  CHECK_NEAR(b.replies.last.targets[0], -0.01, 1e-7);  // the target is the setpoint
  b.run_fed(2.5);
  CHECK_NEAR(b.length_m(0), -0.01, 1e-4);
}

}  // namespace

void test_firmware() {
  handshake();
  setpoint_gives_pwm_sign();
  telemetry_schedule();
  telemetry_carries_every_ticks_encoder_counts();
  control_runs_at_100_hz();
  corrupted_command_is_not_acted_on();
  garbage_is_counted_and_ignored();
  commands_are_validated();
  tare_sets_origins();
  calibrations_outside_physical_bounds_are_refused();
  the_rated_sensitivity_the_host_sends_bounds_the_calibrations();
  the_motors_the_host_sends_bound_the_duty();
  gains_beyond_their_bounds_are_refused();
  hello_leaves_the_board_disabled();
  a_tare_outside_the_offset_bound_is_refused();
  a_saturated_load_cell_faults();
  a_length_step_is_driven_as_a_ramp();
}
