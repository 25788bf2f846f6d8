// Rig constants, timing and defaults of the firmware core (thesis §4). The ones the parameter set
// also holds are checked against models/endoscope/endoscope.toml by tests/test_firmware_config.py.
#pragma once

#include <cstddef>
#include <cstdint>

namespace twinfw {

// Motors (tendons, load cells) a board may drive: the plant loop's BL_MAX_CHANNELS, and the most
// the TELEMETRY fault flags have channel bits for (12 per fault kind). The count a board drives
// is given at construction: the rig's sketch fixes it (teensy/twin_rig/pins.h), the emulated
// board takes its robot's tendon count.
constexpr size_t kMaxChannels = 12;
// The thesis endoscope's four tendons (models/endoscope/endoscope.toml, tendons.count): the
// count of a board built without one.
constexpr size_t kDefaultChannels = 4;
// A set of channels, bit i for channel i.
using ChannelMask = uint16_t;
static_assert(kMaxChannels <= 8 * sizeof(ChannelMask), "a ChannelMask holds a bit per channel");

// Protocol version: bumped on any change of a byte layout in firmware/PROTOCOL.md.
constexpr uint16_t kProtocolVersion = 5;
constexpr uint8_t kFirmwareVersionMajor = 0;
constexpr uint8_t kFirmwareVersionMinor = 4;
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
// The board's tick (µs): the Teensy sketch's IntervalTimer period, which the emulated board
// (twin/device/board.py, TICK_S) ticks at too.
constexpr uint32_t kTickPeriodUs = 5000;
static_assert(kControlPeriodUs % kTickPeriodUs == 0 && kTelemetryPeriodUs % kTickPeriodUs == 0,
              "control and telemetry fall on ticks");
// Encoder counts a TELEMETRY frame carries per channel: one per tick since the frame before
// (25 ms / 5 ms = 5), so that the host sees the spools' motion between frames.
constexpr size_t kTelemetryTicks = kTelemetryPeriodUs / kTickPeriodUs;

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

// The motors at the tendons, as the host gives them (SET_MOTORS, from the parameter set's
// rig.motor_stall_torque_nm, rig.motor_no_load_speed_rpm, rig.motor_rotor_inertia_kgm2,
// rig.gear_ratio and rig.spool_radius_m), until then the thesis rig's (thesis §4): at full duty a
// stalled spool pulls the tendon with 0.5 N·m / 3.25 mm = 154 N, an unloaded one winds
// 1500 rpm × 2π × 3.25 mm = 0.51 m/s, and its rotor (1e-6 kg·m² behind the 5.3:1 gearbox) weighs
// 1e-6 × 5.3² / 3.25 mm² = 2.66 kg at the tendon. A stalled motor's pull is its duty times the
// stall force: the bound on tension below rests on that. Its back-EMF damping at the tendon is
// stall force over no-load speed (300 N·s/m).
constexpr float kMotorStallTorqueNm = 0.5f;
constexpr float kMotorNoLoadSpeedRpm = 1500.0f;
constexpr double kMotorRotorInertiaKgm2 = 1e-6;
constexpr float kDefaultStallForceN = static_cast<float>(kMotorStallTorqueNm / kSpoolRadiusM);
constexpr float kDefaultNoLoadSpeedMPerS =
    static_cast<float>(kMotorNoLoadSpeedRpm * 2.0 * kPi / 60.0 * kSpoolRadiusM);
constexpr float kDefaultReflectedMassKg =
    static_cast<float>(kMotorRotorInertiaKgm2 * kGearRatio * kGearRatio / (kSpoolRadiusM * kSpoolRadiusM));
constexpr float kDefaultMotorDampingNsPerM = kDefaultStallForceN / kDefaultNoLoadSpeedMPerS;
// Motors SET_MOTORS accepts, at the tendon. Stall force 1…10,000 N: under 1 N a motor cannot hold
// a tendon taut against the loop's noise, and the cap's duty (0.9 × limit / stall force) must
// stay resolvable in a float. No-load speed 1 mm/s…10 m/s. Reflected mass 0.01…1000 kg: the
// blow bound below scales with its square root, and the brake's settling time with it.
constexpr float kMinStallForceN = 1.0f;
constexpr float kMaxStallForceN = 1.0e4f;
constexpr float kMinNoLoadSpeedMPerS = 1.0e-3f;
constexpr float kMaxNoLoadSpeedMPerS = 10.0f;
constexpr float kMinReflectedMassKg = 0.01f;
constexpr float kMaxReflectedMassKg = 1000.0f;

constexpr float kPullForceFraction = 0.9f;
constexpr float kBlowBoundFraction = 1.2f;
constexpr float kBlowImpedanceNsPerM = 390.0f;
// A tendon that reads more than kTautFraction of the cap has no slack to take up: its spool may
// wind kTautSpeedFactor times faster, which the tension loop needs to follow its setpoints
// (its tension then rises with the rod's stiffness, where the load cell sees it).
constexpr float kTautFraction = 0.1f;
constexpr float kTautSpeedFactor = 2.0f;
// Length references ramp towards their targets at the winding speed limit, paying out as well
// (a tendon paid out faster than its antagonist winds in goes slack), and never faster than
// this (m/s, for large limits): a step becomes a ramp the PID tracks.
constexpr float kMaxLengthRateMPerS = 0.02f;
// ... and no further than this (m) ahead of the tendon's length.
constexpr float kMaxLengthLeadM = 0.00025f;
// Tension references ramp towards their targets at this many times the tension limit per
// second (a full-range step takes 0.1 s). A motor pulling against its antagonist raises the
// antagonist's tension by what it adds; where that spool holds its tendon at the cap (a tip load
// on it), it must yield, and its 2.7 kg of reflected rotor lags a pull that rises at once: on the
// twin, a tension step at 2 N with an 18 g tip load put 1.23× the limit on the held tendon.
constexpr float kTensionRatePerS = 10.0f;
// The tension loop's proportional term acts on the tension error through a first-order lag of
// this time constant (s); 0 acts on the error itself. A held tendon that friction sticks is a
// stiff load (presliding: tens of kN/m against 2.7 kg of reflected rotor, a 20-40 Hz resonance
// behind the 80 Hz load cell), and the proportional term feeds the cells' white noise into it:
// on stiff-long at μ = 0.3 (5 kg cells, 25 mN RMS) the true tension of its 16 N tendon rang
// 0.43 N peak to peak, 73 % of its variance in 25-40 Hz, and not at all with noiseless cells
// (no limit cycle: the ring grows with the noise). One control period, 10 ms (a 16 Hz corner,
// under half the drive at 30 Hz, 14 degrees on the proportional term at the loop's ~4 Hz
// crossover, ki × stall force = 23 /s), took it to 0.12 N
// and changed no other robot of the zoo by more than 3 mN (twin bench hold, μ 0-0.3). It is
// 25 ms (a 6.4 Hz corner) because a stuck tendon held near the duty clamp cycles by itself:
// on long at μ = 0.3, κ 15.72 1/m, φ 270°, 10 g, tensions 2.74 / 3.50 / 5.115 / 5.115 N (a
// compensation's command, 95 % of the clamp), the last two rang at 20 Hz, 2.0 N peak to peak
// with 10 ms, as much with noiseless cells, and grew with the bend to the 6 N limit; with
// 20 / 25 / 30 ms 0.07-0.09 / 0.05-0.06 / 0.04-0.05 N (seeds 0-2), and no bench hold figure of
// the zoo moved by more than 5 mN. The integral alone keeps a ring there where the robot is
// bent further (2.0 / 2.5 / 5.115 / 5.115 N: 0.15 N at 20 Hz with kp = 0, 0.41 N with 25 ms),
// which no lag of the proportional term removes. Longer lags cost more than they give: 30 ms
// left a dynamics calibration of a miscalibrated cell with no dynamic candidate even better
// than none, 50 ms let the endoscope ring at 0.13 N and moved a noisy recording's tension
// steps 0.3 mm from their noiseless replay (a clean run then read as an effect).
constexpr float kTensionProportionalLagS = 0.025f;
// The tension loop's integral term acts on the tension error through two first-order lags of
// this time constant (s) each (0: on the error itself). A stuck tendon held near the duty clamp
// rang with the integral driving it: on long at μ = 0.3, κ 15.72 1/m, φ 270°, 10 g, holding
// 5.115 N on two tendons against 2.0-2.2 N on the others, those two cycled at 20 Hz, 0.3-1.2 N
// peak to peak (as much with noiseless cells: a limit cycle; 0.7 N with kp = 0), their duty in
// phase with their tension: each rotor (2.7 kg at the tendon) on a tendon friction holds in
// presliding (~100 kN/m) is a resonance the back-EMF damps lightly. Two 4 ms lags (11° at the
// loop's ~4 Hz crossover, ki × stall force = 23 /s) take it to 0.05-0.13 N (seeds 0-2; 0.07 N
// with noiseless cells), its 0.1 s means within 0.013 N; 3 or 7 ms left 0.12-0.16 N (2.0 / 2.5 N),
// one 15 or 25 ms lag left 0.36-0.41 N. 5 ms (0.05-0.15 N) made a dynamics recording of a load
// cell reading 10 % high pass for a friction and backlash pair (held-out score 1.8 against a
// bound of 3.2; 9.2 against 2.4 with 4 ms, 5.8 against 2.5 without the lags).
// Longer lags cost phase at the crossover that the dynamics identification needs:
// two 10 ms lags on both terms (instead of the proportional lag alone) held those tendons within
// 0.04 N, but a dynamics recording with a 20 ms actuation latency and a 50 ms cell lag was then
// no longer named. A spool damping straight into the duty (half the back-EMF up to 2 mm/s) with
// 5 ms lags held them within 0.05 N, but rang stiff-long's 25 N tendon (0.42 N; a speed taken
// over one 10 ms period and acted on over the next lags 10-15 ms, which turns a damping over
// above ~20 Hz) and slowed the frictionless rod's settling.
constexpr float kTensionIntegralLagS = 0.004f;
// Tension mode can hold each taut tendon (over kTautFraction of the limit) at its reference
// plus a damping (N·s/m) times the tendon's swinging speed (paying out raises the reference,
// winding in lowers it): a viscous tendon to the rod's swing modes instead of an ideal tension
// source, whose only damping is then the rod's own. 0 turns it off. Under tendon friction those
// modes grow into limit cycles whatever the kp (the endoscope at κ 17.5 1/m, φ 0, μ = 0.3:
// its sideways pair ±0.6 N at 3 Hz within 3 s of a 5 g hold; a 10 g hold at the compensation's
// ceiling swinging to the 6 N limit). Measured on the twin: 300 and 600 N·s/m let that 10 g
// hold reach the limit still, 1500 held both, and 1500 (five times the motor's back-EMF
// damping, 302 N·s/m, which the tension loop otherwise cancels) took `twin compensate` at
// μ = 0.3 from 9 of 14 faulted rows on the high-curvature bends to none. But it slows a tension
// step through the soft rod by as much (a dynamics recording's 2.75 N step held at 2.12 N), which
// the tuned gains, the tuning's step rollout and the dynamics identification were all made
// without: off until they are made with it. A slack tendon is never damped: its spool is free,
// and there the damping would be a velocity loop through the speed's lag.
constexpr float kTensionDampingNsPerM = 0.0f;
// The swinging speed is the length's difference over a control period through a first-order
// lag of kTensionDampingLagS (an encoder count in a period, 0.094 mm/s, is then ~0.05 N of
// reference at 1500 N·s/m, not 0.14 N), less its average over kTensionDampingWashoutS: a
// steady motion (slack taken up, a slow tension ramp through the soft rod) is not damped, and
// swings faster than ~1/(2π · 0.5 s) = 0.3 Hz are.
constexpr float kTensionDampingLagS = 0.02f;
constexpr float kTensionDampingWashoutS = 0.5f;
// Spool speeds are measured tick to tick (5 ms on the Teensy: 0.19 mm/s per encoder count), over
// at least this (µs).
constexpr uint32_t kSpeedWindowUs = 1000;
// A spool slower than this (m/s) is still. A motor that stops driving brakes (shorted: 300 N·s/m
// at the tendon, but never resisting with more than the cap) until its spool stays still in the
// brake, and only then coasts: a spool still winding in would wind on, and one let go under
// tension would fly out while the rod springs back, and the tendon snap taut again. Still in
// the brake means a tension under 0.3 N.
constexpr float kStillSpeedMPerS = 0.001f;
// ... in every window for this long (µs), twice the brake's time constant (2.7 kg of reflected
// rotor over 300 N·s/m: 9 ms): a spool the brake turns round, from winding in to a tendon
// pulling it out, is still for a few ms on the way, but not for this long unless the tendon
// pulls it with less than 0.35 N. A heavier rotor or a weaker brake takes longer: the board
// waits max(kStillUs, twice the time constant of the motors it is given).
constexpr uint32_t kStillUs = 20000;

// A motor that has pulled with kAtCapFraction of its cap or more against a still spool for
// kAtCapUs trips the tension limit: its tendon then carries 0.9 of the limit, whatever the load
// cell reads, and its target is not to be reached within the limit.
constexpr float kAtCapFraction = 0.999f;
constexpr uint32_t kAtCapUs = 200000;

// Load-cell plausibility: a spool that has stood still for kImplausibleUs while its motor winds
// in with a stall force F ≥ kPlausibleMinForceN must read at least kPlausibleFraction · F −
// kPlausibleMarginN; a channel reading less trips a fault (it is miscalibrated, unplugged or
// its tendon off the pulley). Gearbox friction takes some of F, hence the
// wide margin; a gain within the calibration bounds below (25 %) never trips it.
constexpr uint32_t kImplausibleUs = 100000;
constexpr float kPlausibleMinForceN = 0.6f;
constexpr float kPlausibleFraction = 1.0f / 3.0f;
constexpr float kPlausibleMarginN = 0.2f;

// Load cells. The host gives the board its cells' rated sensitivity (SET_LIMITS
// loadcell_gain_counts_per_n: the parameter set's sensors.loadcell_gain_counts_per_n, 45,000
// counts/N for the thesis's HX711 at gain 128 with 1 kg cells) and SET_CALIBRATION accepts a
// gain only within kGainTolerance of it either way: the cell's rated output ±10 %, the HX711's
// excitation and gain a few % more. A larger error is a wrong cell, wiring or unit; it would
// blind the tension limit (a reading 10x low lets the tendon reach 10x the limit) and scale the
// tension loop's gain away from what its gains were tuned for. Until a calibration arrives the
// rated sensitivity converts the readings, so the limit holds from the first ENABLE.
constexpr float kGainTolerance = 1.25f;
// Offsets: within 2^20 counts of zero, an eighth of the HX711's 24-bit range. Readings at either
// end of the 24-bit range are not trusted at all.
constexpr float kMaxOffsetCounts = 1048576.0f;
constexpr int32_t kLoadcellMaxCounts = 8388607;
constexpr int32_t kLoadcellMinCounts = -8388608;
// Rated sensitivities SET_LIMITS accepts (counts/N). At most so much that the largest limit
// (kMaxTensionLimitN) at the largest calibrated gain on the largest offset still reads below
// saturation: (2^23 - 1 - 2^20) / (50 N x 1.25) = 117,440 counts/N. At least 100: a count is then
// 10 mN, twice the thesis cell's noise; a coarser cell cannot hold a limit to a few percent.
constexpr float kMinRatedGainCountsPerN = 100.0f;
constexpr float kMaxRatedGainCountsPerN =
    static_cast<float>((kLoadcellMaxCounts - kMaxOffsetCounts) / (kMaxTensionLimitN * kGainTolerance));

// Largest PID gains SET_GAINS accepts, per unit of the mode: length modes in duty per m, tension
// in duty per N (100 to 300× the defaults). At them a 1-count (0.94 µm) error already commands
// about 1 % duty and a noise-level (5 mN) one 0.5 %; and every product stays finite.
constexpr float kMaxLengthKp = 1.0e4f;
constexpr float kMaxLengthKi = 1.0e5f;
constexpr float kMaxLengthKd = 1.0e2f;
constexpr float kMaxTensionKp = 1.0f;
constexpr float kMaxTensionKi = 1.0e2f;
constexpr float kMaxTensionKd = 1.0e-1f;

// Rated load-cell sensitivity until the host sends its own (45,000 counts/N: HX711 at gain 128
// with a 1 kg cell, models/endoscope/endoscope.toml [sensors]).
constexpr float kDefaultGainNPerCount = 1.0f / 45000.0f;

}  // namespace twinfw
