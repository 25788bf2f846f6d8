"""The shadow's naming on a stiff, long robot: a tip load that barely moves the tip within its band
while the tensions holding it change, and a step that rings as the rod rings on both sides."""

import numpy as np
import pytest

from twin.params import load_params
from twin.shadow import FrameValues, Monitor

PARAMS = load_params()
N = PARAMS.tendons.count
PERIOD_S = 0.025
# A stiff rod's rod model: the tip moves 8 mm per N of tendon 0's tension (along y) and 20 mm per N
# at the tip (a hundredth of a soft endoscope's 2 m/N): a 0.2 N load moves it 4 mm.
WRT_TENSION = np.zeros((3, N))
WRT_TENSION[1, 0] = 8e-3
WRT_FORCE = 0.02 * np.eye(3)


def _jacobian(tensions_n):
    return WRT_TENSION, WRT_FORCE


def _frames(rng, count, start_s=0.0, *, twin_swing_n=0.0):
    """Device and twin frames that differ by sensor noise only; the tip's noise 0.2 mm, with a
    warm-up excursion of 1 mm on the device's tip for five frames every 5 s (a transient of the
    motion that widens the tip's band); with ``twin_swing_n`` both sides' tensions swing together
    from frame to frame (a stiff rod ringing on both sides)."""
    for k in range(count):
        t = start_s + k * PERIOD_S
        lengths = 1e-3 * np.sin(2 * np.pi * 0.3 * t + np.arange(N))
        tensions = 1.5 + 0.5 * np.sin(2 * np.pi * 0.3 * t + np.arange(N)) + twin_swing_n * (-1) ** k
        tip = np.array([0.06, 0.005 * np.sin(t), 0.005 * np.cos(t)])
        device_tip = tip + rng.normal(0, 2e-4, 3)
        if round(t / PERIOD_S) % 200 < 5:
            device_tip[1] += 1e-3
        yield (FrameValues(t, lengths.copy(), tensions + rng.normal(0, 0.01, N), np.zeros(N), device_tip),
               FrameValues(t, lengths, tensions, np.zeros(N), tip))


def _learned(rng, **kwargs):
    monitor = Monitor(PARAMS, warmup_s=10.0, jacobian=_jacobian)
    frames = int(10.0 / PERIOD_S) + 1
    for device, twin in _frames(rng, frames, **kwargs):
        monitor.update(device, twin, tip_frame_time_s=device.time_s)
    assert monitor.ready
    return monitor, frames * PERIOD_S


def _first(monitor, rng, start, d_ten, d_tip, **kwargs):
    for device, twin in _frames(rng, 40, start, **kwargs):
        changed = FrameValues(device.time_s, device.lengths_m, device.tensions_n + d_ten, device.duty,
                              device.tip_m + d_tip)
        raised = monitor.update(changed, twin, tip_frame_time_s=device.time_s)
        if raised:
            return raised[0]
    return None


@pytest.mark.parametrize("cause", ["tip_load", "loadcell_offset", "tendon_slip"])
def test_a_tip_load_within_the_tips_band_is_told_from_a_cell_and_a_slip_by_where_the_tip_went(cause):
    """Tendon 0's tension falls 0.5 N (a slip's raises the others' 0.2 N). A load cell's change
    leaves the tip where the twin's is; a slip moves it as the rod model says for the tensions (4 mm
    along −y); a 0.45 N push along +y, which those tensions hold back, moves it 9 − 4 = 5 mm along
    +y: within the tip's band (6 mm, widened by the warm-up's 1 mm transients) but far beyond the
    tip's spread. Each is named so; before, the tip load was named the cell's offset."""
    rng = np.random.default_rng(4)
    monitor, start = _learned(rng)
    d_ten = np.zeros(N)
    d_ten[0] = -0.5
    if cause == "tendon_slip":
        d_ten[1:] = 0.2
    d_tip = {"tip_load": WRT_TENSION @ d_ten + WRT_FORCE @ np.array([0.0, 0.45, 0.0]),
             "loadcell_offset": np.zeros(3), "tendon_slip": WRT_TENSION @ d_ten}[cause]
    band = monitor.noise.band[3 * N:]
    assert np.all(np.abs(d_tip) < band), "the tip left its band: the test shows nothing"
    first = _first(monitor, rng, start, d_ten, d_tip)
    assert first is not None and "tension[0]" in first.where
    assert first.kind == cause
    if cause == "tip_load":
        assert first.detail["force_n"][1] == pytest.approx(0.45, abs=0.1)


def test_a_step_that_rings_where_the_twin_rings_as_much_is_not_a_latency():
    """Both sides' tensions swing 1 N from frame to frame (the rod rings on both); the device's
    tendon 0 slips, its tension falling 0.2 N and the others' rising 0.08 N at once, and its cell
    rings ±0.5 N off the twin's, at a third of the frame rate, which no lag of the twin's swinging
    tensions fits: not a late loop (as ringing off a quiet twin is), the step is named, a slip (the tip
    moving as the tensions say)."""
    rng = np.random.default_rng(6)
    monitor, start = _learned(rng, twin_swing_n=1.0)
    step = np.full(N, 0.08)
    step[0] = -0.2
    first = None
    for k, (device, twin) in enumerate(_frames(rng, 40, start, twin_swing_n=1.0)):
        d_ten = np.zeros(N)
        if k >= 5:
            d_ten = step.copy()
            d_ten[0] += 0.6 * np.sin(2 * np.pi * k / 3)
        changed = FrameValues(device.time_s, device.lengths_m, device.tensions_n + d_ten, device.duty,
                              device.tip_m + WRT_TENSION @ (step if k >= 5 else np.zeros(N)))
        raised = monitor.update(changed, twin, tip_frame_time_s=device.time_s)
        if raised:
            first = raised[0]
            break
    assert first is not None
    assert first.detail.get("ringing_n", 0.0) > monitor.noise.ring_band_n, "no ringing: the test shows nothing"
    assert first.detail["twin_ringing_n"] > first.detail["ringing_n"]
    assert first.kind == "tendon_slip"
    assert first.detail["tendon"] == 0


def _sliding(rng, count, start_s=0.0, *, lag_s=0.0, friction_m_per_n=0.0):
    """Tendons swinging ±1 mm at 0.3 Hz, each a quarter period after the last, their tensions
    500 N/m stiff about 1.5 N; the device's encoders either a lag behind the twin's or held back
    by friction (``friction_m_per_n`` per N of tension, behind the sliding)."""
    count_m = PARAMS.rig.tendon_m_per_count
    phase = np.arange(N) * np.pi / 2
    for k in range(count):
        t = start_s + k * PERIOD_S
        lengths = 1e-3 * np.sin(2 * np.pi * 0.3 * t + phase)
        rate = np.cos(2 * np.pi * 0.3 * t + phase)
        tensions = 1.5 - 500.0 * lengths
        device_lengths = (1e-3 * np.sin(2 * np.pi * 0.3 * (t - lag_s) + phase)
                          - friction_m_per_n * np.sign(rate) * tensions
                          + count_m * rng.integers(-1, 2, N))
        tip = np.array([0.06, 0.0, 0.0])
        yield (FrameValues(t, device_lengths, tensions + rng.normal(0, 0.01, N), np.zeros(N),
                           tip + rng.normal(0, 2e-4, 3)),
               FrameValues(t, lengths, tensions, np.zeros(N), tip))


@pytest.mark.parametrize("cause", ["friction", "latency"])
def test_encoders_held_back_by_friction_are_friction_and_lagging_ones_a_latency(cause):
    """The cells read as the twin's; the encoders part from the twin's by 20 counts at most, either
    held back by friction in proportion to each tendon's tension and against its sliding, or late
    in proportion to its rate: the pattern across the tendons names which (a stiff rod's loop
    answers friction with its encoders, where a soft one's cells show it)."""
    rng = np.random.default_rng(9)
    monitor = Monitor(PARAMS, warmup_s=10.0)
    frames = int(10.0 / PERIOD_S) + 1
    for device, twin in _sliding(rng, frames):
        monitor.update(device, twin, tip_frame_time_s=device.time_s)
    assert monitor.ready
    lag_m = 20 * PARAMS.rig.tendon_m_per_count
    change = {"friction": {"friction_m_per_n": lag_m / 2.0}, "latency": {"lag_s": lag_m / (2 * np.pi * 0.3 * 1e-3)}}
    raised = []
    for device, twin in _sliding(rng, 80, frames * PERIOD_S, **change[cause]):
        raised += monitor.update(device, twin, tip_frame_time_s=device.time_s)
    assert raised and any(name.startswith("length") for name in raised[0].where)
    assert not any(name.startswith("tension") for name in raised[0].where), "the cells crossed: the test shows nothing"
    assert raised[0].kind == cause


def test_a_slip_whose_tip_goes_astray_is_not_a_tip_load_where_its_tensions_do_not_hold_the_tip_back():
    """A slip's tensions (tendon 0 −0.5 N, the others +0.2 N) would move the tip 4 mm along −y;
    the tip goes 5 mm along z instead (the rod model off). A force at the tip fits that move better
    than the tensions do by far, but those tensions push the tip across the force, not back
    against it, as a tip load's must: the tensions' change is named (a slip), not a tip load."""
    rng = np.random.default_rng(4)
    monitor, start = _learned(rng)
    d_ten = np.full(N, 0.2)
    d_ten[0] = -0.5
    d_tip = np.array([0.0, 0.0, 5e-3])
    assert np.all(np.abs(d_tip) < monitor.noise.band[3 * N:]), "the tip left its band: the test shows nothing"
    first = _first(monitor, rng, start, d_ten, d_tip)
    assert first is not None
    assert first.detail["tip_chi2_margin"] > 16.0, "a force does not fit better: the test shows nothing"
    assert first.kind == "tendon_slip"
