// A test bench around one Firmware: a host that frames commands and parses replies, a clock,
// and a crude plant (motors that move tendons, load cells that see a spring) so that closed
// loops can be checked end to end without hardware.
#pragma once

#include <cstdint>

#include "firmware.h"
#include "frame.h"

namespace bench {

using namespace twinfw;

struct Replies {
  int acks = 0;
  int nacks = 0;
  uint8_t last_nack_error = 0;
  uint16_t last_acked_seq = 0;
  int hello_replies = 0;
  msg::HelloReply hello{};
  int telemetry = 0;
  msg::TelemetryMessage last{};
};

class Bench {
 public:
  // Tendon speed at full duty (m/s): 1321 rpm at the gearbox output on a 3.25 mm spool
  // (0.45 m/s), somewhat more unloaded: the twin's motor model gives ~0.51 m/s.
  static constexpr float kTendonSpeedMPerS = 0.51f;
  static constexpr int32_t kRawOffset = 8200;
  static constexpr float kRawPerN = 45000.0f;

  // A bench of `channels` motors (the thesis endoscope's four unless told).
  explicit Bench(size_t channels = kDefaultChannels) : fw(channels), channels_(fw.channels()) {}

  Firmware fw;
  Replies replies;
  uint32_t now_us = 0;
  double counts[kMaxChannels] = {};
  // Load-cell model: tension = pretension − stiffness · length (a taut tendon slackens as it
  // pays out); samples every 12.5 ms unless a channel is silenced.
  float pretension_n = 1.0f;
  float stiffness_n_per_m = 200.0f;
  float extra_tension_n[kMaxChannels] = {};
  ChannelMask silenced_mask = 0;
  // Spools that do not turn whatever their motors do: a tendon the rod holds fast.
  ChannelMask stalled_mask = 0;
  Outputs out{};

  template <class T>
  uint16_t send(const T& message) {
    uint8_t frame[kMaxEncodedFrameBytes];
    const size_t n = encode_message(message, seq_, frame, sizeof frame);
    fw.receive(frame, n);
    drain();
    return seq_++;
  }

  // Sends raw bytes (for corrupted or garbage input).
  void send_bytes(const uint8_t* data, size_t size) {
    fw.receive(data, size);
    drain();
  }

  // Handshake, calibration to the plant's load cells, enable; true if all were acknowledged.
  bool start(Mode mode = Mode::kLengths) {
    send(msg::Hello{kProtocolVersion});
    msg::SetCalibration calibration{};
    calibration.channels = static_cast<uint8_t>(channels_);
    for (size_t i = 0; i < channels_; ++i) {
      calibration.gain_n_per_count[i] = 1 / kRawPerN;
      calibration.offset_counts[i] = kRawOffset;
    }
    send(calibration);
    run(0.05);  // fresh load-cell samples
    send(msg::SetMode{static_cast<uint8_t>(mode)});
    send(msg::Enable{});
    return replies.hello_replies == 1 && replies.acks == 3 && fw.state() == State::kEnabled;
  }

  // Advances `seconds` in ticks of `tick_us`, moving the plant with the last outputs.
  void run(double seconds, uint32_t tick_us = 1000) {
    const int steps = static_cast<int>(seconds * 1e6 / tick_us + 0.5);
    for (int s = 0; s < steps; ++s) {
      for (size_t i = 0; i < channels_; ++i) {
        const bool turns = out.drive[i] == Drive::kDrive && !(stalled_mask & (1u << i));
        const double rate = turns ? out.duty[i] * kTendonSpeedMPerS : 0.0;
        counts[i] += rate * tick_us * 1e-6 / kTendonMPerCount;
      }
      now_us += tick_us;
      Inputs in{};
      const bool sample = (now_us / 12500u) != ((now_us - tick_us) / 12500u);
      for (size_t i = 0; i < channels_; ++i) {
        in.encoder_counts[i] = static_cast<int32_t>(counts[i]);
        in.raw_counts[i] = kRawOffset + static_cast<int32_t>(kRawPerN * tension_n(i));
        if (sample && !(silenced_mask & (1u << i))) in.new_sample_mask = static_cast<ChannelMask>(in.new_sample_mask | (1u << i));
      }
      out = fw.tick(now_us, in);
      drain();
    }
  }

  // Runs while sending PING every 100 ms, so the watchdog stays fed.
  void run_fed(double seconds) {
    for (int k = 0; k < static_cast<int>(seconds * 10 + 0.5); ++k) {
      send(msg::Ping{});
      run(0.1);
    }
  }

  float length_m(size_t i) const { return static_cast<float>(counts[i]) * kTendonMPerCount; }
  float tension_n(size_t i) const { return pretension_n - stiffness_n_per_m * length_m(i) + extra_tension_n[i]; }

 private:
  void drain() {
    uint8_t buf[256];
    size_t n;
    while ((n = fw.take_tx(buf, sizeof buf)) > 0) {
      for (size_t i = 0; i < n; ++i) {
        if (decoder_.push(buf[i])) parse(decoder_.frame());
      }
    }
  }

  void parse(const RawFrame& f) {
    switch (static_cast<MsgType>(f.type)) {
      case MsgType::kAck: {
        msg::Ack a{};
        if (read_payload(f.payload, f.payload_size, a)) {
          ++replies.acks;
          replies.last_acked_seq = a.acked_seq;
        }
        break;
      }
      case MsgType::kNack: {
        msg::Nack n{};
        if (read_payload(f.payload, f.payload_size, n)) {
          ++replies.nacks;
          replies.last_nack_error = n.error;
          replies.last_acked_seq = n.acked_seq;
        }
        break;
      }
      case MsgType::kHelloReply:
        if (read_payload(f.payload, f.payload_size, replies.hello)) ++replies.hello_replies;
        break;
      case MsgType::kTelemetry:
        if (read_payload(f.payload, f.payload_size, replies.last)) ++replies.telemetry;
        break;
      default:
        break;
    }
  }

  size_t channels_;
  FrameDecoder decoder_;
  uint16_t seq_ = 0;
};

}  // namespace bench
