#include "load_cells.h"

#include <Arduino.h>

#include "pins.h"

void LoadCells::begin() {
  for (size_t i = 0; i < pins::kRigChannels; ++i) {
    pinMode(pins::kLoadcellDout[i], INPUT);
    pinMode(pins::kLoadcellSck[i], OUTPUT);
    digitalWrite(pins::kLoadcellSck[i], LOW);  // SCK high for > 60 µs would power the chip down
  }
}

void LoadCells::poll(twinfw::Inputs& inputs) {
  const int channel = next_;
  next_ = (next_ + 1) % static_cast<int>(pins::kRigChannels);
  if (digitalRead(pins::kLoadcellDout[channel]) != LOW) return;
  inputs.raw_counts[channel] = read(channel);
  inputs.new_sample_mask = static_cast<twinfw::ChannelMask>(inputs.new_sample_mask | (1u << channel));
}

// 24 data bits, MSB first, then one more pulse to select channel A at gain 128 for the next
// conversion. Interrupts are held off for one clock pulse at a time, not the whole read: that
// bounds SCK high to ~1 µs (far from the 60 µs power-down) while the encoder interrupts, which
// arrive every ~10 µs at full motor speed, are served between pulses and no count is lost.
int32_t LoadCells::read(int channel) {
  const uint8_t sck = pins::kLoadcellSck[channel];
  const uint8_t dout = pins::kLoadcellDout[channel];
  uint32_t value = 0;
  for (int bit = 0; bit < 25; ++bit) {
    noInterrupts();
    digitalWrite(sck, HIGH);
    delayMicroseconds(1);
    digitalWrite(sck, LOW);
    interrupts();
    delayMicroseconds(1);
    if (bit < 24) value = (value << 1) | (digitalRead(dout) == HIGH ? 1u : 0u);
  }
  // Sign-extend the 24-bit two's complement reading.
  return static_cast<int32_t>(value << 8) >> 8;
}
