// The Teensy 3.5's hardware watchdog (the MK64FX512's WDOG): if loop() stops ticking the core
// for kWatchdogTimeoutMs, the chip resets. A reset leaves every pin an input, so the DRV8871
// inputs fall to their pull-downs and all motors coast; the firmware comes back DISABLED and
// waits for a host. This is the last line under the core's own host watchdog: it catches a
// hung sketch (a stuck USB write, a wild pointer, an HX711 read that never ends), which the
// core cannot see from inside.
#pragma once

#include <stdint.h>

namespace hw_watchdog {

// Ten 5 ms ticks: long enough for a slow pass of loop() (a 64-byte USB write, four HX711 reads),
// short enough that a hung loop stops a motor driving at full duty within 0.1 s.
constexpr uint16_t kWatchdogTimeoutMs = 100;

// Arms the watchdog (once, from setup(); it cannot be disarmed until the next reset).
void arm();
// Restarts its count; called from loop() on every tick.
void feed();

}  // namespace hw_watchdog
