#include "guard.h"

#include <cmath>

#include "pid.h"

namespace twinfw {

namespace {
bool still(float speed_m_s, float threshold_m_s) { return speed_m_s <= threshold_m_s && speed_m_s >= -threshold_m_s; }
}  // namespace

Guard::Guard(size_t channels, float tendon_m_per_count)
    : channels_(channels < 1 ? 1 : (channels > kMaxChannels ? kMaxChannels : channels)),
      tendon_m_per_count_(tendon_m_per_count) {
  set_tension_limit(kDefaultTensionLimitN);
}

void Guard::set_tension_limit(float tension_limit_n) {
  tension_limit_n_ = tension_limit_n;
  cap_n_ = kPullForceFraction * tension_limit_n;
  // The blow a spool winding in at w deals when its tendon snaps taut lands on the tendons
  // already taut, at most at the cap: the speed that keeps them under the bound.
  speed_limit_m_s_ = (kBlowBoundFraction - kPullForceFraction) * tension_limit_n / blow_impedance_ns_per_m_;
}

void Guard::set_motors(float stall_force_n, float no_load_speed_m_per_s, float reflected_mass_kg) {
  stall_force_n_ = stall_force_n;
  damping_ns_per_m_ = stall_force_n / no_load_speed_m_per_s;
  // The blow's impedance √(k m) scales with the root of the rotor's mass at the tendon.
  blow_impedance_ns_per_m_ = kBlowImpedanceNsPerM * std::sqrt(reflected_mass_kg / kDefaultReflectedMassKg);
  // Twice the brake's time constant (reflected mass over back-EMF damping), at least kStillUs.
  const float settle_us = 2.0f * reflected_mass_kg / damping_ns_per_m_ * 1e6f;
  still_us_ = settle_us > static_cast<float>(kStillUs) ? static_cast<uint32_t>(settle_us) : kStillUs;
  set_tension_limit(tension_limit_n_);
}

void Guard::observe(uint64_t now_us, const int32_t* counts, const float* tensions_n, ChannelMask stale_mask) {
  for (size_t i = 0; i < channels_; ++i) tensions_n_[i] = tensions_n[i];
  stale_mask_ = stale_mask;
  if (measured_ && now_us - window_start_us_ < kSpeedWindowUs) return;
  const float window_s = static_cast<float>(now_us - window_start_us_) * 1e-6f;
  for (size_t i = 0; i < channels_; ++i) {
    // Positive counts pay out: winding in counts down.
    const float moved_m = static_cast<float>(static_cast<int64_t>(window_counts_[i]) - counts[i]) * tendon_m_per_count_;
    winding_speed_m_s_[i] = measured_ ? moved_m / window_s : 0.0f;
    window_counts_[i] = counts[i];
  }
  window_start_us_ = now_us;
  measured_ = true;
  ChannelMask still_braked = 0;
  for (size_t i = 0; i < channels_; ++i) {
    if (braked_[i] && still(winding_speed_m_s_[i], kStillSpeedMPerS)) still_braked = static_cast<ChannelMask>(still_braked | (1u << i));
  }
  still_in_brake_ = braked_still_.update(now_us, still_braked, still_us_);
}

// A tendon that reads taut has no slack to be taken up with a blow: its spool may wind faster.
float Guard::winding_speed_limit(size_t i) const {
  const bool taut = !(stale_mask_ & (1u << i)) && tensions_n_[i] > kTautFraction * cap_n_;
  return taut ? kTautSpeedFactor * speed_limit_m_s_ : speed_limit_m_s_;
}

// Lowest duty motor i may have now: the most negative, as winding in is negative. At rest the
// cap; winding in at w, a pull falling linearly to what only balances the back-EMF damping at
// the speed limit, so that the spool cannot accelerate past the limit and any tension slows it.
// Paying out at w, the back-EMF brakes the spool with 300 N·s/m × w on top of the duty's pull:
// that much less pull, down to paying out with the spool beyond cap / 300 N·s/m, so that a
// motor never resists its tendon with more than the cap either, be it yielding to a load or
// taking up a spool that flies out.
float Guard::lowest_duty(size_t i) const {
  const float w = winding_speed_m_s_[i];
  const float limit = winding_speed_limit(i);
  const float pull_n = clamp_range(cap_n_ * (1.0f - w / limit) + damping_ns_per_m_ * limit, 0.0f, cap_n_);
  const float back_emf_n = w < 0.0f ? -damping_ns_per_m_ * w : 0.0f;
  const float lowest = (back_emf_n - pull_n) / stall_force_n_;
  return lowest < 1.0f ? lowest : 1.0f;
}

// What a still spool's motor pulls its tendon with (N) at `duty`: the duty's stall force, and
// the back-EMF braking a spool that creeps out at the speed the duty was bounded with (the
// speed measured since differs by an encoder count or two, which at the cap is a few times
// the at-cap margin).
float Guard::pull_n(size_t i, float duty) const {
  const float w = driven_speed_m_s_[i];
  return -duty * stall_force_n_ - (w < 0.0f ? damping_ns_per_m_ * w : 0.0f);
}

void Guard::drive(const float* command, float* duty, Drive* drive) {
  for (size_t i = 0; i < channels_; ++i) {
    const float lowest = lowest_duty(i);
    const float d = clamp_range(command[i], lowest, 1.0f);
    duty[i] = d < lowest ? lowest : d;  // NaN gives 0, which may brake harder than the cap
    drive[i] = Drive::kDrive;
    driven_speed_m_s_[i] = winding_speed_m_s_[i];
    stopping_[i] = true;
  }
}

void Guard::brake(size_t i, float* duty, Drive* drive) {
  const float lowest = lowest_duty(i);
  driven_speed_m_s_[i] = winding_speed_m_s_[i];
  duty[i] = lowest > 0.0f ? lowest : 0.0f;
  drive[i] = lowest > 0.0f ? Drive::kDrive : Drive::kBrake;
}

void Guard::hold(float* duty, Drive* drive) {
  for (size_t i = 0; i < channels_; ++i) {
    brake(i, duty, drive);
    stopping_[i] = true;
  }
}

// A spool that stays still while braked has nothing left to give: no rotor energy, and no
// tendon pulling it out through the brake (that would turn it at tension / 300 N·s/m). One
// window is not enough: a spool the brake turns round, from winding in to being pulled out,
// passes through still on the way.
void Guard::release(float* duty, Drive* drive) {
  for (size_t i = 0; i < channels_; ++i) {
    if (stopping_[i] && (still_in_brake_ & (1u << i))) stopping_[i] = false;
    if (stopping_[i]) {
      brake(i, duty, drive);
    } else {
      duty[i] = 0.0f;
      drive[i] = Drive::kCoast;
    }
  }
}

void Guard::applied(const Drive* drive) {
  for (size_t i = 0; i < channels_; ++i) braked_[i] = drive[i] == Drive::kBrake;
}

ChannelMask Lasting::update(uint64_t now_us, ChannelMask holding, uint32_t duration_us) {
  ChannelMask lasted = 0;
  for (size_t i = 0; i < kMaxChannels; ++i) {
    const ChannelMask bit = static_cast<ChannelMask>(1u << i);
    if (!(holding & bit)) continue;
    if (!(holding_ & bit)) since_us_[i] = now_us;
    if (now_us - since_us_[i] >= duration_us) lasted = static_cast<ChannelMask>(lasted | bit);
  }
  holding_ = holding;
  return lasted;
}

uint32_t Guard::faults(uint64_t now_us, const float* duty, const Drive* drive, ChannelMask beyond_lowest) {
  ChannelMask low = 0;
  ChannelMask at_cap = 0;
  for (size_t i = 0; i < channels_; ++i) {
    if (drive[i] != Drive::kDrive || !still(winding_speed_m_s_[i], kStillSpeedMPerS)) continue;
    const ChannelMask bit = static_cast<ChannelMask>(1u << i);
    const float pull = pull_n(i, duty[i]);
    const bool fresh = !(stale_mask_ & bit);
    // A spool winding in, even too slowly to count as moving, loses damping × speed of its pull
    // to back-EMF: a slack tendon taken up at 0.9 mm/s by a motor of 1200 N·s/m pulls 1 N less
    // than its duty says, and its cell rightly reads nothing. The tension limit's at-cap check
    // keeps the gross pull, which errs towards tripping.
    const float w = driven_speed_m_s_[i];
    const float net = w > 0.0f ? pull - damping_ns_per_m_ * w : pull;
    if (fresh && net >= kPlausibleMinForceN && tensions_n_[i] < kPlausibleFraction * net - kPlausibleMarginN) {
      low = static_cast<ChannelMask>(low | bit);
    }
    if (pull >= kAtCapFraction * cap_n_ || (beyond_lowest & bit)) at_cap = static_cast<ChannelMask>(at_cap | bit);
  }
  const ChannelMask implausible = implausible_.update(now_us, low, kImplausibleUs);
  const ChannelMask over = at_cap_.update(now_us, at_cap, kAtCapUs);
  uint32_t flags = 0;
  for (size_t i = 0; i < channels_; ++i) {
    if (implausible & (1u << i)) flags |= fault::kLoadcellImplausible | fault::implausible_channel(i);
    if (over & (1u << i)) flags |= fault::kTensionLimit | fault::tension_channel(i);
  }
  return flags;
}

}  // namespace twinfw
