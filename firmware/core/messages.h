// Message types of the host ↔ board protocol (firmware/PROTOCOL.md). Each struct lists its
// fields in wire order; visit_fields() is the single place that order is written down, and
// both encoding and decoding walk it. A message whose layout depends on the channel count
// starts with it (`channels`), and its per-channel fields have that many entries on the wire
// (the arrays here hold kMaxChannels). Enumerations travel as plain bytes so that a decoded
// message can hold an out-of-range value, which the firmware then refuses with a NACK.
#pragma once

#include <cstddef>
#include <cstdint>

#include "bytes.h"
#include "config.h"

namespace twinfw {

enum class MsgType : uint8_t {
  kHello = 0x01,
  kPing = 0x02,
  kEnable = 0x03,
  kDisable = 0x04,
  kTare = 0x05,
  kSetMode = 0x06,
  kSetSetpoints = 0x07,
  kSetGains = 0x08,
  kSetCalibration = 0x09,
  kSetLimits = 0x0A,
  kSetMotors = 0x0B,
  kHelloReply = 0x81,
  kAck = 0x82,
  kNack = 0x83,
  kTelemetry = 0x84,
};

enum class Mode : uint8_t { kLengths = 0, kPairs = 1, kTension = 2 };
constexpr size_t kModes = 3;

enum class State : uint8_t { kDisabled = 0, kEnabled = 1, kFault = 2 };

// How an H-bridge is driven: DRV8871 IN1 = IN2 = 0 coasts, both high brakes.
enum class Drive : uint8_t { kCoast = 0, kDrive = 1, kBrake = 2 };

enum class NackError : uint8_t {
  kUnknownType = 1,
  kBadLength = 2,
  kBadValue = 3,
  kWrongMode = 4,
  kNotEnabled = 5,
  kNotWhileEnabled = 6,
  kNoHandshake = 7,
  kNotCalibrated = 8,
};

namespace fault {
constexpr uint32_t kWatchdog = 1u << 0;      // latched: host silent for the watchdog timeout
constexpr uint32_t kTensionLimit = 1u << 1;  // latched: a tension exceeded the limit
constexpr uint32_t kLoadcellStale = 1u << 2; // live: motion held while a load cell is stale
constexpr uint32_t kLoadcellImplausible = 1u << 3;  // latched: a load cell cannot be believed
// Latched: which channel exceeded the tension limit (bits 8..19).
constexpr uint32_t tension_channel(size_t channel) { return 1u << (8 + channel); }
// Latched: which channel's load cell was implausible (bits 20..31).
constexpr uint32_t implausible_channel(size_t channel) { return 1u << (20 + channel); }
static_assert(20 + kMaxChannels <= 32, "the fault flags hold a tension and an implausible bit per channel");
}  // namespace fault

namespace msg {

// Host → board.
struct Hello {
  static constexpr MsgType kType = MsgType::kHello;
  uint16_t protocol_version;
};
struct Ping {
  static constexpr MsgType kType = MsgType::kPing;
};
struct Enable {
  static constexpr MsgType kType = MsgType::kEnable;
};
struct Disable {
  static constexpr MsgType kType = MsgType::kDisable;
};
struct Tare {
  static constexpr MsgType kType = MsgType::kTare;
  uint8_t channels;
  ChannelMask loadcell_mask;  // bit i: offset of load cell i := its latest raw count (reads 0 N)
  ChannelMask length_mask;    // bit i: length origin of motor i := its encoder count (reads 0 m)
};
struct SetMode {
  static constexpr MsgType kType = MsgType::kSetMode;
  uint8_t mode;
};
struct SetSetpoints {
  static constexpr MsgType kType = MsgType::kSetSetpoints;
  uint8_t channels;
  uint8_t mode;                // must equal the active mode
  float values[kMaxChannels];  // m (lengths; pairs use the first channels / 2) or N (tension)
};
struct SetGains {
  static constexpr MsgType kType = MsgType::kSetGains;
  uint8_t mode;
  float kp;            // duty per m (length modes) or per N (tension)
  float ki;            // the same per second
  float kd;            // the same times seconds
  float output_limit;  // |duty| and integral clamp, in (0, 1]
};
struct SetCalibration {
  static constexpr MsgType kType = MsgType::kSetCalibration;
  uint8_t channels;
  float gain_n_per_count[kMaxChannels];  // tension_n = gain_n_per_count · (raw − offset_counts)
  float offset_counts[kMaxChannels];
};
struct SetLimits {
  static constexpr MsgType kType = MsgType::kSetLimits;
  float tension_limit_n;
  uint16_t watchdog_timeout_ms;
  float loadcell_gain_counts_per_n;  // the load cells' rated sensitivity
};
// The motors at the tendons, all alike: what the tension bound derives from.
struct SetMotors {
  static constexpr MsgType kType = MsgType::kSetMotors;
  float stall_force_n;          // pull at full duty on a stalled spool (N)
  float no_load_speed_m_per_s;  // tendon speed at full duty and no load (m/s)
  float reflected_mass_kg;      // rotor inertia seen at the tendon (kg)
};

// Board → host.
struct HelloReply {
  static constexpr MsgType kType = MsgType::kHelloReply;
  uint16_t protocol_version;
  uint8_t firmware_version[3];  // major, minor, patch
  uint8_t channels;
  uint32_t control_period_us;
  uint32_t telemetry_period_us;
  float tendon_m_per_count;
};
struct Ack {
  static constexpr MsgType kType = MsgType::kAck;
  uint16_t acked_seq;
  uint8_t acked_type;
};
struct Nack {
  static constexpr MsgType kType = MsgType::kNack;
  uint16_t acked_seq;
  uint8_t acked_type;
  uint8_t error;
};
struct TelemetryMessage {
  static constexpr MsgType kType = MsgType::kTelemetry;
  uint8_t channels;
  uint64_t time_us;                      // device time since the first tick
  uint32_t sample_seq;                   // telemetry counter: a gap means lost samples
  int32_t encoder_counts[kMaxChannels];  // raw encoder counts (no origin applied)
  float lengths_m[kMaxChannels];         // relative tendon lengths (origin set by TARE)
  int32_t raw_counts[kMaxChannels];      // latest HX711 readings
  float tensions_n[kMaxChannels];        // calibrated tensions
  float targets[kMaxChannels];           // per-motor target: m (length modes) or N (tension)
  float duty[kMaxChannels];              // motor commands in [-1, 1]
  uint8_t drive_modes[kMaxChannels];     // Drive of each motor
  uint8_t state;
  uint8_t mode;
  uint32_t fault_flags;
  ChannelMask stale_mask;                // bit i: load cell i stale
  uint32_t rx_bad_frames;                // frames dropped for framing or CRC errors
  uint32_t tx_dropped_frames;   // frames not sent because the TX queue was full
  // Encoder counts at each of the last kTelemetryTicks ticks, oldest first, the last being this
  // frame's own (0), as differences from encoder_counts saturated to the int16 range:
  // [tick][channel], each tick's row holding `channels` entries.
  int16_t encoder_history[kTelemetryTicks][kMaxChannels];
};

}  // namespace msg

template <class V> void visit_fields(V& v, msg::Hello& m) { v(m.protocol_version); }
template <class V> void visit_fields(V&, msg::Ping&) {}
template <class V> void visit_fields(V&, msg::Enable&) {}
template <class V> void visit_fields(V&, msg::Disable&) {}
template <class V> void visit_fields(V& v, msg::Tare& m) {
  v(m.channels);
  v(bits_of(m.loadcell_mask, m.channels, kMaxChannels));
  v(bits_of(m.length_mask, m.channels, kMaxChannels));
}
template <class V> void visit_fields(V& v, msg::SetMode& m) { v(m.mode); }
template <class V> void visit_fields(V& v, msg::SetSetpoints& m) {
  v(m.channels);
  v(m.mode);
  v(first(m.values, m.channels));
}
template <class V> void visit_fields(V& v, msg::SetGains& m) {
  v(m.mode);
  v(m.kp);
  v(m.ki);
  v(m.kd);
  v(m.output_limit);
}
template <class V> void visit_fields(V& v, msg::SetCalibration& m) {
  v(m.channels);
  v(first(m.gain_n_per_count, m.channels));
  v(first(m.offset_counts, m.channels));
}
template <class V> void visit_fields(V& v, msg::SetLimits& m) {
  v(m.tension_limit_n);
  v(m.watchdog_timeout_ms);
  v(m.loadcell_gain_counts_per_n);
}
template <class V> void visit_fields(V& v, msg::SetMotors& m) {
  v(m.stall_force_n);
  v(m.no_load_speed_m_per_s);
  v(m.reflected_mass_kg);
}
template <class V> void visit_fields(V& v, msg::HelloReply& m) {
  v(m.protocol_version);
  v(m.firmware_version);
  v(m.channels);
  v(m.control_period_us);
  v(m.telemetry_period_us);
  v(m.tendon_m_per_count);
}
template <class V> void visit_fields(V& v, msg::Ack& m) {
  v(m.acked_seq);
  v(m.acked_type);
}
template <class V> void visit_fields(V& v, msg::Nack& m) {
  v(m.acked_seq);
  v(m.acked_type);
  v(m.error);
}
template <class V> void visit_fields(V& v, msg::TelemetryMessage& m) {
  v(m.channels);
  v(m.time_us);
  v(m.sample_seq);
  v(first(m.encoder_counts, m.channels));
  v(first(m.lengths_m, m.channels));
  v(first(m.raw_counts, m.channels));
  v(first(m.tensions_n, m.channels));
  v(first(m.targets, m.channels));
  v(first(m.duty, m.channels));
  v(first(m.drive_modes, m.channels));
  v(m.state);
  v(m.mode);
  v(m.fault_flags);
  v(bits_of(m.stale_mask, m.channels, kMaxChannels));
  v(m.rx_bad_frames);
  v(m.tx_dropped_frames);
  for (auto& row : m.encoder_history) v(first(row, m.channels));
}

// Writes the payload of `message` and its size; false if `capacity` is too small.
template <class T>
bool write_payload(const T& message, uint8_t* out, size_t capacity, size_t& size) {
  T copy = message;
  ByteWriter writer(out, capacity);
  visit_fields(writer, copy);
  size = writer.size();
  return writer.ok();
}

// Fills `out` from a payload; false unless the payload has exactly the message's size.
template <class T>
bool read_payload(const uint8_t* payload, size_t size, T& out) {
  ByteReader reader(payload, size);
  visit_fields(reader, out);
  return reader.consumed_exactly();
}

}  // namespace twinfw
