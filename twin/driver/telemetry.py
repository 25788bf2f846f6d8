"""What a device reports, in host units: telemetry samples and the board's identity.

:class:`Telemetry` is the host's view of one 40 Hz TELEMETRY frame (arrays, SI units, enums);
:class:`DeviceInfo` is what the handshake told the host. Both are produced by
:class:`twin.driver.Device` whatever the backend.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING

import numpy as np

from twin.driver import codec

if TYPE_CHECKING:
    # The transport imports the inbox, which imports this module.
    from twin.driver.transport import Clock

__all__ = ["DeviceInfo", "Telemetry"]

@dataclasses.dataclass(frozen=True, eq=False)
class Telemetry:
    """One telemetry sample; N is the board's channel count (:attr:`DeviceInfo.channels`).

    Attributes:
        time_s: device time of the sample (s since the board's first tick): simulated time on
            ``sim://``, the board's clock on ``serial://``.
        seq: the board's sample counter; a gap means samples were lost on the way.
        encoder_counts: (N,) int64 raw quadrature counts (no origin applied).
        encoder_history_counts: (K, N) int64 raw counts at each of the K board ticks since the
            sample before (:data:`codec.TELEMETRY_TICKS`, 5 ms apart), oldest first, the last
            this sample's own ``encoder_counts``; a tick more than 32767 counts (31 mm) away
            from this sample reads that far. Computed on first use.
        encoder_history_deltas: the same as the board sends them: K·N differences (counts)
            from ``encoder_counts``, tick by tick.
        tendon_lengths_m: (N,) relative tendon lengths (m, from the last tare; positive = paid out).
        raw_counts: (N,) int64 latest HX711 readings (counts).
        tensions_n: (N,) calibrated tensions (N).
        targets: (N,) per-motor targets: m in the length modes, N in tension mode.
        motor_commands: (N,) duty per motor in [-1, 1]; positive pays tendon out.
        drives: per motor :class:`codec.Drive` (coast, drive, brake).
        state: :class:`codec.State` (disabled, enabled, fault).
        mode: :class:`codec.Mode` (lengths, pairs, tension).
        fault_flags: :class:`codec.Fault` flags (watchdog and tension limit latch until enable).
        stale_mask: bit i set while load cell i is stale.
        rx_bad_frames: frames the board dropped for framing or CRC errors, since power-up.
        tx_dropped_frames: frames the board could not send (its queue was full), since power-up.
        received_s: when the host had the sample, in the transport's clock (simulated seconds
            on ``sim://``, :func:`time.monotonic` seconds on ``serial://``).
    """

    time_s: float
    seq: int
    encoder_counts: np.ndarray
    tendon_lengths_m: np.ndarray
    raw_counts: np.ndarray
    tensions_n: np.ndarray
    targets: np.ndarray
    motor_commands: np.ndarray
    drives: tuple[codec.Drive, ...]
    state: codec.State
    mode: codec.Mode
    fault_flags: codec.Fault
    stale_mask: int
    rx_bad_frames: int
    tx_dropped_frames: int
    received_s: float
    encoder_history_deltas: tuple[int, ...]

    @functools.cached_property
    def encoder_history_counts(self) -> np.ndarray:
        # Built on first use: the env and the controllers read only the sample's own counts.
        history = np.array(self.encoder_history_deltas, dtype=np.int64).reshape(codec.TELEMETRY_TICKS, -1)
        history += self.encoder_counts
        return history

    @classmethod
    def from_message(cls, message: codec.TelemetryMessage, received_s: float) -> "Telemetry":
        """The host view of a decoded TELEMETRY message received at ``received_s``."""
        return cls(
            time_s=message.time_us / 1e6,
            seq=message.sample_seq,
            encoder_counts=np.array(message.encoder_counts, dtype=np.int64),
            tendon_lengths_m=np.array(message.lengths_m, dtype=float),
            raw_counts=np.array(message.raw_counts, dtype=np.int64),
            tensions_n=np.array(message.tensions_n, dtype=float),
            targets=np.array(message.targets, dtype=float),
            motor_commands=np.array(message.duty, dtype=float),
            drives=message.drives(),
            state=codec.enum_member(codec.State, message.state),
            mode=codec.enum_member(codec.Mode, message.mode),
            fault_flags=codec.enum_member(codec.Fault, message.fault_flags),
            stale_mask=message.stale_mask,
            rx_bad_frames=message.rx_bad_frames,
            tx_dropped_frames=message.tx_dropped_frames,
            received_s=received_s,
            encoder_history_deltas=message.encoder_history,
        )

    @property
    def enabled(self) -> bool:
        return self.state is codec.State.ENABLED


@dataclasses.dataclass(frozen=True)
class DeviceInfo:
    """The board as the handshake described it.

    Attributes:
        url: the device URL.
        clock: how the device's time advances (:attr:`twin.driver.Device.clock`).
        protocol_version: the board's protocol version (equal to the host's once connected).
        firmware_version: (major, minor, patch).
        channels: motors / load cells (the robot's tendon count once connected).
        control_period_s: PID period (s), 0.01.
        telemetry_period_s: telemetry period (s), 0.025.
        tendon_m_per_count: tendon length per encoder count (m).
    """

    url: str
    clock: Clock
    protocol_version: int
    firmware_version: tuple[int, int, int]
    channels: int
    control_period_s: float
    telemetry_period_s: float
    tendon_m_per_count: float

    @classmethod
    def from_reply(cls, reply: codec.HelloReply, *, url: str, clock: Clock) -> "DeviceInfo":
        return cls(
            url=url,
            clock=clock,
            protocol_version=reply.protocol_version,
            firmware_version=(reply.firmware_version[0], reply.firmware_version[1], reply.firmware_version[2]),
            channels=reply.channels,
            control_period_s=reply.control_period_us / 1e6,
            telemetry_period_s=reply.telemetry_period_us / 1e6,
            tendon_m_per_count=reply.tendon_m_per_count,
        )
