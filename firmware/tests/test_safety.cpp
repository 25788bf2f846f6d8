#include "bench.h"
#include "check.h"
#include "suites.h"

using namespace twinfw;
using bench::Bench;

namespace {

bool all_drive(const Outputs& out, Drive d) {
  for (size_t i = 0; i < kDefaultChannels; ++i) {
    if (out.drive[i] != d || out.duty[i] != 0.0f) return false;
  }
  return true;
}

void watchdog_trips_latches_and_reenables() {
  Bench b;
  CHECK(b.start());
  b.send(msg::SetSetpoints{4, 0, {0.01f, 0.0f, 0.0f, 0.0f}});
  b.run_fed(1.0);  // PING every 100 ms keeps it alive
  CHECK(b.fw.state() == State::kEnabled);
  b.run(0.14);  // 240 ms since the last PING: within the 250 ms default
  CHECK(b.fw.state() == State::kEnabled);
  b.run(0.02);
  CHECK(b.fw.state() == State::kFault);
  CHECK((b.fw.faults() & fault::kWatchdog) != 0);
  b.run(kStillUs * 1e-6);  // the bench's spools stop at once: braked still for kStillUs
  CHECK(all_drive(b.out, Drive::kCoast));
  const float length_at_trip = b.length_m(0);
  b.send(msg::Ping{});  // the host is back: the fault stays latched
  b.run(0.1);
  CHECK(b.fw.state() == State::kFault && b.length_m(0) == length_at_trip);
  b.send(msg::SetSetpoints{4, 0, {0.0f, 0.0f, 0.0f, 0.0f}});
  CHECK(static_cast<NackError>(b.replies.last_nack_error) == NackError::kNotEnabled);
  b.run(0.03);
  CHECK(b.replies.last.state == static_cast<uint8_t>(State::kFault) &&
        (b.replies.last.fault_flags & fault::kWatchdog));
  for (size_t i = 0; i < 4; ++i) CHECK(b.replies.last.drive_modes[i] == static_cast<uint8_t>(Drive::kCoast));
  b.send(msg::Enable{});
  CHECK(b.fw.state() == State::kEnabled && b.fw.faults() == 0);
  b.run(0.05);
  CHECK_NEAR(b.out.duty[0], 0.0, 1e-3);  // re-enabled holding where it stopped
}

void watchdog_timeout_is_settable() {
  Bench b;
  CHECK(b.start());
  b.send(msg::SetLimits{6.0f, 50, 45000.0f});
  b.run(0.045);
  CHECK(b.fw.state() == State::kEnabled);
  b.run(0.01);
  CHECK(b.fw.state() == State::kFault);
}

void tension_limit_faults_one_channel() {
  Bench b;
  CHECK(b.start());
  b.run_fed(0.2);
  b.extra_tension_n[2] = 5.5f;  // 1 + 5.5 N > 6 N
  b.run(0.02);
  CHECK(b.fw.state() == State::kFault);
  CHECK(b.fw.faults() == (fault::kTensionLimit | fault::tension_channel(2)));
  b.run(kStillUs * 1e-6);
  CHECK(all_drive(b.out, Drive::kCoast));
  b.extra_tension_n[2] = 0.0f;
  b.send(msg::Ping{});
  b.run(0.05);
  CHECK(b.fw.state() == State::kFault);  // latched after the tension fell
  b.send(msg::Disable{});
  CHECK(b.fw.state() == State::kDisabled && (b.fw.faults() & fault::kTensionLimit));
  b.send(msg::Enable{});
  CHECK(b.fw.state() == State::kEnabled && b.fw.faults() == 0);
}

// A length target the tendon cannot reach (the rod holds it fast, short of it): the loop winds
// its output down to the pull limit and keeps asking for more, so the motor pulls at its cap
// against a still spool and trips the tension limit, though the load cell, reading what the
// motor pulls, stays under the limit.
void a_motor_held_at_its_cap_by_the_length_loop_trips_the_limit() {
  Bench b;
  CHECK(b.start());
  b.stalled_mask = 1u << 1;
  const float cap_n = kPullForceFraction * kDefaultTensionLimitN;
  b.extra_tension_n[1] = cap_n - b.pretension_n;  // the cell reads the motor's pull: plausible
  b.send(msg::SetSetpoints{4, 0, {0.0f, -0.0004f, 0.0f, 0.0f}});
  b.run_fed(0.5);
  CHECK(b.fw.state() == State::kEnabled);  // still winding its output down to the cap
  b.run_fed(1.5);
  CHECK(b.fw.state() == State::kFault);
  CHECK(b.fw.faults() == (fault::kTensionLimit | fault::tension_channel(1)));
}

void stale_loadcell_blocks_motion() {
  Bench b;
  CHECK(b.start());
  b.send(msg::SetSetpoints{4, 0, {0.005f, 0.0f, 0.0f, 0.0f}});
  b.run(0.02);
  CHECK(b.out.drive[0] == Drive::kDrive && b.out.duty[0] > 0.0f);
  b.silenced_mask = 0b1000;
  b.run(0.025);  // 32.5 ms since the last sample: not stale yet
  CHECK(b.out.drive[0] == Drive::kDrive);
  b.run(0.02);
  CHECK(all_drive(b.out, Drive::kBrake));
  CHECK(b.fw.state() == State::kEnabled && b.fw.faults() == fault::kLoadcellStale);
  const float held = b.length_m(0);
  b.send(msg::Ping{});
  b.run(0.1);
  CHECK(b.length_m(0) == held);
  CHECK(b.replies.last.stale_mask == 0b1000 && b.replies.last.channels == 4);
  for (size_t i = 0; i < 4; ++i) CHECK(b.replies.last.drive_modes[i] == static_cast<uint8_t>(Drive::kBrake));
  b.silenced_mask = 0;
  b.run(0.03);
  CHECK(b.fw.faults() == 0 && b.out.drive[0] == Drive::kDrive && b.out.duty[0] > 0.0f);
}

void never_sampled_is_stale() {
  Bench b;
  b.send(msg::Hello{kProtocolVersion});
  b.send(msg::Enable{});  // before any tick: no load cell has reported
  b.silenced_mask = 0b0001;
  b.run(0.1);
  CHECK(b.fw.state() == State::kEnabled && all_drive(b.out, Drive::kBrake));
  CHECK(b.replies.last.stale_mask == 0b0001);
}

void disable_brakes_a_moving_spool_then_coasts() {
  Bench b;
  CHECK(b.start());
  b.send(msg::SetSetpoints{4, 0, {0.005f, 0.0f, 0.0f, 0.0f}});
  b.run(0.02);
  b.send(msg::Disable{});
  // Each motor brakes until its spool has stood still in the brake for kStillUs: motor 1, paying
  // out, would otherwise fly on. The bench's spools stop at once: seen still in the brake from
  // the second tick, they coast kStillUs later.
  b.run(0.001);
  CHECK(b.fw.state() == State::kDisabled && all_drive(b.out, Drive::kBrake));
  b.run(kStillUs * 1e-6);
  CHECK(b.fw.state() == State::kDisabled && all_drive(b.out, Drive::kBrake));
  b.run(0.002);
  CHECK(b.fw.state() == State::kDisabled && all_drive(b.out, Drive::kCoast));
}

void clock_wrap_keeps_schedules() {
  Bench b;
  b.now_us = 0xFFFFFFFFu - 300000u;  // micros() wraps 0.3 s in
  CHECK(b.start());
  b.run_fed(0.6);
  CHECK(b.fw.state() == State::kEnabled);
  CHECK(b.replies.telemetry == 26);  // 0.65 s of ticks at 40 Hz
  CHECK(b.replies.last.time_us == 625000u);
  b.run(0.3);
  CHECK(b.fw.state() == State::kFault);  // the watchdog still counts across the wrap
}

}  // namespace

void test_safety() {
  watchdog_trips_latches_and_reenables();
  watchdog_timeout_is_settable();
  tension_limit_faults_one_channel();
  a_motor_held_at_its_cap_by_the_length_loop_trips_the_limit();
  stale_loadcell_blocks_motion();
  never_sampled_is_stale();
  disable_brakes_a_moving_spool_then_coasts();
  clock_wrap_keeps_schedules();
}
