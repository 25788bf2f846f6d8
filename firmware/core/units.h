// Unit conversions between what the hardware counts and what the protocol speaks.
#pragma once

#include <cstdint>

#include "config.h"

namespace twinfw {

// Relative tendon length (m, positive = paid out) from an encoder count and its origin, at
// `m_per_count` of tendon per count (the board's encoder, gearbox and spool). The difference is
// taken in integers so that a large count keeps its resolution in float.
inline float counts_to_length_m(int32_t counts, int32_t origin_counts, float m_per_count = kTendonMPerCount) {
  return static_cast<float>(static_cast<int64_t>(counts) - origin_counts) * m_per_count;
}

inline float length_m_to_counts(float length_m, float m_per_count = kTendonMPerCount) { return length_m / m_per_count; }

// Calibrated tension (N) from a raw HX711 reading: the host's linear regression.
inline float raw_to_tension_n(int32_t raw_counts, float gain_n_per_count, float offset_counts) {
  return gain_n_per_count * (static_cast<float>(raw_counts) - offset_counts);
}

}  // namespace twinfw
