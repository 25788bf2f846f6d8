// Runs every suite; exits 0 if every check passed, else 1 (a count could wrap to 0 in an 8-bit
// exit status). The host shell and QEMU's semihosting exit both hand the status back.
#include <cstdio>

#include "check.h"
#include "suites.h"

namespace check {
Counters& counters() {
  static Counters c;
  return c;
}
}  // namespace check

int main() {
  struct Suite {
    const char* name;
    void (*run)();
  };
  const Suite suites[] = {
      {"units", test_units},       {"pid", test_pid},         {"codec", test_codec},
      {"controller", test_controller}, {"firmware", test_firmware}, {"safety", test_safety},
      {"guard", test_guard},       {"channels", test_channels},
  };
  for (const Suite& s : suites) {
    const int before = check::counters().failures;
    s.run();
    std::printf("%-10s %s\n", s.name, check::counters().failures == before ? "ok" : "FAILED");
  }
  const check::Counters& c = check::counters();
  std::printf("%d checks, %d failures\n", c.checks, c.failures);
  return c.failures == 0 ? 0 : 1;
}
