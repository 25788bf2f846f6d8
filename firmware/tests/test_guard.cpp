#include <cmath>
#include <initializer_list>

#include "check.h"
#include "guard.h"
#include "suites.h"

using namespace twinfw;

namespace {

constexpr float kLimitN = 6.0f;
const float kRelaxed[kDefaultChannels] = {1.0f, 1.0f, 1.0f, 1.0f};

// A guard that has seen spools moving at `winding_m_s` (positive = winding in) for 5 ms.
Guard moving(const float winding_m_s[kDefaultChannels], const float tensions_n[kDefaultChannels] = kRelaxed) {
  Guard g;
  g.set_tension_limit(kLimitN);
  int32_t counts[kDefaultChannels] = {};
  g.observe(0, counts, tensions_n, 0);
  for (size_t i = 0; i < kDefaultChannels; ++i) {
    counts[i] = static_cast<int32_t>(std::lround(-winding_m_s[i] * 0.005 / kTendonMPerCount));
  }
  g.observe(5000, counts, tensions_n, 0);
  return g;
}

void a_motor_winds_in_with_at_most_the_cap_and_nan_gives_zero() {
  const float still[kDefaultChannels] = {};
  Guard g = moving(still);
  const float command[kDefaultChannels] = {-1.0f, 1.0f, NAN, -0.01f};
  float duty[kDefaultChannels];
  Drive drive[kDefaultChannels];
  g.drive(command, duty, drive);
  // 0.9 of the 6 N limit over the 154 N stall force; paying out is not bounded.
  CHECK_NEAR(duty[0], -0.9 * 6.0 / kDefaultStallForceN, 1e-6);
  CHECK_NEAR(duty[1], 1.0, 0.0);
  CHECK(duty[2] == 0.0f);
  CHECK_NEAR(duty[3], -0.01, 1e-7);
  for (Drive d : drive) CHECK(d == Drive::kDrive);
  // A lower limit lowers the cap with it.
  g.set_tension_limit(2.0f);
  g.drive(command, duty, drive);
  CHECK_NEAR(duty[0], -0.9 * 2.0 / kDefaultStallForceN, 1e-6);
}

void the_winding_speed_limit_takes_the_pull_away() {
  Guard reference;
  reference.set_tension_limit(kLimitN);
  const float limit = reference.winding_speed_limit();
  // (1.2 − 0.9) · 6 N over 390 N·s/m.
  CHECK_NEAR(limit, 0.3 * 6.0 / 390.0, 1e-6);
  const float speeds[kDefaultChannels] = {0.0f, 0.5f * limit, limit, 2.0f * limit};
  const float slack[kDefaultChannels] = {};
  Guard g = moving(speeds, slack);
  const float pull = -1.0f;
  const float command[kDefaultChannels] = {pull, pull, pull, pull};
  float duty[kDefaultChannels];
  Drive drive[kDefaultChannels];
  g.drive(command, duty, drive);
  const double cap = 0.9 * 6.0 / kDefaultStallForceN;
  CHECK_NEAR(duty[0], -cap, 1e-6);
  CHECK(duty[1] > -cap && duty[1] < 0.0f);
  // At the limit only what balances the back-EMF damping: the spool cannot speed up (to within
  // the speed's encoder quantum, 0.19 mm/s, worth 0.2 N of pull).
  CHECK_NEAR(duty[2], -kDefaultMotorDampingNsPerM * limit / kDefaultStallForceN, 1.5e-3);
  CHECK(duty[3] == 0.0f);  // beyond it, nothing
  // Paying out is never held back.
  const float out[kDefaultChannels] = {1.0f, 1.0f, 1.0f, 1.0f};
  g.drive(out, duty, drive);
  for (float d : duty) CHECK(d == 1.0f);
  // A taut tendon (over a tenth of the cap) may be wound in twice as fast: at the slack limit
  // its motor still pulls.
  const float taut[kDefaultChannels] = {1.0f, 1.0f, 1.0f, 1.0f};
  Guard t = moving(speeds, taut);
  CHECK_NEAR(t.winding_speed_limit(2), 2.0 * limit, 1e-7);
  t.drive(command, duty, drive);
  CHECK(duty[2] < -0.5 * cap && duty[3] < 0.0f);
}

void a_released_motor_brakes_until_its_spool_stands_still_in_the_brake() {
  Guard g;
  g.set_tension_limit(kLimitN);
  const float command[kDefaultChannels] = {-0.01f, -0.01f, -0.01f, -0.01f};
  float duty[kDefaultChannels];
  Drive drive[kDefaultChannels];
  int32_t counts[kDefaultChannels] = {};
  uint32_t now_us = 0;
  g.observe(now_us, counts, kRelaxed, 0);
  g.drive(command, duty, drive);
  g.applied(drive);
  // Released while spool 0 winds in at 10 mm/s and the others stand still: all brake first
  // (the brake has not acted yet), then the still ones coast once they have stayed still in the
  // brake for kStillUs, and spool 0 brakes on.
  g.release(duty, drive);
  for (Drive d : drive) CHECK(d == Drive::kBrake);
  const int32_t moving = static_cast<int32_t>(0.01 * 0.005 / kTendonMPerCount);
  for (int tick = 0; tick < 4; ++tick) {
    g.applied(drive);
    counts[0] -= moving;
    now_us += 5000;
    g.observe(now_us, counts, kRelaxed, 0);
    g.release(duty, drive);
    for (Drive d : drive) CHECK(d == Drive::kBrake);
  }
  g.applied(drive);
  counts[0] -= moving;
  now_us += 5000;  // still in the brake since the first window: for kStillUs now
  g.observe(now_us, counts, kRelaxed, 0);
  g.release(duty, drive);
  CHECK(drive[0] == Drive::kBrake && drive[1] == Drive::kCoast && drive[2] == Drive::kCoast);
  for (int tick = 0; tick < 5; ++tick) {
    g.applied(drive);
    now_us += 5000;
    g.observe(now_us, counts, kRelaxed, 0);
    g.release(duty, drive);
  }
  for (Drive d : drive) CHECK(d == Drive::kCoast);
  for (float d : duty) CHECK(d == 0.0f);
  // Coasting stays coasting until the motor drives again.
  counts[1] += 50;
  g.applied(drive);
  now_us += 5000;
  g.observe(now_us, counts, kRelaxed, 0);
  g.release(duty, drive);
  CHECK(drive[1] == Drive::kCoast);
}

void a_spool_the_brake_turns_round_is_not_taken_for_still() {
  // Released while winding in, spool 0 is turned round by its tendon in the brake: one window
  // through zero speed, then it is pulled out at 2 mm/s. It brakes on.
  Guard g;
  g.set_tension_limit(kLimitN);
  const float command[kDefaultChannels] = {-0.01f, 0.0f, 0.0f, 0.0f};
  float duty[kDefaultChannels];
  Drive drive[kDefaultChannels];
  int32_t counts[kDefaultChannels] = {};
  g.observe(0, counts, kRelaxed, 0);
  g.drive(command, duty, drive);
  g.applied(drive);
  g.release(duty, drive);
  g.applied(drive);
  g.observe(5000, counts, kRelaxed, 0);  // through zero
  g.release(duty, drive);
  CHECK(drive[0] == Drive::kBrake);
  g.applied(drive);
  uint32_t now_us = 5000;
  for (int tick = 0; tick < 8; ++tick) {
    counts[0] += static_cast<int32_t>(0.002 * 0.005 / kTendonMPerCount);
    now_us += 5000;
    g.observe(now_us, counts, kRelaxed, 0);
    g.release(duty, drive);
    g.applied(drive);
    CHECK(drive[0] == Drive::kBrake);
  }
}

void no_brake_resists_a_spool_flying_out_with_more_than_the_cap() {
  // Spool 0 pays out at 50 mm/s, spool 1 at 10 mm/s: shorted, the back-EMF would resist them
  // with 15 N and 3 N against a 5.4 N cap. Spool 0's motor drives along to leave the cap, spool
  // 1's brakes, and neither may wind in.
  const float speeds[kDefaultChannels] = {-0.05f, -0.01f, 0.0f, 0.0f};
  Guard g = moving(speeds);
  const double cap_n = 0.9 * kLimitN;
  const double back_emf_n = kDefaultMotorDampingNsPerM * 0.05;
  float duty[kDefaultChannels];
  Drive drive[kDefaultChannels];
  g.hold(duty, drive);
  CHECK(drive[0] == Drive::kDrive);
  // To the encoder quantum of the speed (0.19 mm/s: 0.06 N).
  CHECK_NEAR(duty[0] * kDefaultStallForceN, back_emf_n - cap_n, 0.1);
  CHECK(drive[1] == Drive::kBrake && duty[1] == 0.0f);
  CHECK(drive[2] == Drive::kBrake && drive[3] == Drive::kBrake);
  g.release(duty, drive);
  CHECK(drive[0] == Drive::kDrive && duty[0] > 0.0f && drive[1] == Drive::kBrake);
  const float pull[kDefaultChannels] = {-1.0f, -1.0f, -1.0f, NAN};
  g.drive(pull, duty, drive);
  CHECK_NEAR(duty[0] * kDefaultStallForceN, back_emf_n - cap_n, 0.1);
  CHECK_NEAR(duty[1] * kDefaultStallForceN, kDefaultMotorDampingNsPerM * 0.01 - cap_n, 0.1);
  CHECK_NEAR(duty[2] * kDefaultStallForceN, -cap_n, 1e-4);
  CHECK(duty[3] == 0.0f);
  // NaN on spool 0 gives the duty that leaves the cap, not the full brake of 0.
  const float nan[kDefaultChannels] = {NAN, NAN, NAN, NAN};
  g.drive(nan, duty, drive);
  CHECK(duty[0] > 0.0f && duty[1] == 0.0f);
}

void a_motor_at_its_cap_against_a_still_spool_trips_the_tension_limit() {
  const float still[kDefaultChannels] = {};
  const float tensions[kDefaultChannels] = {5.4f, 1.0f, 1.0f, 1.0f};
  Guard g = moving(still, tensions);
  const float cap = -0.9f * 6.0f / kDefaultStallForceN;
  const float duty[kDefaultChannels] = {cap, -0.005f, 0.0f, 0.01f};
  const Drive drive[kDefaultChannels] = {Drive::kDrive, Drive::kDrive, Drive::kDrive, Drive::kDrive};
  CHECK(g.faults(10000, duty, drive) == 0);
  CHECK(g.faults(10000 + kAtCapUs - 1000, duty, drive) == 0);
  CHECK(g.faults(10000 + kAtCapUs, duty, drive) == (fault::kTensionLimit | fault::tension_channel(0)));
}

void a_motor_whose_loop_asks_beyond_the_cap_against_a_still_spool_trips_too() {
  // Spool 0's PID asks for more than the cap and stops its integral a little short of it:
  // 0.1 % less pull than the cap, which alone does not count as at the cap. Spool 1 pulls as
  // much, its loop content: no trip.
  const float still[kDefaultChannels] = {};
  const float tensions[kDefaultChannels] = {5.4f, 5.4f, 1.0f, 1.0f};
  Guard g = moving(still, tensions);
  const float short_of_cap = -0.998f * 0.9f * 6.0f / kDefaultStallForceN;
  const float duty[kDefaultChannels] = {short_of_cap, short_of_cap, 0.0f, 0.0f};
  const Drive drive[kDefaultChannels] = {Drive::kDrive, Drive::kDrive, Drive::kDrive, Drive::kDrive};
  CHECK(g.faults(10000, duty, drive) == 0);
  CHECK(g.faults(10000 + kAtCapUs, duty, drive) == 0);
  CHECK(g.faults(20000 + kAtCapUs, duty, drive, 1u << 0) == 0);
  CHECK(g.faults(20000 + 2 * kAtCapUs - 1000, duty, drive, 1u << 0) == 0);
  CHECK(g.faults(20000 + 2 * kAtCapUs, duty, drive, 1u << 0) == (fault::kTensionLimit | fault::tension_channel(0)));
  // A spool that moves is not held: its loop asking for more is no trip.
  const float winding[kDefaultChannels] = {0.003f, 0.0f, 0.0f, 0.0f};
  Guard m = moving(winding, tensions);
  CHECK(m.faults(10000, duty, drive, 1u << 0) == 0);
  CHECK(m.faults(10000 + kAtCapUs, duty, drive, 1u << 0) == 0);
}

void a_motor_at_its_cap_against_a_spool_creeping_out_trips_too() {
  // Spool 0 creeps out at 0.4 mm/s (still) under a tendon the motor holds at its cap: its duty
  // leaves the back-EMF's share of the cap. The next windows read a count more or less; the
  // motor is at its cap all the same and trips after kAtCapUs.
  const float creep[kDefaultChannels] = {-0.0004f, 0.0f, 0.0f, 0.0f};
  const float tensions[kDefaultChannels] = {5.4f, 1.0f, 1.0f, 1.0f};
  Guard g = moving(creep, tensions);
  const float pull[kDefaultChannels] = {-1.0f, 0.0f, 0.0f, 0.0f};
  float duty[kDefaultChannels];
  Drive drive[kDefaultChannels];
  g.drive(pull, duty, drive);
  CHECK(duty[0] > -0.9f * kLimitN / kDefaultStallForceN);
  int32_t counts[kDefaultChannels] = {};
  counts[0] = static_cast<int32_t>(std::lround(0.0004 * 0.005 / kTendonMPerCount));
  uint32_t now_us = 5000;
  for (int tick = 0; tick <= static_cast<int>(kAtCapUs / 5000); ++tick) {
    now_us += 5000;
    counts[0] += 1 + tick % 2;  // 0.19 or 0.38 mm/s
    g.observe(now_us, counts, tensions, 0);
    const uint32_t flags = g.faults(now_us, duty, drive);
    if (tick < static_cast<int>(kAtCapUs / 5000)) CHECK(flags == 0);
    if (tick == static_cast<int>(kAtCapUs / 5000)) CHECK(flags == (fault::kTensionLimit | fault::tension_channel(0)));
  }
}

void a_cell_reading_far_under_its_stalled_motors_pull_is_implausible() {
  const float still[kDefaultChannels] = {};
  // Channel 1 reads a tenth of what its motor pulls at stall (3 N); channel 2 half of it.
  const float tensions[kDefaultChannels] = {1.0f, 0.3f, 1.5f, 0.0f};
  Guard g = moving(still, tensions);
  const float pull = -3.0f / kDefaultStallForceN;
  const float duty[kDefaultChannels] = {-0.5f / kDefaultStallForceN, pull, pull, 0.0f};
  const Drive drive[kDefaultChannels] = {Drive::kDrive, Drive::kDrive, Drive::kDrive, Drive::kBrake};
  CHECK(g.faults(10000, duty, drive) == 0);
  const uint32_t flags = g.faults(10000 + kImplausibleUs, duty, drive);
  CHECK(flags == (fault::kLoadcellImplausible | fault::implausible_channel(1)));
  // A break in the condition starts the count again.
  const float fine[kDefaultChannels] = {1.0f, 3.0f, 1.5f, 0.0f};
  int32_t counts[kDefaultChannels] = {};
  g.observe(20000 + kImplausibleUs, counts, fine, 0);
  CHECK(g.faults(20000 + kImplausibleUs, duty, drive) == 0);
  g.observe(30000 + kImplausibleUs, counts, tensions, 0);
  CHECK(g.faults(30000 + kImplausibleUs, duty, drive) == 0);
}

// Other motors: a stronger, faster one with a heavier rotor. The cap stays 0.9 of the limit as
// force, so its duty falls with the stall force; the blow bound slows winding by √(mass ratio);
// the implausibility check compares the cell with this motor's pull.
void the_bounds_follow_the_motors_the_host_gives() {
  Guard g;
  g.set_tension_limit(kLimitN);
  const float stall_n = 2.0f * kDefaultStallForceN;
  const float speed_m_s = 3.0f * kDefaultNoLoadSpeedMPerS;
  const float mass_kg = 4.0f * kDefaultReflectedMassKg;
  g.set_motors(stall_n, speed_m_s, mass_kg);
  CHECK_NEAR(g.pull_limit(), 0.9 * 6.0 / stall_n, 1e-7);
  CHECK_NEAR(g.damping_ns_per_m(), stall_n / speed_m_s, 1e-3);
  CHECK_NEAR(g.winding_speed_limit(), 0.3 * 6.0 / (390.0 * 2.0), 1e-7);
  // The brake settles over twice its time constant: 4 × 2.66 kg over 200 N·s/m, 106 ms.
  CHECK(g.still_us() == static_cast<uint32_t>(2.0f * mass_kg / g.damping_ns_per_m() * 1e6f));
  // A limit set later keeps the motors.
  g.set_tension_limit(2.0f);
  CHECK_NEAR(g.pull_limit(), 0.9 * 2.0 / stall_n, 1e-7);
  CHECK_NEAR(g.winding_speed_limit(), 0.3 * 2.0 / (390.0 * 2.0), 1e-7);
  // A light rotor keeps the thesis's 20 ms of stillness.
  g.set_motors(kDefaultStallForceN, kDefaultNoLoadSpeedMPerS, 0.1f);
  CHECK(g.still_us() == kStillUs);
  // 3 N of this motor's pull against a cell reading 0.35 N is implausible; with the thesis's
  // motor the same duty pulls 1.5 N, which 0.35 N is not implausibly far from.
  Guard strong;
  strong.set_tension_limit(kLimitN);
  strong.set_motors(stall_n, speed_m_s, mass_kg);
  Guard thesis;
  thesis.set_tension_limit(kLimitN);
  const float tensions[kDefaultChannels] = {0.35f, 0.35f, 0.35f, 0.35f};
  const int32_t counts[kDefaultChannels] = {};
  const float duty[kDefaultChannels] = {-3.0f / stall_n, 0.0f, 0.0f, 0.0f};
  const Drive drive[kDefaultChannels] = {Drive::kDrive, Drive::kBrake, Drive::kBrake, Drive::kBrake};
  for (Guard* guard : {&strong, &thesis}) {
    guard->observe(0, counts, tensions, 0);
    guard->observe(5000, counts, tensions, 0);
    guard->faults(5000, duty, drive);
  }
  CHECK(strong.faults(5000 + kImplausibleUs, duty, drive) == (fault::kLoadcellImplausible | fault::implausible_channel(0)));
  CHECK(thesis.faults(5000 + kImplausibleUs, duty, drive) == 0);
}

// A slack tendon taken up slowly by a strongly damped motor: its spool counts as still, and its
// duty's stall pull (1.2 N) is what back-EMF mostly takes; the cell reading nothing is plausible.
// The same pull on a spool that does not turn is not.
void a_slack_tendon_wound_in_slowly_is_not_implausible() {
  const float stall_n = 4.0f * kDefaultStallForceN;
  const float damping = stall_n / kDefaultNoLoadSpeedMPerS;  // 1200 N·s/m
  const float w = 0.0009f;                                    // winding in, under kStillSpeedMPerS
  const float slack[kDefaultChannels] = {0.0f, 0.0f, 0.0f, 0.0f};
  const float duty[kDefaultChannels] = {-(damping * w + 0.1f) / stall_n, 0.0f, 0.0f, 0.0f};
  const Drive drive[kDefaultChannels] = {Drive::kDrive, Drive::kBrake, Drive::kBrake, Drive::kBrake};
  for (const bool turning : {true, false}) {
    Guard g;
    g.set_tension_limit(kLimitN);
    g.set_motors(stall_n, kDefaultNoLoadSpeedMPerS, kDefaultReflectedMassKg);
    int32_t counts[kDefaultChannels] = {};
    g.observe(0, counts, slack, 0);
    uint32_t flags = 0;
    for (uint64_t t = 5000; t <= 5000 + kImplausibleUs + 20000; t += 5000) {
      if (turning) counts[0] -= static_cast<int32_t>(std::lround(w * 0.005 / kTendonMPerCount));
      g.observe(t, counts, slack, 0);
      float out[kDefaultChannels];
      Drive d[kDefaultChannels];
      g.drive(duty, out, d);
      flags |= g.faults(t, duty, drive);
    }
    CHECK(flags == (turning ? 0u : (fault::kLoadcellImplausible | fault::implausible_channel(0))));
  }
}

void lasting_counts_unbroken_spans() {
  Lasting l;
  CHECK(l.update(0, 0b0011, 100) == 0);
  CHECK(l.update(99, 0b0011, 100) == 0);
  CHECK(l.update(100, 0b0001, 100) == 0b0001);
  CHECK(l.update(150, 0b0011, 100) == 0b0001);  // channel 1 broke off at 100
  CHECK(l.update(250, 0b0011, 100) == 0b0011);
}

}  // namespace

void test_guard() {
  a_motor_whose_loop_asks_beyond_the_cap_against_a_still_spool_trips_too();
  a_motor_winds_in_with_at_most_the_cap_and_nan_gives_zero();
  the_winding_speed_limit_takes_the_pull_away();
  a_released_motor_brakes_until_its_spool_stands_still_in_the_brake();
  a_spool_the_brake_turns_round_is_not_taken_for_still();
  no_brake_resists_a_spool_flying_out_with_more_than_the_cap();
  a_motor_at_its_cap_against_a_still_spool_trips_the_tension_limit();
  a_motor_at_its_cap_against_a_spool_creeping_out_trips_too();
  a_cell_reading_far_under_its_stalled_motors_pull_is_implausible();
  the_bounds_follow_the_motors_the_host_gives();
  a_slack_tendon_wound_in_slowly_is_not_implausible();
  lasting_counts_unbroken_spans();
}
