"""Telemetry rate and command latency through the emulated board over a pseudo-terminal
(``twin bench device``): the serial driver, the protocol and the firmware as on the rig, with
the pseudo-terminal in place of USB.
"""

from __future__ import annotations

import time

import numpy as np

from twin.driver.device import Device
from twin.device.pty_board import PtyBoard
from twin.driver.url import open_device
from twin.params import Params, load_params

__all__ = ["bench_device"]

# Small steps of tendon 1 (m): the board must be enabled to take setpoints, and these keep the
# twin near straight.
_STEP_M = 5e-5


def bench_device(params: Params | None = None, *, rate_window_s: float = 2.0, commands: int = 40,
                 seed: int = 0) -> dict:
    """Measure the link through :class:`PtyBoard` and ``serial://``.

    Args:
        params: parameter set of the twin (default ``models/endoscope/endoscope.toml``).
        rate_window_s: wall time over which telemetry is counted (s).
        commands: length setpoints sent to time the latency.
        seed: twin noise seed; also seeds the random delays between commands.

    Returns:
        ``telemetry_rate_hz`` (samples per wall second at the host), ``device_rate_hz`` (per
        second of board time), ``lost_samples``; for the setpoint commands, ``ack_median_ms`` /
        ``ack_max_ms`` (write to ACK at the host) and ``latency_median_ms`` /
        ``latency_p95_ms`` / ``latency_max_ms`` (write to the first telemetry sample carrying
        the new target, at the host); the board's ``overruns``.
    """
    params = params if params is not None else load_params()
    rng = np.random.default_rng(seed)
    with PtyBoard(params, seed=seed) as board, open_device(board.url, params=params) as device:
        device.drain()
        device.wait(rate_window_s)
        samples = device.drain()
        span_wall_s = samples[-1].received_s - samples[0].received_s
        span_device_s = samples[-1].time_s - samples[0].time_s
        acks, latencies = _latencies(device, commands, rng)
        figures = {
            "telemetry_rate_hz": (len(samples) - 1) / span_wall_s,
            "device_rate_hz": (len(samples) - 1) / span_device_s,
            "lost_samples": device.lost_samples,
            "ack_median_ms": float(np.median(acks)) * 1e3,
            "ack_max_ms": float(np.max(acks)) * 1e3,
            "latency_median_ms": float(np.median(latencies)) * 1e3,
            "latency_p95_ms": float(np.percentile(latencies, 95)) * 1e3,
            "latency_max_ms": float(np.max(latencies)) * 1e3,
            "commands": commands,
            "overruns": board.overruns,
        }
    return figures


def _latencies(device: Device, commands: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    device.tare()
    device.set_gains("lengths", kp=60.0, ki=100.0, kd=0.0)
    device.enable()
    period_s = device.info.telemetry_period_s
    acks, latencies = [], []
    for k in range(commands):
        target = np.float32(_STEP_M if k % 2 == 0 else -_STEP_M)
        # A random phase against the 40 Hz telemetry, so the latencies sample it evenly.
        time.sleep(rng.uniform(0.0, period_s))
        start_s = time.monotonic()
        device.set_lengths([target] + [0.0] * (device.channels - 1))
        acks.append(time.monotonic() - start_s)
        sample = device.wait_next()
        while np.float32(sample.targets[0]) != target:
            sample = device.wait_next()
        latencies.append(sample.received_s - start_s)
    device.disable()
    return np.array(acks), np.array(latencies)
