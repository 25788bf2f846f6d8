// The three control modes over one PID per motor (thesis §4, §10.2):
//   lengths — each motor tracks its own tendon length setpoint (m);
//   pairs   — antagonistic pairs (k, k + N/2) of an even count N, (1,3) and (2,4) on four
//             tendons: a pair setpoint d (m) drives the first tendon to c + d and the second to
//             c − d, so one shortens by what the other pays out; c is the pair's mean length
//             when the mode was entered;
//   tension — each motor tracks a tension setpoint (N) on its calibrated load cell.
// Positive duty pays tendon out: it lengthens the tendon and lowers its tension.
// In the length modes each PID tracks a reference that moves towards its target at no more than
// length_rate(), so a step is driven as a ramp, its speed fed forward: no spool is jerked, and
// no tendon paid out so fast that it goes slack and snaps taut again when the rod moves. In
// tension mode the references move at no more than tension_rate(): a motor's pull rises no
// faster than the spool of the tendon it pulls against, held at its cap, can yield; a taut
// tendon's can be raised by a damping times its swinging speed (kTensionDampingNsPerM) within
// [0, tension limit] (kTensionDampingNsPerM, off by default); the proportional term acts through
// a lag (kTensionProportionalLagS), the integral term through two (kTensionIntegralLagS):
// config.h says what each was measured to do.
#pragma once

#include <cstddef>

#include "config.h"
#include "messages.h"
#include "pid.h"

namespace twinfw {

struct Measurements {
  float lengths_m[kMaxChannels];
  float tensions_n[kMaxChannels];
};

// Whether `channels` tendons form antagonistic pairs (k, k + channels / 2): an even count.
constexpr bool pairs_possible(size_t channels) { return channels >= 2 && channels % 2 == 0; }

class Controller {
 public:
  // PIDs for `channels` motors (1..kMaxChannels).
  explicit Controller(size_t channels = kDefaultChannels);

  size_t channels() const { return channels_; }

  Mode mode() const { return mode_; }
  const PidGains& gains(Mode mode) const { return gains_[static_cast<size_t>(mode)]; }
  void set_gains(Mode mode, const PidGains& gains) { gains_[static_cast<size_t>(mode)] = gains; }
  // Every mode back to its default gains, made for motors of `stall_force_n` (N at the tendon):
  // the defaults are the thesis motor's (154 N), in duty per m or per N, so another motor gets
  // them scaled by 154 N over its own stall force (and the tension clamp likewise, up to full
  // duty): the same pull per unit of error, the same bound on a runaway's pull.
  void use_default_gains(float stall_force_n);

  // Fastest the length references move (m/s).
  float length_rate() const { return length_rate_m_s_; }
  void set_length_rate(float length_rate_m_s) { length_rate_m_s_ = length_rate_m_s; }
  // Fastest the tension references move (N/s).
  // Tendon speed of an unloaded motor at full duty (m/s): a ramp's speed is fed forward as the
  // duty it takes.
  void set_no_load_speed(float no_load_speed_m_per_s) { no_load_speed_m_per_s_ = no_load_speed_m_per_s; }
  float tension_rate() const { return tension_rate_n_per_s_; }
  void set_tension_rate(float tension_rate_n_per_s) { tension_rate_n_per_s_ = tension_rate_n_per_s; }
  // Highest tension reference (N) the damping may raise a reference to: the tension limit.
  void set_tension_limit(float tension_limit_n) { tension_limit_n_ = tension_limit_n; }
  // Tendon damping of tension mode (N·s/m; kTensionDampingNsPerM by default, 0 = off).
  void set_tension_damping(float ns_per_m) { tension_damping_ns_per_m_ = ns_per_m; }

  // Switches mode and holds (see hold()), with each PID's integral starting at the duty of the
  // last step, so the motors keep pulling as they were instead of letting go: entering tension
  // mode from a length-held bend under load no longer kicks the tip by millimetres.
  void set_mode(Mode mode, const Measurements& now, float tension_limit_n);

  // Bumpless start: setpoints := the current measurement (tensions clamped to
  // [0, tension_limit_n]), PIDs restart from it. The rig holds still until new setpoints arrive.
  void hold(const Measurements& now, float tension_limit_n);

  // Restarts the PIDs from the current measurement and a stopped motor, keeping the setpoints
  // (motion resumes after a pause without a derivative kick, the references ramping from where
  // the tendons are).
  void restart(const Measurements& now);

  // Setpoints in the active mode's units (validated by the caller), one per channel; pairs use
  // the first channels() / 2.
  void set_setpoints(const float* values);

  // One control period: writes duty[channels()] in [−limit, limit].
  void step(const Measurements& now, float dt_s, float* duty);
  // The same with motor i's duty, and its PID's integral, no lower than lowest[i] (within the
  // mode's output limit): what the motor can be given (Guard::lowest_duty), so that no integral
  // winds up against it.
  void step(const Measurements& now, float dt_s, const float* lowest, float* duty);

  // Motors (bit i) whose PIDs' last step asked for a duty below the `lowest` it was given: more
  // pull than the motor may give, which it gives within one integral increment. Not where the
  // mode's output limit, tighter than `lowest`, held the PID: that is no pull at the guard's bound.
  ChannelMask beyond_lowest() const { return beyond_lowest_; }

  // Per-motor target of the last setpoints or hold: m (length modes) or N (tension).
  const float* targets() const { return targets_; }

  // What each PID tracks now: the ramped length (m) or tension (N).
  const float* references() const { return references_; }

 private:
  float measured(const Measurements& now, size_t channel) const;
  void update_targets();

  size_t channels_;
  Mode mode_ = Mode::kLengths;
  PidGains gains_[kModes];
  Pid pid_[kMaxChannels];
  float setpoints_[kMaxChannels] = {};
  float pair_centres_m_[kMaxChannels / 2] = {};
  float targets_[kMaxChannels] = {};
  float references_[kMaxChannels] = {};
  float length_rate_m_s_ = kMaxLengthRateMPerS;
  float tension_rate_n_per_s_ = kTensionRatePerS * kDefaultTensionLimitN;
  float no_load_speed_m_per_s_ = kDefaultNoLoadSpeedMPerS;
  float last_duty_[kMaxChannels] = {};  // duty of the last step; 0 after restart()
  ChannelMask beyond_lowest_ = 0;
  float last_length_m_[kMaxChannels] = {};  // tendon length at the last step
  float speed_m_s_[kMaxChannels] = {};      // tendon speed (m/s, paying out > 0) through kTensionDampingLagS
  float steady_m_s_[kMaxChannels] = {};     // ... and through kTensionDampingWashoutS
  float tension_limit_n_ = kDefaultTensionLimitN;
  float tension_damping_ns_per_m_ = kTensionDampingNsPerM;
};

}  // namespace twinfw
