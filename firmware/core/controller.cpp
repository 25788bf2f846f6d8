#include "controller.h"

namespace twinfw {

namespace {

// Defaults, to be tuned on the rig. Lengths: the motor makes the plant an integrator of
// ~0.5 m/s of tendon per unit duty (1321 rpm is the gearbox output speed, on a 3.25 mm spool);
// kp = 60 /m (1 mm of error gives 0.06 duty) and ki = 100 /(m s) track a 2 mm step to ~20 um
// within a second on the twin without exciting the stiff tendon, and the integral is there
// for friction. Tension: through a practically inextensible tendon the stalled motor is a force
// source, ~154 N of tension at full duty (24 V / 7.33 ohm x 0.153 N m/A over r = 3.25 mm), so
// the loop gain is kp x 154 N: kp = 0.003 /N keeps it at 0.46, ki = 0.3 /(N s) removes the error
// in ~0.2 s, and the 0.2 duty clamp bounds a runaway at ~30 N. (0.2 /N gave 30x that gain and
// tripped the tension limit within one control period on the twin.)
constexpr PidGains kDefaultLengthGains{60.0f, 100.0f, 0.0f, 1.0f};
constexpr PidGains kDefaultTensionGains{0.003f, 0.3f, 0.0f, 0.2f};

}  // namespace

Controller::Controller(size_t channels)
    : channels_(channels < 1 ? 1 : (channels > kMaxChannels ? kMaxChannels : channels)),
      gains_{kDefaultLengthGains, kDefaultLengthGains, kDefaultTensionGains} {}

void Controller::use_default_gains(float stall_force_n) {
  const float s = kDefaultStallForceN / stall_force_n;
  const PidGains length{kDefaultLengthGains.kp * s, kDefaultLengthGains.ki * s, kDefaultLengthGains.kd * s,
                        kDefaultLengthGains.output_limit};
  const float clamp = kDefaultTensionGains.output_limit * s;
  const PidGains tension{kDefaultTensionGains.kp * s, kDefaultTensionGains.ki * s, kDefaultTensionGains.kd * s,
                         clamp < 1.0f ? clamp : 1.0f};
  gains_[static_cast<size_t>(Mode::kLengths)] = length;
  gains_[static_cast<size_t>(Mode::kPairs)] = length;
  gains_[static_cast<size_t>(Mode::kTension)] = tension;
}

void Controller::set_mode(Mode mode, const Measurements& now, float tension_limit_n) {
  float duty[kMaxChannels];
  for (size_t i = 0; i < channels_; ++i) duty[i] = last_duty_[i];
  mode_ = mode;
  hold(now, tension_limit_n);
  for (size_t i = 0; i < channels_; ++i) {
    pid_[i].reset(measured(now, i), duty[i]);
    last_duty_[i] = duty[i];
  }
  beyond_lowest_ = 0;
}

void Controller::hold(const Measurements& now, float tension_limit_n) {
  switch (mode_) {
    case Mode::kLengths:
      for (size_t i = 0; i < channels_; ++i) setpoints_[i] = now.lengths_m[i];
      break;
    case Mode::kPairs:
      // Pair k couples motor k with motor k + channels / 2, the tendon opposite it: tendons 1
      // and 3, 2 and 4 of four. An odd count has no pairs (SET_MODE refuses the mode).
      for (size_t k = 0; k < channels_ / 2; ++k) {
        const size_t opposite = k + channels_ / 2;
        const float a = now.lengths_m[k];
        const float b = now.lengths_m[opposite];
        pair_centres_m_[k] = 0.5f * (a + b);
        setpoints_[k] = 0.5f * (a - b);
        setpoints_[opposite] = 0.0f;
      }
      break;
    case Mode::kTension:
      for (size_t i = 0; i < channels_; ++i) {
        setpoints_[i] = clamp_range(now.tensions_n[i], 0.0f, tension_limit_n);
      }
      break;
  }
  update_targets();
  restart(now);
}

void Controller::restart(const Measurements& now) {
  for (size_t i = 0; i < channels_; ++i) {
    pid_[i].reset(measured(now, i));
    last_duty_[i] = 0.0f;
    beyond_lowest_ = 0;
    references_[i] = mode_ == Mode::kTension ? now.tensions_n[i] : now.lengths_m[i];
    last_length_m_[i] = now.lengths_m[i];
    speed_m_s_[i] = steady_m_s_[i] = 0.0f;
  }
}

void Controller::set_setpoints(const float* values) {
  for (size_t i = 0; i < channels_; ++i) setpoints_[i] = values[i];
  update_targets();
}

void Controller::step(const Measurements& now, float dt_s, float* duty) {
  const float limit = gains(mode_).output_limit;
  float lowest[kMaxChannels];
  for (float& l : lowest) l = -limit;
  step(now, dt_s, lowest, duty);
}

void Controller::step(const Measurements& now, float dt_s, const float* lowest, float* duty) {
  const PidGains& g = gains(mode_);
  const float ramp_m = length_rate_m_s_ * dt_s;
  const float ramp_n = tension_rate_n_per_s_ * dt_s;
  for (size_t i = 0; i < channels_; ++i) {
    float& reference = references_[i];
    // A ramping length is fed forward as the duty its speed takes an unloaded motor, so that the
    // integral holds only the load and has nothing to unwind when the ramp ends.
    float feedforward = 0.0f;
    float tracked = reference;
    // The speeds are clamped to the no-load speed, which no spool exceeds: no NaN or overflow
    // from a length jump (a restart's) reaches a reference.
    const float speed_m_s = clamp_range((now.lengths_m[i] - last_length_m_[i]) / dt_s, -no_load_speed_m_per_s_, no_load_speed_m_per_s_);
    last_length_m_[i] = now.lengths_m[i];
    speed_m_s_[i] += dt_s / (kTensionDampingLagS + dt_s) * (speed_m_s - speed_m_s_[i]);
    steady_m_s_[i] += dt_s / (kTensionDampingWashoutS + dt_s) * (speed_m_s - steady_m_s_[i]);
    if (mode_ == Mode::kTension) {
      reference += clamp_range(targets_[i] - reference, -ramp_n, ramp_n);
      tracked = reference;
      // Only a taut tendon is damped: a slack one's spool is free, and on a free spool the
      // damping would be a velocity loop through the speed's lag, five times the motor's own.
      if (tension_damping_ns_per_m_ > 0.0f && now.tensions_n[i] > kTautFraction * tension_limit_n_) {
        const float swinging_m_s = speed_m_s_[i] - steady_m_s_[i];
        tracked = clamp_range(reference + tension_damping_ns_per_m_ * swinging_m_s, 0.0f, tension_limit_n_);
      }
    } else {
      // Nor does it run ahead of a tendon that cannot follow (a motor at its pull limit): the
      // error stays small, and so does the overshoot when the tendon catches up.
      const float lead_m = reference - now.lengths_m[i];
      const float most_m = clamp_range(kMaxLengthLeadM - lead_m, 0.0f, ramp_m);
      const float least_m = -clamp_range(kMaxLengthLeadM + lead_m, 0.0f, ramp_m);
      const float move_m = clamp_range(targets_[i] - reference, least_m, most_m);
      reference += move_m;
      tracked = reference;
      feedforward = move_m / dt_s / no_load_speed_m_per_s_;
    }
    // In tension mode the loop runs on −tension: paying out (positive duty) lowers tension.
    const float sign = mode_ == Mode::kTension ? -1.0f : 1.0f;
    const float low = clamp_range(lowest[i], -g.output_limit, g.output_limit);
    const bool tension = mode_ == Mode::kTension;
    duty[i] = pid_[i].step(g, sign * tracked, measured(now, i), dt_s, low, g.output_limit, feedforward,
                           tension ? kTensionProportionalLagS : 0.0f, tension ? kTensionIntegralLagS : 0.0f);
    last_duty_[i] = duty[i];
    const ChannelMask bit = static_cast<ChannelMask>(1u << i);
    const bool beyond = pid_[i].below_lowest() && low == lowest[i];
    beyond_lowest_ = static_cast<ChannelMask>(beyond ? (beyond_lowest_ | bit) : (beyond_lowest_ & ~bit));
  }
}

float Controller::measured(const Measurements& now, size_t channel) const {
  return mode_ == Mode::kTension ? -now.tensions_n[channel] : now.lengths_m[channel];
}

void Controller::update_targets() {
  if (mode_ == Mode::kPairs) {
    for (size_t k = 0; k < channels_ / 2; ++k) {
      targets_[k] = pair_centres_m_[k] + setpoints_[k];
      targets_[k + channels_ / 2] = pair_centres_m_[k] - setpoints_[k];
    }
    return;
  }
  for (size_t i = 0; i < channels_; ++i) targets_[i] = setpoints_[i];
}

}  // namespace twinfw
