#include "pid.h"

namespace twinfw {

namespace {
float clamp(float x, float limit) { return x > limit ? limit : (x < -limit ? -limit : x); }
}  // namespace

void Pid::reset(float measurement, float output) {
  integral_ = output;
  last_measurement_ = measurement;
}

float Pid::step(const PidGains& gains, float setpoint, float measurement, float dt_s) {
  const float error = setpoint - measurement;
  integral_ = clamp(integral_ + gains.ki * error * dt_s, gains.output_limit);
  const float derivative = -gains.kd * (measurement - last_measurement_) / dt_s;
  last_measurement_ = measurement;
  return clamp(gains.kp * error + integral_ + derivative, gains.output_limit);
}

}  // namespace twinfw
