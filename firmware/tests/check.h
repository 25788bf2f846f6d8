// A dependency-free test harness that runs the same on the host and under QEMU semihosting:
// checks print file:line and the failing expression, and main() returns the failure count.
#pragma once

#include <cstdio>

namespace check {

struct Counters {
  int checks = 0;
  int failures = 0;
};

Counters& counters();

inline bool record(bool ok, const char* file, int line, const char* what) {
  ++counters().checks;
  if (!ok) {
    ++counters().failures;
    std::printf("FAIL %s:%d: %s\n", file, line, what);
  }
  return ok;
}

inline bool near(double a, double b, double tol) { return (a - b <= tol) && (b - a <= tol); }

}  // namespace check

#define CHECK(cond) check::record(static_cast<bool>(cond), __FILE__, __LINE__, #cond)
#define CHECK_NEAR(a, b, tol)                                                                   \
  do {                                                                                          \
    const double check_a_ = (a), check_b_ = (b);                                                \
    if (!check::record(check::near(check_a_, check_b_, (tol)), __FILE__, __LINE__,              \
                       #a " ~= " #b " within " #tol)) {                                         \
      std::printf("     %.9g vs %.9g\n", check_a_, check_b_);                                   \
    }                                                                                           \
  } while (0)
