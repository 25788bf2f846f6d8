#include "check.h"
#include "suites.h"
#include "units.h"

using namespace twinfw;

void test_units() {
  // 4 × 1024 × 5.3 = 21,708.8 counts per spool turn, 2π · 3.25 mm = 20.42 mm of tendon.
  CHECK_NEAR(kTendonMPerCount, 9.4064859e-7, 1e-13);
  CHECK_NEAR(counts_to_length_m(21709, 0), 2.0 * 3.14159265 * 0.00325 * 21709 / 21708.8, 1e-8);
  CHECK_NEAR(counts_to_length_m(-21709, 0), -counts_to_length_m(21709, 0), 1e-12);
  CHECK_NEAR(length_m_to_counts(counts_to_length_m(12345, 0)), 12345.0, 0.01);
  // The origin is subtracted in integers: one count stays one count near the int32 limits.
  CHECK_NEAR(counts_to_length_m(2000000001, 2000000000), kTendonMPerCount, 1e-12);
  CHECK_NEAR(counts_to_length_m(2147483647, -2147483647 - 1), 4294967295.0 * kTendonMPerCount, 1.0);
  // 45,000 counts per newton above an offset of 8,200 counts.
  CHECK_NEAR(raw_to_tension_n(8200 + 45000, 1.0f / 45000.0f, 8200.0f), 1.0, 1e-6);
  CHECK_NEAR(raw_to_tension_n(8200, 1.0f / 45000.0f, 8200.0f), 0.0, 1e-9);
  CHECK_NEAR(raw_to_tension_n(-8388608, -2.0f, 0.0f), 16777216.0, 1e-3);
}
