#include <cmath>

#include "check.h"
#include "pid.h"
#include "suites.h"

using namespace twinfw;

namespace {

constexpr float kDt = 0.01f;

void proportional_and_output_clamp() {
  Pid pid;
  pid.reset(0.0f);
  CHECK_NEAR(pid.step({2.0f, 0.0f, 0.0f, 1.0f}, 0.25f, 0.0f, kDt), 0.5, 1e-6);
  CHECK_NEAR(pid.step({2.0f, 0.0f, 0.0f, 1.0f}, 5.0f, 0.0f, kDt), 1.0, 0.0);
  CHECK_NEAR(pid.step({2.0f, 0.0f, 0.0f, 0.3f}, -5.0f, 0.0f, kDt), -0.3f, 0.0);
}

void integrator_clamp_prevents_windup() {
  const PidGains g{0.1f, 10.0f, 0.0f, 1.0f};
  Pid pid;
  pid.reset(0.0f);
  for (int i = 0; i < 1000; ++i) pid.step(g, 1.0f, 0.0f, kDt);  // unclamped integral would be 100
  // Now overshoot by 0.5: P gives -0.05 and the integral falls by 0.05 per step from 1, so the
  // output turns negative after ~19 steps. A wound-up integral would take ~2000.
  int steps = 0;
  while (pid.step(g, 1.0f, 1.5f, kDt) > 0.0f && steps < 1000) ++steps;
  CHECK(steps >= 15 && steps <= 20);
}

void a_step_asking_beyond_lowest_says_so() {
  // Pure integral, -0.1 per step: -0.1, -0.2, and the step to -0.3 would pass -0.25. The
  // integral stops at -0.2, one increment short of the bound, and the PID says it asks for more.
  const PidGains g{0.0f, 10.0f, 0.0f, 1.0f};
  Pid pid;
  pid.reset(0.0f);
  CHECK_NEAR(pid.step(g, -1.0f, 0.0f, kDt, -0.25f, 1.0f), -0.1, 1e-6);
  CHECK(!pid.below_lowest());
  float out = 0.0f;
  for (int i = 0; i < 5; ++i) out = pid.step(g, -1.0f, 0.0f, kDt, -0.25f, 1.0f);
  CHECK_NEAR(out, -0.2, 1e-6);
  CHECK(pid.below_lowest());
  // The error turned round: it asks for less, and the integral leaves at once.
  CHECK(pid.step(g, 1.0f, 0.0f, kDt, -0.25f, 1.0f) > -0.15f && !pid.below_lowest());
  pid.step(g, -1.0f, 0.0f, kDt, -0.25f, 1.0f);
  pid.step(g, -1.0f, 0.0f, kDt, -0.25f, 1.0f);
  CHECK(pid.below_lowest());
  pid.reset(0.0f);
  CHECK(!pid.below_lowest());
}

void derivative_on_measurement() {
  const PidGains g{1.0f, 0.0f, 0.1f, 100.0f};
  Pid pid;
  pid.reset(0.0f);
  // A setpoint step gives only the proportional jump: no derivative kick.
  CHECK_NEAR(pid.step(g, 1.0f, 0.0f, kDt), 1.0, 1e-6);
  // A measurement change of 0.01 in 10 ms is a rate of 1/s: derivative term −kd · 1.
  CHECK_NEAR(pid.step(g, 1.0f, 0.01f, kDt), 0.99 - 0.1, 1e-5);
  // After reset() the first step does not difference against the old measurement.
  pid.reset(0.5f);
  CHECK_NEAR(pid.step(g, 1.0f, 0.5f, kDt), 0.5, 1e-6);
}

void step_response_settles() {
  // Integrating plant x' = 10 · u (a motor driving a tendon), PI loop at 100 Hz: closed-loop
  // poles at −2.8 and −37 /s, the zero at −2.5 nearly cancels the slow one, so a step that
  // does not saturate the output settles within 2 s with ~5 % overshoot.
  const PidGains g{4.0f, 10.0f, 0.0f, 1.0f};
  Pid pid;
  pid.reset(0.0f);
  float x = 0.0f;
  float peak = 0.0f;
  for (int i = 0; i < 200; ++i) {
    x += 10.0f * pid.step(g, 0.2f, x, kDt) * kDt;
    if (x > peak) peak = x;
  }
  CHECK_NEAR(x, 0.2, 2e-4);
  CHECK(peak < 0.22f);
}

void huge_gains_never_give_nan() {
  // kp · error and kd · rate overflow to +inf and −inf: their sum is NaN, which the clamp turns
  // into 0 rather than pass to a motor. (The firmware refuses such gains; this is the last line.)
  const PidGains g{3e38f, 0.0f, 3e38f, 1.0f};
  Pid pid;
  pid.reset(0.0f);
  const float out = pid.step(g, 10.0f, -2.0f, kDt);
  CHECK(out == out && out >= -1.0f && out <= 1.0f);
  CHECK(clamp_range(NAN, -0.5f, 1.0f) == 0.0f);
  CHECK(clamp_range(INFINITY, -0.5f, 1.0f) == 1.0f && clamp_range(-INFINITY, -0.5f, 1.0f) == -0.5f);
}

void asymmetric_clamp_and_feedforward() {
  const PidGains g{1.0f, 10.0f, 0.0f, 1.0f};
  Pid pid;
  pid.reset(0.0f);
  // Winding in (negative) bounded at −0.1; the integral does not wind up against the bound, so
  // with the error gone the output is back at 0 at once. The feedforward is added first.
  CHECK_NEAR(pid.step(g, -5.0f, 0.0f, kDt, -0.1f, 1.0f), -0.1, 1e-7);
  for (int i = 0; i < 100; ++i) pid.step(g, -5.0f, 0.0f, kDt, -0.1f, 1.0f);
  CHECK_NEAR(pid.step(g, 0.0f, 0.0f, kDt, -0.1f, 1.0f), 0.0, 1e-6);
  // A bound narrowed for a moment leaves the integral (the load it holds) as it was.
  pid.reset(0.0f, -0.05f);
  CHECK_NEAR(pid.step(g, 0.0f, 0.0f, kDt, 0.0f, 1.0f), 0.0, 0.0);
  CHECK_NEAR(pid.step(g, 0.0f, 0.0f, kDt, -0.1f, 1.0f), -0.05, 1e-7);
  pid.reset(0.0f);
  CHECK_NEAR(pid.step(g, 0.0f, 0.0f, kDt, -0.1f, 1.0f, 0.25f), 0.25, 1e-6);
}

void proportional_lag() {
  // kp acts on the error through a first-order lag: after n periods of a unit error it gives
  // 1 − (1 − a)^n with a = dt / (lag + dt); the integral sees the error itself.
  const PidGains g{1.0f, 0.0f, 0.0f, 10.0f};
  const float lag_s = 0.04f;
  const float a = kDt / (lag_s + kDt);
  Pid pid;
  pid.reset(0.0f);
  CHECK_NEAR(pid.step(g, 1.0f, 0.0f, kDt, -10.0f, 10.0f, 0.0f, lag_s), a, 1e-6);
  float out = 0.0f;
  for (int n = 2; n <= 10; ++n) out = pid.step(g, 1.0f, 0.0f, kDt, -10.0f, 10.0f, 0.0f, lag_s);
  CHECK_NEAR(out, 1.0 - std::pow(1.0 - a, 10), 1e-5);
  // reset() starts the lag from no error (a bumpless start is at its setpoint).
  pid.reset(0.0f);
  CHECK_NEAR(pid.step(g, 1.0f, 0.0f, kDt, -10.0f, 10.0f, 0.0f, lag_s), a, 1e-6);
  const PidGains integral_only{0.0f, 10.0f, 0.0f, 10.0f};
  pid.reset(0.0f);
  CHECK_NEAR(pid.step(integral_only, 1.0f, 0.0f, kDt, -10.0f, 10.0f, 0.0f, lag_s), 0.1, 1e-6);
  // A NaN measurement does not stay in the lag.
  pid.reset(0.0f);
  pid.step(g, 1.0f, NAN, kDt, -10.0f, 10.0f, 0.0f, lag_s);
  CHECK_NEAR(pid.step(g, 0.0f, 0.0f, kDt, -10.0f, 10.0f, 0.0f, lag_s), 0.0, 1e-6);
}

void integral_lag() {
  // ki acts on the error through two first-order lags: after n periods of a unit error the
  // second gives 1 − (1 − a)^n − n·a·(1 − a)^n with a = dt / (lag + dt), and the integral sums
  // ki·dt of it; kp sees the error itself.
  const PidGains integral_only{0.0f, 10.0f, 0.0f, 10.0f};
  const float lag_s = 0.005f;
  const double a = kDt / (lag_s + kDt);
  Pid pid;
  pid.reset(0.0f);
  double expected = 0.0;
  float out = 0.0f;
  for (int n = 1; n <= 5; ++n) {
    out = pid.step(integral_only, 1.0f, 0.0f, kDt, -10.0f, 10.0f, 0.0f, 0.0f, lag_s);
    expected += 10.0 * kDt * (1.0 - std::pow(1.0 - a, n) - n * a * std::pow(1.0 - a, n));
  }
  CHECK_NEAR(out, expected, 1e-6);
  CHECK(out < 5 * 10.0f * kDt);  // less than the unlagged integral
  const PidGains proportional_only{1.0f, 0.0f, 0.0f, 10.0f};
  pid.reset(0.0f);
  CHECK_NEAR(pid.step(proportional_only, 1.0f, 0.0f, kDt, -10.0f, 10.0f, 0.0f, 0.0f, lag_s), 1.0, 1e-7);
  // reset() starts the lags from no error, and a NaN measurement does not stay in them.
  pid.reset(0.0f);
  CHECK_NEAR(pid.step(integral_only, 1.0f, 0.0f, kDt, -10.0f, 10.0f, 0.0f, 0.0f, lag_s), 10.0 * kDt * a * a, 1e-7);
  pid.reset(0.0f);
  pid.step(integral_only, 1.0f, NAN, kDt, -10.0f, 10.0f, 0.0f, 0.0f, lag_s);
  const float after_nan = pid.step(integral_only, 0.0f, 0.0f, kDt, -10.0f, 10.0f, 0.0f, 0.0f, lag_s);
  CHECK(after_nan == after_nan);
  CHECK_NEAR(pid.step(integral_only, 0.0f, 0.0f, kDt, -10.0f, 10.0f, 0.0f, 0.0f, lag_s), after_nan, 1e-7);
}

}  // namespace

void test_pid() {
  proportional_and_output_clamp();
  integrator_clamp_prevents_windup();
  a_step_asking_beyond_lowest_says_so();
  derivative_on_measurement();
  step_response_settles();
  huge_gains_never_give_nan();
  asymmetric_clamp_and_feedforward();
  proportional_lag();
  integral_lag();
}
