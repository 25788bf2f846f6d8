// Boards of other channel counts than the endoscope's four: every per-channel layout, the pairs
// of an even count, the refusal of messages sized for another count, of pairs on an odd count.
#include "bench.h"
#include "check.h"
#include "suites.h"

using namespace twinfw;
using bench::Bench;

namespace {

NackError last_error(const Bench& b) { return static_cast<NackError>(b.replies.last_nack_error); }

msg::SetSetpoints setpoints(size_t channels, Mode mode, const float* values) {
  msg::SetSetpoints m{};
  m.channels = static_cast<uint8_t>(channels);
  m.mode = static_cast<uint8_t>(mode);
  for (size_t i = 0; i < channels; ++i) m.values[i] = values[i];
  return m;
}

void the_count_is_the_constructed_one_within_range() {
  CHECK(Firmware(8).channels() == 8);
  CHECK(Firmware(3).channels() == 3);
  CHECK(Firmware(0).channels() == 1);
  CHECK(Firmware(kMaxChannels + 5).channels() == kMaxChannels);
  CHECK(Firmware().channels() == kDefaultChannels);
}

void an_eight_channel_board_reports_and_drives_every_motor() {
  Bench b(8);
  CHECK(b.start());
  CHECK(b.replies.hello.channels == 8);
  float values[8] = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.001f};
  b.send(setpoints(8, Mode::kLengths, values));
  CHECK(b.replies.nacks == 0);
  b.run_fed(1.5);
  CHECK_NEAR(b.length_m(7), 0.001, 1e-4);
  for (size_t i = 0; i < 7; ++i) CHECK_NEAR(b.length_m(i), 0.0, 2e-5);
  CHECK(b.replies.last.channels == 8);
  CHECK_NEAR(b.replies.last.targets[7], 0.001, 1e-7);
  CHECK_NEAR(b.replies.last.lengths_m[7], b.length_m(7), 2e-6);
  for (size_t i = 0; i < 8; ++i) CHECK(b.replies.last.drive_modes[i] == static_cast<uint8_t>(Drive::kDrive));
  // Tension on the eighth load cell reads through its calibration.
  CHECK_NEAR(b.replies.last.tensions_n[7], b.tension_n(7), 1e-3);
}

void pairs_of_eight_are_tendon_k_and_k_plus_four() {
  Bench b(8);
  CHECK(b.start(Mode::kPairs));
  float values[8] = {0.001f, 0.0f, 0.0f, -0.0005f, 0.0f, 0.0f, 0.0f, 0.0f};
  b.send(setpoints(8, Mode::kPairs, values));
  CHECK(b.replies.nacks == 0);
  b.run_fed(1.5);
  CHECK_NEAR(b.length_m(0), 0.001, 1e-4);
  CHECK_NEAR(b.length_m(4), -0.001, 1e-4);
  CHECK_NEAR(b.length_m(3), -0.0005, 1e-4);
  CHECK_NEAR(b.length_m(7), 0.0005, 1e-4);
  CHECK_NEAR(b.length_m(1), 0.0, 2e-5);
  CHECK_NEAR(b.length_m(5), 0.0, 2e-5);
  // The second half of a pairs setpoint is zero, as the first two of four are the only ones.
  values[5] = 0.001f;
  b.send(setpoints(8, Mode::kPairs, values));
  CHECK(last_error(b) == NackError::kBadValue);
}

void pairs_on_an_odd_count_are_refused() {
  Bench b(3);
  b.send(msg::Hello{kProtocolVersion});
  CHECK(b.replies.hello.channels == 3);
  b.send(msg::SetMode{static_cast<uint8_t>(Mode::kPairs)});
  CHECK(b.replies.nacks == 1 && last_error(b) == NackError::kBadValue);
  b.send(msg::SetMode{static_cast<uint8_t>(Mode::kLengths)});
  CHECK(b.replies.acks == 1);
}

void messages_sized_for_another_count_are_refused() {
  Bench b(8);
  b.send(msg::Hello{kProtocolVersion});
  b.run(0.05);
  b.send(msg::Tare{4, 0b1, 0});
  CHECK(last_error(b) == NackError::kBadLength);
  b.send(msg::SetCalibration{4, {1 / Bench::kRawPerN, 1 / Bench::kRawPerN, 1 / Bench::kRawPerN, 1 / Bench::kRawPerN},
                             {0, 0, 0, 0}});
  CHECK(last_error(b) == NackError::kBadLength);
  b.send(msg::Enable{});
  b.send(msg::SetSetpoints{4, 0, {0.001f, 0, 0, 0}});
  CHECK(last_error(b) == NackError::kBadLength && b.replies.nacks == 3);
  b.run(0.03);
  CHECK_NEAR(b.replies.last.targets[0], 0.0, 0.0);  // nothing refused was applied
  // A mask bit beyond the board's channels is a bad value, as on four.
  Bench three(3);
  three.send(msg::Hello{kProtocolVersion});
  three.run(0.05);
  three.send(msg::Tare{3, 0b1000, 0});
  CHECK(last_error(three) == NackError::kBadValue);
  three.send(msg::Tare{3, 0b0100, 0b0111});
  CHECK(three.replies.acks == 1);
}

void a_stale_eighth_cell_holds_every_motor() {
  Bench b(8);
  CHECK(b.start());
  b.silenced_mask = 1u << 7;
  b.run(0.1);  // past the 37.5 ms to stale, and a telemetry sample after that
  CHECK(b.fw.faults() == fault::kLoadcellStale && b.replies.last.stale_mask == (1u << 7));
  for (size_t i = 0; i < 8; ++i) CHECK(b.out.drive[i] == Drive::kBrake);
}

void the_twelfth_channel_has_its_fault_bits() {
  Bench b(kMaxChannels);
  CHECK(b.start());
  b.extra_tension_n[kMaxChannels - 1] = 10.0f;
  b.run(0.03);
  CHECK(b.fw.state() == State::kFault);
  CHECK(b.fw.faults() == (fault::kTensionLimit | fault::tension_channel(kMaxChannels - 1)));
  CHECK(fault::tension_channel(kMaxChannels - 1) == (1u << 19) && fault::implausible_channel(0) == (1u << 20));
  CHECK(b.replies.last.channels == kMaxChannels && b.replies.last.fault_flags == b.fw.faults());
}

void a_layout_that_cannot_carry_a_message_encodes_nothing() {
  uint8_t frame[kMaxEncodedFrameBytes];
  // A mask bit beyond the mask's byte, a count beyond kMaxChannels: refused, not truncated.
  CHECK(encode_message(msg::Tare{4, 0x100, 0}, 1, frame, sizeof frame) == 0);
  CHECK(encode_message(msg::Tare{kMaxChannels + 1, 0, 0}, 1, frame, sizeof frame) == 0);
  CHECK(encode_message(msg::SetSetpoints{kMaxChannels + 1, 0, {}}, 1, frame, sizeof frame) == 0);
  CHECK(encode_message(msg::Tare{9, 0x100, 0}, 1, frame, sizeof frame) > 0);  // two mask bytes
  msg::TelemetryMessage longest{};
  longest.channels = kMaxChannels;
  CHECK(encode_message(longest, 1, frame, sizeof frame) == kMaxPayloadBytes + 7);
}

}  // namespace

void test_channels() {
  a_layout_that_cannot_carry_a_message_encodes_nothing();
  the_count_is_the_constructed_one_within_range();
  an_eight_channel_board_reports_and_drives_every_motor();
  pairs_of_eight_are_tendon_k_and_k_plus_four();
  pairs_on_an_odd_count_are_refused();
  messages_sized_for_another_count_are_refused();
  a_stale_eighth_cell_holds_every_motor();
  the_twelfth_channel_has_its_fault_bits();
}
