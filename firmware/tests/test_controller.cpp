#include "bench.h"
#include "pid.h"
#include "check.h"
#include "controller.h"
#include "suites.h"

using namespace twinfw;

namespace {

Measurements at(float l0, float l1, float l2, float l3, float tension_n = 1.0f) {
  return Measurements{{l0, l1, l2, l3}, {tension_n, tension_n, tension_n, tension_n}};
}

void hold_is_bumpless() {
  for (uint8_t m = 0; m < kModes; ++m) {
    Controller c;
    const Measurements now = at(0.002f, -0.001f, 0.0005f, 0.003f, 1.3f);
    c.set_mode(static_cast<Mode>(m), now, 6.0f);
    float duty[kDefaultChannels];
    c.step(now, kControlPeriodS, duty);
    for (float d : duty) CHECK_NEAR(d, 0.0, 1e-6);
  }
}

void mode_switch_keeps_the_motors_pulling() {
  // Lengths held with the motors pulling (reeling in) against the tendon tension; switching to
  // tension mode at the measured tension carries each motor's duty over instead of dropping it.
  Controller c;
  const Measurements now = at(-0.001f, 0.0f, 0.001f, 0.0f, 2.0f);
  c.set_mode(Mode::kLengths, now, 6.0f);
  const float sp[kDefaultChannels] = {-0.0012f, 0.0f, 0.0012f, 0.0f};
  c.set_setpoints(sp);
  float before[kDefaultChannels];
  for (int k = 0; k < 50; ++k) c.step(now, kControlPeriodS, before);
  CHECK(before[0] < -0.01f && before[2] > 0.01f);
  c.set_mode(Mode::kTension, now, 6.0f);
  float after[kDefaultChannels];
  c.step(now, kControlPeriodS, after);
  // The tension gains clamp at 0.2 duty; within that the duty is unchanged.
  for (size_t i = 0; i < kDefaultChannels; ++i) {
    const float expected = before[i] > 0.2f ? 0.2f : (before[i] < -0.2f ? -0.2f : before[i]);
    CHECK_NEAR(after[i], expected, 1e-6);
  }
  // A restart (motion held, or enabling) starts from a stopped motor again.
  c.restart(now);
  c.step(now, kControlPeriodS, after);
  for (float d : after) CHECK_NEAR(d, 0.0, 1e-6);
}

void antagonistic_pairs_couple() {
  Controller c;
  // Pair (1,3) centred at 1 mm, pair (2,4) at −0.5 mm when the mode is entered.
  c.set_mode(Mode::kPairs, at(0.002f, -0.001f, 0.0f, 0.0f), 6.0f);
  CHECK_NEAR(c.targets()[0], 0.002, 1e-7);
  CHECK_NEAR(c.targets()[2], 0.0, 1e-7);
  const float d[kDefaultChannels] = {0.003f, -0.0005f, 0.0f, 0.0f};
  c.set_setpoints(d);
  // One tendon shortens by what the other pays out, about the pair's centre.
  CHECK_NEAR(c.targets()[0], 0.001 + 0.003, 1e-7);
  CHECK_NEAR(c.targets()[2], 0.001 - 0.003, 1e-7);
  CHECK_NEAR(c.targets()[1], -0.0005 - 0.0005, 1e-7);
  CHECK_NEAR(c.targets()[3], -0.0005 + 0.0005, 1e-7);
  CHECK_NEAR(c.targets()[0] + c.targets()[2], 0.002, 1e-7);
  float duty[kDefaultChannels];
  c.step(at(0.002f, -0.001f, 0.0f, 0.0f), kControlPeriodS, duty);
  CHECK(duty[0] > 0.0f && duty[2] < 0.0f);  // tendon 1 pays out, tendon 3 reels in
}

void tension_mode_sign() {
  Controller c;
  c.set_mode(Mode::kTension, at(0, 0, 0, 0, 1.0f), 6.0f);
  const float sp[kDefaultChannels] = {1.5f, 0.5f, 1.0f, 1.0f};
  c.set_setpoints(sp);
  float duty[kDefaultChannels];
  c.step(at(0, 0, 0, 0, 1.0f), kControlPeriodS, duty);
  CHECK(duty[0] < 0.0f);  // too slack: reel in
  CHECK(duty[1] > 0.0f);  // too tight: pay out
  CHECK_NEAR(duty[2], 0.0, 1e-6);
}

void tension_references_ramp() {
  // A tension step is driven as a ramp at tension_rate(): 20 N/s is 0.2 N per 10 ms period.
  Controller c;
  c.set_tension_rate(20.0f);
  const Measurements now = at(0, 0, 0, 0, 1.0f);
  c.set_mode(Mode::kTension, now, 2.0f);
  const float sp[kDefaultChannels] = {2.0f, 0.5f, 1.0f, 1.1f};
  c.set_setpoints(sp);
  float duty[kDefaultChannels];
  c.step(now, kControlPeriodS, duty);
  CHECK_NEAR(c.references()[0], 1.2, 1e-6);
  CHECK_NEAR(c.references()[1], 0.8, 1e-6);
  CHECK_NEAR(c.references()[2], 1.0, 1e-6);
  CHECK_NEAR(c.references()[3], 1.1, 1e-6);
  for (int k = 0; k < 4; ++k) c.step(now, kControlPeriodS, duty);
  CHECK_NEAR(c.references()[0], 2.0, 1e-6);
  CHECK_NEAR(c.references()[1], 0.5, 1e-6);
  CHECK_NEAR(c.targets()[0], 2.0, 0.0);  // the targets are the setpoints at once
}

// With the tendon damping on, a taut tendon swinging out (paying out) is held at more than its reference,
// one swinging in at less: the motor winds in harder against the one, lets go of the other,
// a damper on the rod's swing. Slack, the reference itself.
void tension_damping_on_a_taut_tendon() {
  const float taut_n = 2.0f, slack_n = 0.3f;  // the 6 N limit's taut fraction is 0.6 N
  auto duties_after = [](float tension_n, float speed_m_s, int periods) {
    Controller c;
    c.set_tension_damping(1500.0f);
    c.set_mode(Mode::kTension, at(0, 0, 0, 0, tension_n), 6.0f);
    float duty[kDefaultChannels] = {};
    for (int k = 1; k <= periods; ++k) {
      const float x = speed_m_s * kControlPeriodS * static_cast<float>(k);
      c.step(at(x, -x, 0.0f, 0.0f, tension_n), kControlPeriodS, duty);
    }
    return duty[0] - duty[2];  // channel 0 moves, channel 2 stands still
  };
  // 2 mm/s out for 50 ms: wound in harder (more negative duty) than the still channel.
  CHECK(duties_after(taut_n, 0.002f, 5) < -1e-4f);
  CHECK(duties_after(taut_n, -0.002f, 5) > 1e-4f);
  // A slack tendon is not damped: its spool is free.
  CHECK_NEAR(duties_after(slack_n, 0.002f, 5), 0.0, 1e-6);
}

void tension_hold_clamps_to_limit() {
  Controller c;
  Measurements now = at(0, 0, 0, 0, 0.0f);
  now.tensions_n[0] = -0.2f;
  now.tensions_n[1] = 9.0f;
  c.set_mode(Mode::kTension, now, 6.0f);
  CHECK_NEAR(c.targets()[0], 0.0, 0.0);
  CHECK_NEAR(c.targets()[1], 6.0, 0.0);
}

// A motor holding tension on a tendon that friction in the disc holes holds (presliding): the
// stalled motor pulls with duty × kDefaultStallForceN through 2.7 kg of reflected rotor and 300 N·s/m
// of back-EMF against a 60 kN/m load (the twin's at μ = 0.1: 2 N over 30 µm of spool travel),
// its load cell sampled at 80 Hz, the loop stepped at 100 Hz with the tuned gains of
// twin/control/gains.py. `duty_of(tension_n)` is the loop; returns the peak-to-peak tension (N)
// over the last second of 4 s, and the mean's offset from `setpoint_n` in *offset_n.
template <class Loop>
float stiff_load_ripple(Loop duty_of, float setpoint_n, float* offset_n) {
  constexpr double kMassKg = 2.7;
  constexpr double kStiffnessNPerM = 60e3;
  constexpr double kSubstepS = 1e-4;
  double x_m = 0.0, v_m_s = 0.0;  // spool travel paid out
  float sampled_n = setpoint_n, duty = 0.0f;
  float lowest = 1e9f, highest = -1e9f;
  double sum = 0.0;
  int count = 0;
  for (int k = 0; k < 40000; ++k) {
    const double t_s = k * kSubstepS;
    const double tension_n = setpoint_n - kStiffnessNPerM * x_m;
    if (k % 125 == 0) sampled_n = static_cast<float>(tension_n);  // HX711 at 80 Hz
    if (k % 100 == 0) duty = duty_of(sampled_n);                   // control at 100 Hz
    const double force_n = tension_n + duty * kDefaultStallForceN - kDefaultMotorDampingNsPerM * v_m_s;
    v_m_s += force_n / kMassKg * kSubstepS;
    x_m += v_m_s * kSubstepS;
    if (t_s >= 3.0) {
      const float t = static_cast<float>(tension_n);
      lowest = t < lowest ? t : lowest;
      highest = t > highest ? t : highest;
      sum += t;
      ++count;
    }
  }
  *offset_n = static_cast<float>(sum / count) - setpoint_n;
  return highest - lowest;
}

void tension_hold_settles_on_a_stiff_load() {
  const PidGains tuned{0.006f, 0.15f, 0.0f, 0.035f};
  float offset_n = 0.0f;
  // Without the lag on the proportional term the loop rings up to the duty clamp.
  Pid pid;
  pid.reset(-2.0f);
  const float ringing = stiff_load_ripple([&](float t) { return pid.step(tuned, -2.0f, -t, kControlPeriodS); },
                                          2.0f, &offset_n);
  CHECK(ringing > 0.5f);
  // Its proportional term through a 50 ms lag settles on the setpoint.
  Pid lagged;
  lagged.reset(-2.0f);
  const float ripple = stiff_load_ripple(
      [&](float t) { return lagged.step(tuned, -2.0f, -t, kControlPeriodS, -tuned.output_limit, tuned.output_limit, 0.0f, 0.05f); }, 2.0f,
      &offset_n);
  CHECK(ripple < 0.01f);
  CHECK_NEAR(offset_n, 0.0, 0.005);
}

void closed_loops_on_the_bench() {
  {
    bench::Bench b;
    CHECK(b.start(Mode::kLengths));
    b.send(msg::SetSetpoints{4, 0, {0.002f, -0.003f, 0.0f, 0.001f}});
    b.run_fed(3.0);
    CHECK_NEAR(b.length_m(0), 0.002, 5e-6);
    CHECK_NEAR(b.length_m(1), -0.003, 5e-6);
    CHECK_NEAR(b.length_m(3), 0.001, 5e-6);
  }
  {
    bench::Bench b;
    CHECK(b.start(Mode::kPairs));
    b.send(msg::SetSetpoints{4, 1, {0.002f, -0.001f, 0.0f, 0.0f}});
    b.run_fed(3.0);
    CHECK_NEAR(b.length_m(0), 0.002, 5e-6);
    CHECK_NEAR(b.length_m(2), -0.002, 5e-6);
    CHECK_NEAR(b.length_m(1), -0.001, 5e-6);
    CHECK_NEAR(b.length_m(3), 0.001, 5e-6);
  }
  {
    bench::Bench b;
    // The bench's motor is a velocity source on a soft spring, not the rig's stalled motor on a
    // stiff tendon that the default tension gains are tuned for: give it gains for its own plant.
    CHECK(b.start(Mode::kTension));
    b.send(msg::SetGains{2, 0.04f, 0.1f, 0.0f, 0.5f});
    b.send(msg::SetSetpoints{4, 2, {1.5f, 0.5f, 1.0f, 1.2f}});
    b.run_fed(3.0);
    CHECK_NEAR(b.tension_n(0), 1.5, 0.01);
    CHECK_NEAR(b.tension_n(1), 0.5, 0.01);
    CHECK_NEAR(b.tension_n(3), 1.2, 0.01);
    CHECK(b.length_m(0) < 0.0f);  // reeled in to tighten
  }
}

}  // namespace

void test_controller() {
  hold_is_bumpless();
  mode_switch_keeps_the_motors_pulling();
  antagonistic_pairs_couple();
  tension_mode_sign();
  tension_references_ramp();
  tension_hold_clamps_to_limit();
  tension_damping_on_a_taut_tendon();
  tension_hold_settles_on_a_stiff_load();
  closed_loops_on_the_bench();
}
