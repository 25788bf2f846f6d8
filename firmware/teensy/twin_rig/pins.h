// Teensy 3.5 pin map of the rig (firmware/README.md has it as a table). The thesis does not
// give its wiring: these are a choice. Every Teensy 3.5 digital pin can interrupt, so all
// encoder channels get full 4× decoding; the motor pins are PWM-capable.
#pragma once

#include <stdint.h>

namespace pins {

// DRV8871 inputs: IN1 high drives forward (pays tendon out, counts up), IN2 high reverse.
constexpr uint8_t kMotorIn1[4] = {2, 4, 6, 8};
constexpr uint8_t kMotorIn2[4] = {3, 5, 7, 9};

// Quadrature encoder A/B. If a motor counts down while paying out, swap its A and B.
constexpr uint8_t kEncoderA[4] = {24, 26, 28, 31};
constexpr uint8_t kEncoderB[4] = {25, 27, 30, 32};

// HX711 data out and clock, one pair per load cell (a shared clock would read all at once).
constexpr uint8_t kLoadcellDout[4] = {15, 17, 19, 21};
constexpr uint8_t kLoadcellSck[4] = {16, 18, 20, 22};

}  // namespace pins
