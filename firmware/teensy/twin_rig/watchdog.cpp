// WDOG register sequence of the K64 Sub-Family Reference Manual (K64P144M120SF5RM, chapter
// "Watchdog Timer (WDOG)"):
//   * The control registers are write-once after an unlock: writing 0xC520 then 0xD928 to
//     WDOG_UNLOCK, within 20 bus clocks of each other, opens them for WCT = 256 bus clocks;
//     they can be reached at all only while WDOG_STCTRLH.ALLOWUPDATE is set. Teensyduino's
//     reset handler disables the watchdog with ALLOWUPDATE set, which is what lets setup()
//     arm it here.
//   * A refresh is 0xA602 then 0xB480 written to WDOG_REFRESH within 20 bus clocks; anything
//     else in between (an interrupt handler) voids it, hence interrupts off around both.
//   * The unlock takes effect a bus clock after the second write: two NOPs before the first
//     register write.
// Clock: the 1 kHz LPO (CLKSRC = 0) runs whatever the core and bus clocks do, so a clock fault
// cannot stop the watchdog with the loop; with PRESC = 0 (divide by 1) TOVAL counts ms.
// STCTRLH here: WDOGEN, STOPEN and WAITEN (counting in low-power modes too), bit 8 (reserved,
// reads 1 after reset, written back as 1), and ALLOWUPDATE clear, so that nothing, a runaway
// included, can change or stop it before the next reset. IRQRSTEN, WINEN, DBGEN clear: a plain
// reset, no window, and no counting while a debugger halts the core.
#include "watchdog.h"

#include <Arduino.h>

namespace hw_watchdog {

namespace {
constexpr uint16_t kUnlock1 = 0xC520;
constexpr uint16_t kUnlock2 = 0xD928;
constexpr uint16_t kRefresh1 = 0xA602;
constexpr uint16_t kRefresh2 = 0xB480;
constexpr uint16_t kStctrlhReserved = 0x0100;
bool armed = false;
}  // namespace

void arm() {
  if (armed) return;
  noInterrupts();
  WDOG_UNLOCK = kUnlock1;
  WDOG_UNLOCK = kUnlock2;
  __asm__ volatile("nop\n\tnop");
  WDOG_TOVALH = 0;
  WDOG_TOVALL = kWatchdogTimeoutMs;
  WDOG_PRESC = 0;
  WDOG_STCTRLH = WDOG_STCTRLH_WDOGEN | WDOG_STCTRLH_STOPEN | WDOG_STCTRLH_WAITEN | kStctrlhReserved;
  interrupts();
  armed = true;
}

void feed() {
  if (!armed) return;
  noInterrupts();
  WDOG_REFRESH = kRefresh1;
  WDOG_REFRESH = kRefresh2;
  interrupts();
}

}  // namespace hw_watchdog
