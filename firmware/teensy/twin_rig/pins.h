// Teensy 3.5 pin map of the rig (firmware/README.md has it as a table), for up to eight motors.
// The thesis does not give its wiring: these are a choice. Every Teensy 3.5 digital pin can
// interrupt, so all encoder channels get full 4× decoding; both inputs of each DRV8871 are on
// PWM pins (the Teensy 3.5's twenty: 2–10, 14, 20–23, 29, 30, 35–38). Motors 1–4 keep the
// pins of the four-tendon rig. Pins 40 and up are the pads on the board's underside; 13 (the
// LED) is left free.
#pragma once

#include <stddef.h>
#include <stdint.h>

namespace pins {

// Motors the rig has wired and the firmware drives: the thesis endoscope's four tendons
// (models/endoscope/endoscope.toml, tendons.count). A rig with more sets it here, up to kMotors.
constexpr size_t kRigChannels = 4;
// Motors this map has pins for: eight, as many as the Teensy 3.5's twenty PWM pins give two
// each with room to spare.
constexpr size_t kMotors = 8;

// DRV8871 inputs: IN1 high drives forward (pays tendon out, counts up), IN2 high reverse.
constexpr uint8_t kMotorIn1[kMotors] = {2, 4, 6, 8, 10, 23, 35, 37};
constexpr uint8_t kMotorIn2[kMotors] = {3, 5, 7, 9, 14, 29, 36, 38};

// Quadrature encoder A/B. If a motor counts down while paying out, swap its A and B.
constexpr uint8_t kEncoderA[kMotors] = {24, 26, 28, 31, 0, 11, 33, 39};
constexpr uint8_t kEncoderB[kMotors] = {25, 27, 30, 32, 1, 12, 34, 40};

// HX711 data out and clock, one pair per load cell (a shared clock would read all at once).
constexpr uint8_t kLoadcellDout[kMotors] = {15, 17, 19, 21, 41, 43, 45, 47};
constexpr uint8_t kLoadcellSck[kMotors] = {16, 18, 20, 22, 42, 44, 46, 48};

namespace detail {
constexpr const uint8_t* kTables[] = {kMotorIn1, kMotorIn2, kEncoderA, kEncoderB, kLoadcellDout, kLoadcellSck};
constexpr size_t kPinCount = sizeof kTables / sizeof kTables[0] * kMotors;
constexpr uint8_t pin(size_t k) { return kTables[k / kMotors][k % kMotors]; }
constexpr bool all_distinct() {
  for (size_t a = 0; a < kPinCount; ++a) {
    for (size_t b = a + 1; b < kPinCount; ++b) {
      if (pin(a) == pin(b)) return false;
    }
  }
  return true;
}
constexpr bool is_pwm(uint8_t p) { return (p >= 2 && p <= 10) || p == 14 || (p >= 20 && p <= 23) || p == 29 || p == 30 || (p >= 35 && p <= 38); }
constexpr bool motors_on_pwm() {
  for (size_t i = 0; i < kMotors; ++i) {
    if (!is_pwm(kMotorIn1[i]) || !is_pwm(kMotorIn2[i])) return false;
  }
  return true;
}
}  // namespace detail

static_assert(detail::all_distinct(), "a Teensy pin is wired twice");
static_assert(detail::motors_on_pwm(), "a DRV8871 input is not on a PWM pin");
static_assert(kRigChannels >= 1 && kRigChannels <= kMotors, "the rig drives 1..kMotors motors");

}  // namespace pins
