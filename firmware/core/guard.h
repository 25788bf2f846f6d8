// The last stage before the H-bridges, which holds whatever the PIDs ask (firmware/PROTOCOL.md,
// "Tension bound"):
//   * a motor winds in with at most kPullForceFraction of the tension limit as stall force, so
//     no duty can hold a tendon above the limit, and ever less of it as its spool approaches
//     the winding speed limit, which it so cannot pass: the rotor never carries the energy to
//     jerk a tendon over the limit when the tendon snaps taut;
//   * a motor that stops driving (disabled, fault) brakes until its spool stays still in the
//     brake, and only then coasts, so that stored energy, the rotor's or the rod's, goes into
//     the brake and not into a tendon;
//   * a motor that has pulled with all it may against a still spool for kAtCapUs trips the
//     tension limit, as the motor's pull measures it (a stalled spool's tendon carries the
//     motor's pull, whatever its load cell says): the target cannot be reached within the limit;
//   * a load cell reading far less than its stalled motor pulls is reported implausible.
// Spool speeds come from the encoders, over windows of kSpeedWindowUs.
#pragma once

#include <cstddef>
#include <cstdint>

#include "config.h"
#include "messages.h"

namespace twinfw {

// Which channels have held a condition without a break for a duration.
class Lasting {
 public:
  // `holding` (bit i: channel i holds it now) at `now_us`; returns the channels that have held
  // it for `duration_us` or more.
  ChannelMask update(uint64_t now_us, ChannelMask holding, uint32_t duration_us);

 private:
  ChannelMask holding_ = 0;
  uint64_t since_us_[kMaxChannels] = {};
};

class Guard {
 public:
  // The guard of `channels` motors (1..kMaxChannels) whose encoders count `tendon_m_per_count`
  // of tendon each.
  explicit Guard(size_t channels = kDefaultChannels, float tendon_m_per_count = kTendonMPerCount);

  // The tension limit (N) the pull and speed limits derive from.
  void set_tension_limit(float tension_limit_n);
  // The motors at the tendons (SET_MOTORS): stall force (N), no-load speed (m/s) and reflected
  // rotor mass (kg), which the duty of a pull, the back-EMF damping, the blow of a tendon
  // snapping taut and the brake's settling time derive from.
  void set_motors(float stall_force_n, float no_load_speed_m_per_s, float reflected_mass_kg);
  float stall_force_n() const { return stall_force_n_; }
  // Back-EMF damping of a motor at the tendon (N·s/m): stall force over no-load speed.
  float damping_ns_per_m() const { return damping_ns_per_m_; }
  // How long a braked spool must stay still before its motor coasts (µs).
  uint32_t still_us() const { return still_us_; }
  // Largest duty a motor may wind in with, at rest (a positive number).
  float pull_limit() const { return cap_n_ / stall_force_n_; }
  // Fastest a spool may wind in its tendon from slack (m/s).
  float winding_speed_limit() const { return speed_limit_m_s_; }
  // Fastest spool `channel` may wind in now (m/s): kTautSpeedFactor times more while its tendon
  // reads taut.
  float winding_speed_limit(size_t channel) const;

  // What the sensors say at device time `now_us`, every tick: encoder counts, tensions (N) and
  // which load cells are stale (bit i).
  void observe(uint64_t now_us, const int32_t* counts, const float* tensions_n, ChannelMask stale_mask);
  // Spool speed (m/s, positive = winding in) over the last window.
  float winding_speed_m_s(size_t channel) const { return winding_speed_m_s_[channel]; }

  // Lowest duty motor `channel` may have now (winding in is negative), from its spool's speed:
  // positive for a spool paying out so fast that the back-EMF alone would brake it with more
  // than the cap.
  float lowest_duty(size_t channel) const;
  // Motors driven with `command`, each clamped to [lowest_duty(i), 1] (NaN gives 0, or
  // lowest_duty(i) where that is positive).
  void drive(const float* command, float* duty, Drive* drive);
  // All motors brake, holding their spools: shorted, or where that would resist a spool flying
  // out with more than the cap, driven at lowest_duty(i).
  void hold(float* duty, Drive* drive);
  // Motors let go: each brakes as hold() does until its spool has stayed still
  // (kStillSpeedMPerS) in the brake for kStillUs, then coasts until it drives again.
  void release(float* duty, Drive* drive);

  // The drives a tick gave the motors: what they have until the next tick.
  void applied(const Drive* drive);

  // Fault flags (with their channel bits) of what `duty` and `drive`, the outputs the motors had
  // since the last tick, did to still spools: TENSION_LIMIT for a motor at its cap, or whose
  // loop asks for more than the lowest duty it may have (`beyond_lowest`, bit i: its PID stops
  // its integral up to one increment short of the cap, which the at-cap fraction cannot tell
  // from a pull that holds), for kAtCapUs; LOADCELL_IMPLAUSIBLE for a fresh tension implausibly
  // low against a motor's pull for kImplausibleUs. 0 when none.
  uint32_t faults(uint64_t now_us, const float* duty, const Drive* drive, ChannelMask beyond_lowest = 0);

 private:
  float pull_n(size_t channel, float duty) const;
  void brake(size_t channel, float* duty, Drive* drive);

  size_t channels_;
  float tendon_m_per_count_;
  float tension_limit_n_ = kDefaultTensionLimitN;
  float stall_force_n_ = kDefaultStallForceN;
  float damping_ns_per_m_ = kDefaultMotorDampingNsPerM;
  float blow_impedance_ns_per_m_ = kBlowImpedanceNsPerM;
  uint32_t still_us_ = kStillUs;
  float cap_n_ = 0.0f;           // largest pull of a motor on its tendon (N)
  float speed_limit_m_s_ = 0.0f;
  bool measured_ = false;
  uint64_t window_start_us_ = 0;
  int32_t window_counts_[kMaxChannels] = {};
  float winding_speed_m_s_[kMaxChannels] = {};
  float driven_speed_m_s_[kMaxChannels] = {};  // the speed the last outputs were bounded with
  float tensions_n_[kMaxChannels] = {};
  ChannelMask stale_mask_ = 0;
  bool stopping_[kMaxChannels] = {};  // let go since driving: brakes until still in the brake
  bool braked_[kMaxChannels] = {};    // the last tick gave the motor the brake
  ChannelMask still_in_brake_ = 0;    // channels whose spools have stayed still in the brake for kStillUs
  Lasting braked_still_;
  Lasting implausible_;
  Lasting at_cap_;
};

}  // namespace twinfw
