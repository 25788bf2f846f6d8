// PID after Beauregard's Arduino PID: fixed sample time, derivative on measurement (no kick
// when the setpoint steps), integral kept in output units and clamped to the output limit
// (no windup, and a change of ki does not bump the output), output clamped. The proportional
// term may act on the error through a first-order lag, and the integral term through two (the
// tension loop's, see controller.h).
#pragma once

namespace twinfw {

struct PidGains {
  float kp;            // output per unit of error
  float ki;            // output per unit of error per second
  float kd;            // output per unit of measurement rate (unit·s)
  float output_limit;  // |output| and |integral| bound, > 0
};

// `x` limited to [lowest, highest] (lowest ≤ 0 ≤ highest); NaN gives 0, so that no NaN, from
// whatever arithmetic, reaches an integral or a motor.
inline float clamp_range(float x, float lowest, float highest) {
  if (x > highest) return highest;
  if (x < lowest) return lowest;
  return x == x ? x : 0.0f;
}

class Pid {
 public:
  // Bumpless start: the integral restarts at `output`, the output the motor had (0 when it was
  // stopped), so with zero error the first step gives it again; the derivative restarts from
  // `measurement` instead of differencing against a stale value.
  void reset(float measurement, float output = 0.0f);

  // One period with output and integral in [−output_limit, output_limit].
  float step(const PidGains& gains, float setpoint, float measurement, float dt_s) {
    return step(gains, setpoint, measurement, dt_s, -gains.output_limit, gains.output_limit);
  }

  // One period with the output in [lowest, highest] (lowest ≤ highest, within the output limit;
  // a NaN output gives 0), the integral not growing past either; `feedforward` is added to the output before it is clamped.
  // `proportional_lag_s` > 0: kp acts on the error low-passed with that time constant (s);
  // `integral_lag_s` > 0: ki on the error through two first-order lags of that time constant (s)
  // each; 0: on the error itself.
  float step(const PidGains& gains, float setpoint, float measurement, float dt_s, float lowest, float highest,
             float feedforward = 0.0f, float proportional_lag_s = 0.0f, float integral_lag_s = 0.0f);

  // The last step asked for less than its `lowest` (integral included): its output is held at
  // that bound or, the integral stopped, up to one integral increment short of it.
  bool below_lowest() const { return below_lowest_; }

 private:
  float integral_ = 0.0f;
  float lagged_error_ = 0.0f;  // the error through the proportional lag
  float integral_lags_[2] = {0.0f, 0.0f};  // the error through the integral's first lag, and its second
  float last_measurement_ = 0.0f;
  bool below_lowest_ = false;
};

}  // namespace twinfw
