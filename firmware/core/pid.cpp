#include "pid.h"

namespace twinfw {

void Pid::reset(float measurement, float output) {
  integral_ = output;
  last_measurement_ = measurement;
  // A bumpless start is one at its setpoint: the lags start from no error.
  lagged_error_ = 0.0f;
  integral_lags_[0] = integral_lags_[1] = 0.0f;
  below_lowest_ = false;
}

// The integral stays within the output limit; and it does not grow further while the output is
// held at `lowest` or `highest` in the same direction (conditional integration), so that a range
// narrowed for a moment neither winds it up nor wipes out the load it holds.
float Pid::step(const PidGains& gains, float setpoint, float measurement, float dt_s, float lowest, float highest,
               float feedforward, float proportional_lag_s, float integral_lag_s) {
  const float error = setpoint - measurement;
  if (proportional_lag_s > 0.0f) {
    const float lag = dt_s / (proportional_lag_s + dt_s);
    lagged_error_ = clamp_range(lagged_error_ + lag * (error - lagged_error_), -3.0e38f, 3.0e38f);
  } else {
    lagged_error_ = error;  // exactly: x + (e − x) need not round to e
  }
  const float derivative = -gains.kd * (measurement - last_measurement_) / dt_s;
  last_measurement_ = measurement;
  float integrated = error;
  if (integral_lag_s > 0.0f) {
    const float lag = dt_s / (integral_lag_s + dt_s);
    integral_lags_[0] = clamp_range(integral_lags_[0] + lag * (error - integral_lags_[0]), -3.0e38f, 3.0e38f);
    integral_lags_[1] = clamp_range(integral_lags_[1] + lag * (integral_lags_[0] - integral_lags_[1]), -3.0e38f, 3.0e38f);
    integrated = integral_lags_[1];
  }
  const float increment = gains.ki * integrated * dt_s;
  const float rest = gains.kp * lagged_error_ + derivative + feedforward;
  const float unclamped = rest + integral_ + increment;
  below_lowest_ = unclamped < lowest;
  const bool held = (unclamped < lowest && increment < 0.0f) || (unclamped > highest && increment > 0.0f);
  if (!held) integral_ = clamp_range(integral_ + increment, -gains.output_limit, gains.output_limit);
  return clamp_range(rest + integral_, lowest, highest);
}

}  // namespace twinfw
