#include "motors.h"

#include <Arduino.h>

#include "pins.h"

namespace {
// 20 kHz is above hearing; 12-bit duty (Teensy 3.5 scales it to the timer's period).
constexpr float kPwmFrequencyHz = 20000.0f;
constexpr int kPwmBits = 12;
constexpr int kPwmMax = (1 << kPwmBits) - 1;
}  // namespace

void Motors::begin() {
  analogWriteResolution(kPwmBits);
  for (size_t i = 0; i < pins::kRigChannels; ++i) {
    analogWriteFrequency(pins::kMotorIn1[i], kPwmFrequencyHz);
    analogWriteFrequency(pins::kMotorIn2[i], kPwmFrequencyHz);
    analogWrite(pins::kMotorIn1[i], 0);  // coast until the firmware says otherwise
    analogWrite(pins::kMotorIn2[i], 0);
  }
}

// Drive: PWM on one input, the other low (drive/coast, "fast decay"). Coast: both low.
// Brake: both high, which shorts the motor and holds the spool.
void Motors::apply(const twinfw::Outputs& outputs) {
  for (size_t i = 0; i < pins::kRigChannels; ++i) {
    int in1 = 0;
    int in2 = 0;
    if (outputs.drive[i] == twinfw::Drive::kBrake) {
      in1 = in2 = kPwmMax;
    } else if (outputs.drive[i] == twinfw::Drive::kDrive) {
      const float duty = outputs.duty[i];
      const int level = static_cast<int>((duty < 0 ? -duty : duty) * kPwmMax + 0.5f);
      (duty >= 0 ? in1 : in2) = level > kPwmMax ? kPwmMax : level;
    }
    analogWrite(pins::kMotorIn1[i], in1);
    analogWrite(pins::kMotorIn2[i], in2);
  }
}
