// Rig constants, timing and defaults of the firmware core (thesis §4). The ones the parameter set
// also holds are checked against models/endoscope.toml by tests/test_firmware_config.py.
#pragma once

#include <cstddef>
#include <cstdint>

namespace twinfw {

constexpr size_t kChannels = 4;

// Protocol version: bumped on any change of a byte layout in firmware/PROTOCOL.md.
constexpr uint16_t kProtocolVersion = 1;
constexpr uint8_t kFirmwareVersionMajor = 0;
constexpr uint8_t kFirmwareVersionMinor = 1;
constexpr uint8_t kFirmwareVersionPatch = 0;

// Encoder → tendon: 4 × 1024 quadrature counts per motor revolution, 5.3:1 gearbox, spool
// radius 3.25 mm. 21,708.8 counts per spool revolution is not an integer, hence float.
constexpr double kEncoderCountsPerMotorRev = 4.0 * 1024.0;
constexpr double kGearRatio = 5.3;
constexpr double kSpoolRadiusM = 0.00325;
constexpr double kPi = 3.14159265358979323846;
constexpr float kTendonMPerCount =
    static_cast<float>(2.0 * kPi * kSpoolRadiusM / (kEncoderCountsPerMotorRev * kGearRatio));

// Schedules (µs). The control loop runs at 100 Hz and telemetry at 40 Hz whatever rate tick()
// is called at; a tick rate of 200 Hz (the GCD) hits both exactly.
constexpr uint32_t kControlPeriodUs = 10000;
constexpr uint32_t kTelemetryPeriodUs = 25000;
constexpr float kControlPeriodS = kControlPeriodUs * 1e-6f;

// HX711 at 80 Hz: a channel is stale after three missed periods.
constexpr uint32_t kLoadcellPeriodUs = 12500;
constexpr uint32_t kLoadcellStaleUs = 3 * kLoadcellPeriodUs;

// Safety defaults and the ranges SET_LIMITS accepts. The watchdog cannot be switched off.
constexpr float kDefaultTensionLimitN = 6.0f;
constexpr float kMaxTensionLimitN = 50.0f;
constexpr uint16_t kDefaultWatchdogMs = 250;
constexpr uint16_t kMinWatchdogMs = 20;
constexpr uint16_t kMaxWatchdogMs = 10000;

// Length setpoints beyond ±50 mm (2.5 spool turns) are refused: a value in mm sent as m
// must not unwind the spools.
constexpr float kMaxLengthSetpointM = 0.05f;

// Nominal load-cell calibration until the host sends its regression (45,000 counts/N:
// HX711 at gain 128 with a 1 kg cell, models/endoscope.toml [sensors]).
constexpr float kDefaultGainNPerCount = 1.0f / 45000.0f;

}  // namespace twinfw
