// Teensy 3.5 sketch of the tendon rig: a thin layer that samples the hardware, steps the
// portable firmware core (src/core, copied in by `make -C firmware teensy-sketch`) and applies
// its outputs. All logic — PID, modes, safety, protocol — lives in the core and is unit-tested
// on the host and under QEMU; nothing here decides anything.
//
// Timing: an IntervalTimer flags a tick every 5 ms (200 Hz, so the core's 100 Hz control and
// 40 Hz telemetry both fall on ticks); the tick itself runs in loop(), outside interrupt
// context, together with USB and the HX711 polling. Each tick feeds the chip's watchdog
// (watchdog.h): a loop that stops ticking resets the board, and a reset coasts the motors.

#include <Encoder.h>
#include <IntervalTimer.h>

#include "load_cells.h"
#include "motors.h"
#include "pins.h"
#include "src/core/firmware.h"
#include "watchdog.h"

namespace {

using twinfw::kTickPeriodUs;

// Named objects, not an array of temporaries: each Encoder hands `this` to its pin interrupts
// in its constructor, so it must be built in place. All eight are built (their pins pulled up,
// so an unwired one stays still); the first pins::kRigChannels are read.
Encoder encoder1(pins::kEncoderA[0], pins::kEncoderB[0]);
Encoder encoder2(pins::kEncoderA[1], pins::kEncoderB[1]);
Encoder encoder3(pins::kEncoderA[2], pins::kEncoderB[2]);
Encoder encoder4(pins::kEncoderA[3], pins::kEncoderB[3]);
Encoder encoder5(pins::kEncoderA[4], pins::kEncoderB[4]);
Encoder encoder6(pins::kEncoderA[5], pins::kEncoderB[5]);
Encoder encoder7(pins::kEncoderA[6], pins::kEncoderB[6]);
Encoder encoder8(pins::kEncoderA[7], pins::kEncoderB[7]);
Encoder* const encoders[pins::kMotors] = {&encoder1, &encoder2, &encoder3, &encoder4,
                                          &encoder5, &encoder6, &encoder7, &encoder8};
static_assert(twinfw::kMaxChannels >= pins::kMotors, "the core drives every motor of the pin map");
IntervalTimer tickTimer;
volatile bool tickDue = false;
volatile uint32_t tickTimeUs = 0;

twinfw::Firmware firmware(pins::kRigChannels);
twinfw::Inputs inputs = {};
LoadCells loadCells;
Motors motors;

void onTick() {
  tickTimeUs = micros();
  tickDue = true;
}

// Copies the flag and its timestamp out of the interrupt's reach.
bool takeTick(uint32_t& nowUs) {
  noInterrupts();
  const bool due = tickDue;
  nowUs = tickTimeUs;
  tickDue = false;
  interrupts();
  return due;
}

void receiveFromHost() {
  uint8_t buffer[64];
  int available;
  while ((available = Serial.available()) > 0) {
    const size_t n = Serial.readBytes(reinterpret_cast<char*>(buffer),
                                      available < 64 ? available : 64);
    firmware.receive(buffer, n);
  }
}

// Sends only what the USB buffer takes now; the rest waits in the core's queue.
void sendToHost() {
  uint8_t buffer[64];
  const int room = Serial.availableForWrite();
  if (room <= 0 || firmware.tx_pending() == 0) return;
  const size_t n = firmware.take_tx(buffer, room < 64 ? room : 64);
  Serial.write(buffer, n);
}

}  // namespace

void setup() {
  motors.begin();
  loadCells.begin();
  Serial.begin(115200);  // USB serial: the rate is ignored, it runs at USB speed
  tickTimer.begin(onTick, kTickPeriodUs);
  // Last, once everything that may take long has run: from here loop() must tick every 100 ms.
  hw_watchdog::arm();
}

void loop() {
  loadCells.poll(inputs);
  receiveFromHost();
  uint32_t nowUs;
  if (takeTick(nowUs)) {
    for (size_t i = 0; i < pins::kRigChannels; ++i) inputs.encoder_counts[i] = encoders[i]->read();
    motors.apply(firmware.tick(nowUs, inputs));
    inputs.new_sample_mask = 0;
    hw_watchdog::feed();
  }
  sendToHost();
}
