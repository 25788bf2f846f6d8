"""Tensions bounded by construction, on the twin with its ground truth.

The firmware does not only trip at the tension limit, it bounds tension (firmware/PROTOCOL.md,
"Tension bound"): a motor winds in with at most 0.9 of the limit as stall force and no faster
than a blow of its tendon snapping taut allows, no motor resists its tendon with more than that
cap (a spool pulled out by a load, one flying out, one braked), a motor that stops brakes until
its spool has stood still in the brake, length and tension targets ramp. So no sequence of commands the board accepts may drive a true tendon
tension (the twin's, at every physics step, between load-cell samples too) above 1.2× the limit,
whatever the calibration within the bounds the board accepts.

The property is checked on random sequences: length steps up to the accepted ±50 mm on any
channels, pair setpoints, tension setpoints up to the limit, mode switches, disable/enable,
calibrations anywhere in the accepted bounds (their extremes included) and tip masses of 0–20 g,
at the default 6 N limit and at 2 N. The fixture hangs a tip mass in zero time, a blow no
command gives and no firmware can soften (the spool's inertia holds the tendon while the mass
drops); the bound is checked from when the load has settled, and the largest such blow is
reported apart. Tip masses up to 20 g include loads whose statics alone ask more than the 2 N
limit (m·g·L/r: 20 g on the 60 mm segment at the 4.5 mm tendon radius is 2.6 N of tension
difference across the pair); where the pretension and the backbone do not make up the
difference, the motor yields at its cap and the board trips (a test below hangs 40 g).

The twin runs with 1.25 ms physics steps here, not its 5 ms. A slack tendon that goes taut within
one step engages with a spike of about stiffness × step × closing speed (twin/sim/model.py,
INEXTENSIBLE_COMPLIANCE_M_PER_N), which the plant's shorter engagement steps avoid only where the
last step foretells the tendon closing; when it closes faster (the rod jerked by another tendon,
a spool braked under a falling rod), the spike is no tension a rig would see: sequences that
peaked at 1.2 to 3.8× the limit with 5 ms steps (up to 1.7× with 2.5 ms) peak at 0.66 to 0.95×
with 1.25 ms, and within 0.02× of that with 0.625 ms. The board still ticks every 5 ms.

The properties hold with tendon friction on too (μ = 0.3 per radian: the tension loop used to
cycle under friction, see tests/test_settling.py). ``python tests/test_tension_bound.py 2000 [SEED
[MU]]`` runs that many sequences and prints the worst peaks.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from twin.driver import CommandRejected, Device, open_device
from twin.driver import codec as c
from twin.driver.device import GAIN_TOLERANCE
from twin.params import load_params

PARAMS = load_params()
# The twin for the property: engagement spikes of 5 ms steps kept out (see above).
PROPERTY_PARAMS = PARAMS.replace({"sim.timestep_s": 0.00125})
BOUND = 1.2
LIMITS_N = (6.0, 2.0)
SEQUENCES_PER_LIMIT = 40
# Tendon friction (μ per radian) the properties are checked with too: the most the control loops
# are held to settle under (tests/test_settling.py). A friction twin steps ~8x slower, hence
# fewer sequences with it.
FRICTION = 0.3
FRICTION_SEQUENCES_PER_LIMIT = 6
STEPS_PER_SEQUENCE = 10
# What a tip mass hung at once is given to come to rest before the bound applies again (s).
LOAD_SETTLE_S = 0.5


def random_calibration(rng: np.random.Generator) -> dict:
    """A calibration the board accepts: per channel the nominal gain, or either extreme of the
    accepted range, or anywhere between; offsets a few hundred counts off the twin's."""
    nominal = PARAMS.sensors.loadcell_gain_counts_per_n
    low, high = nominal / GAIN_TOLERANCE, nominal * GAIN_TOLERANCE
    if rng.random() < 0.5:
        gains = rng.choice([low, nominal, high], 4)
    else:
        gains = rng.uniform(low, high, 4)
    offsets = np.asarray(PARAMS.sensors.loadcell_offset_counts) + rng.uniform(-2000.0, 2000.0, 4)
    return {"gain_counts_per_n": gains.tolist(), "offset_counts": offsets.tolist()}


class Sequence:
    """One random run of accepted commands on a reset twin; peaks in multiples of the limit."""

    def __init__(self, device: Device, rng: np.random.Generator, limit_n: float):
        self.device, self.rng, self.limit_n = device, rng, limit_n
        self.twin = device.twin
        self.history: list[tuple] = []
        self.load_blow = 0.0
        self._earlier_peak = 0.0  # the largest peak of the stretches before the last load blow

    def run(self, steps: int = STEPS_PER_SEQUENCE) -> float:
        from twin.control.pretension import pretension_straight

        device, rng = self.device, self.rng
        device.twin.reset(int(rng.integers(1 << 30)))
        device.reconnect()
        device.fixture.settle_s = 0.3
        self.mode = str(rng.choice(["lengths", "pairs", "tensions"]))
        self.zero_m = pretension_straight(device, PARAMS, mode=self.mode, calibration=random_calibration(rng),
                                          limit_n=self.limit_n)
        device.fixture.settle_s = 0.0
        self.twin.clear_peak_tensions()
        for _ in range(steps):
            try:
                self._action(int(rng.integers(8)))
            except CommandRejected as exc:
                # Refused: the board faulted meanwhile (or refused a state change). Go on after
                # an ENABLE most of the time, an accepted command that clears the fault.
                self.history.append(("refused", exc.error))
                if device.latest().state is c.State.FAULT and rng.random() < 0.7:
                    try:
                        device.enable()
                    except CommandRejected:
                        pass
            device.wait(float(rng.uniform(0.05, 1.0)))
            self.history[-1] += (round(self.peak(), 3),)
        return self.peak()

    def peak(self) -> float:
        """The largest true tension so far (× limit), but for the blows of tip masses hung."""
        return max(self._earlier_peak, float(self.twin.peak_tensions_n().max()) / self.limit_n)

    def _set_mode(self, mode: str) -> None:
        if self.mode != mode:
            self.device.set_mode(mode)
            self.mode = mode

    def _action(self, action: int) -> None:
        device, rng = self.device, self.rng
        if action <= 1:
            self._set_mode("lengths")
            step = np.where(rng.random(4) < 0.5, rng.uniform(-0.05, 0.05, 4) * rng.choice([1.0, 0.1]), 0.0)
            self.history.append(("lengths mm", np.round(step * 1e3, 2).tolist()))
            device.set_lengths(np.clip(self.zero_m + step, -0.05, 0.05))
        elif action == 2:
            self._set_mode("pairs")
            pairs = rng.uniform(-0.05, 0.05, 2) * rng.choice([1.0, 0.1])
            self.history.append(("pairs mm", np.round(pairs * 1e3, 2).tolist()))
            device.set_pairs(pairs)
        elif action == 3:
            self._set_mode("tensions")
            tensions = rng.uniform(0.0, self.limit_n, 4)
            self.history.append(("tensions N", np.round(tensions, 2).tolist()))
            device.set_tensions(tensions)
        elif action == 4:
            self.mode = str(rng.choice(["lengths", "pairs", "tensions"]))
            self.history.append(("mode", self.mode))
            device.set_mode(self.mode)
        elif action == 5:
            self.history.append(("disable, enable",))
            device.disable()
            device.wait(float(rng.uniform(0.0, 0.3)))
            device.enable()
        elif action == 6:
            mass_kg = float(rng.uniform(0.0, 0.020))
            self.history.append(("tip g", round(mass_kg * 1e3, 1)))
            self._earlier_peak = self.peak()
            self.twin.clear_peak_tensions()
            device.fixture.hang_tip_mass(mass_kg)
            device.wait(LOAD_SETTLE_S)
            self.load_blow = max(self.load_blow, float(self.twin.peak_tensions_n().max()) / self.limit_n)
            self.twin.clear_peak_tensions()
        else:
            calibration = random_calibration(rng)
            gains = np.asarray(calibration["gain_counts_per_n"]) / PARAMS.sensors.loadcell_gain_counts_per_n
            self.history.append(("calibration × nominal", np.round(gains, 2).tolist()))
            device.disable()
            device.set_calibration(**calibration)
            device.enable()


def run_sequences(count_per_limit: int, *, seed: int, friction: float = 0.0) -> dict:
    """Worst peak (× limit) per limit over ``count_per_limit`` sequences each, with its history,
    on the twin with tendon friction μ = ``friction``."""
    rng = np.random.default_rng(seed)
    worst: dict[float, tuple[float, list]] = {limit: (0.0, []) for limit in LIMITS_N}
    load_blow = 0.0
    params = PROPERTY_PARAMS.replace({"effects.tendon_friction_coeff": friction})
    with open_device("sim://?seed=0", params=params) as device:
        for k in range(count_per_limit * len(LIMITS_N)):
            limit = LIMITS_N[k % len(LIMITS_N)]
            sequence = Sequence(device, rng, limit)
            peak = sequence.run()
            load_blow = max(load_blow, sequence.load_blow)
            if peak > worst[limit][0]:
                worst[limit] = (peak, sequence.history)
    return {"worst": worst, "load_blow": load_blow}


@pytest.mark.parametrize("friction", [0.0, FRICTION])
def test_no_accepted_command_sequence_drives_a_tendon_over_1_2_times_the_limit(record_property, friction):
    count = FRICTION_SEQUENCES_PER_LIMIT if friction else SEQUENCES_PER_LIMIT
    result = run_sequences(count, seed=20261201, friction=friction)
    for limit, (peak, history) in result["worst"].items():
        record_property(f"worst_peak_over_limit_{limit:g}_n_friction_{friction:g}", peak)
        print(f"limit {limit:g} N, μ {friction:g}: worst true peak {peak:.3f} × limit")
        assert peak <= BOUND, f"limit {limit} N: true peak {peak:.3f} × limit after {history}"
    # Every sequence did drive the tendons: the property is not met by a board that never moved.
    assert min(peak for peak, _ in result["worst"].values()) > 0.5


@pytest.mark.parametrize("step_mm, friction", [(2, 0.0), (5, 0.0), (10, 0.0), (25, 0.0), (50, 0.0), (10, FRICTION)])
def test_a_length_step_the_board_accepts_stays_within_the_bound(step_mm, friction):
    # Before the bound, these steps gave true peaks of 7.8 to 58 N against the 6 N limit: the
    # spool ran at up to full speed into the tendon and coasted on after the trip.
    from twin.control.pretension import pretension_straight

    params = PARAMS.replace({"effects.tendon_friction_coeff": friction})
    with open_device("sim://?seed=0", params=params) as device:
        zero = pretension_straight(device, params, mode="lengths")
        device.twin.clear_peak_tensions()
        target = zero.copy()
        target[0] -= step_mm * 1e-3
        device.set_lengths(target)
        device.wait(3.0)
        peak_n = device.twin.peak_tensions_n().max()
        sample = device.latest()
    assert peak_n <= BOUND * PARAMS.rig.tension_limit_n
    # The tendon did pull: up to what a stalled motor may (0.9 of the limit) for the large steps.
    assert peak_n > 2.0
    if step_mm >= 10:
        # Out of reach within the limit: the motor pulled at its cap against a still spool, and
        # the board said so instead of holding the tendon there.
        assert sample.state is c.State.FAULT and sample.fault_flags & c.Fault.TENSION_LIMIT


@pytest.mark.parametrize("friction", [0.0, FRICTION])
def test_a_tip_load_the_limit_cannot_hold_makes_the_motor_yield(friction):
    # 40 g at the tip asks m·g·L/r = 5.2 N of the upper tendon to hold the segment where it is,
    # 2.6× the 2 N limit: no firmware can hold it within the limit. The motor yields (pulling,
    # then braking, with no more than its cap), the board trips, and once the blow of the mass
    # hung at once has passed the tendon stays within the bound while the segment sinks.
    from twin.control.pretension import pretension_straight

    limit_n, mass_kg = 2.0, 0.040
    statics_n = mass_kg * PARAMS.environment.gravity_m_s2 * PARAMS.backbone.length_m / PARAMS.tendons.radius_m
    assert statics_n > 2.0 * limit_n
    params = PARAMS.replace({"effects.tendon_friction_coeff": friction})
    with open_device("sim://?seed=0", params=params) as device:
        zero = pretension_straight(device, params, mode="lengths", limit_n=limit_n)
        device.fixture.settle_s = 0.0
        device.fixture.hang_tip_mass(mass_kg)
        device.wait(LOAD_SETTLE_S)
        device.twin.clear_peak_tensions()
        device.wait(2.0)
        peak_n = device.twin.peak_tensions_n().max()
        sample = device.latest()
    assert peak_n <= BOUND * limit_n
    assert sample.state is c.State.FAULT and sample.fault_flags & c.Fault.TENSION_LIMIT
    # The upper tendon gave way by millimetres: yielded, not held.
    assert (sample.tendon_lengths_m - zero).max() > 2e-3


@pytest.mark.parametrize("mode, friction", [("lengths", 0.0), ("tensions", 0.0), ("lengths", FRICTION),
                                            ("tensions", FRICTION)])
def test_a_load_cell_reading_ten_times_low_cannot_blind_the_limit(mode, friction):
    # The calibration is the nominal one and accepted; the cell itself reads a tenth (a wrong
    # cell, or a tendon off its pulley). Before, such a reading held 14 N on the tendon in
    # tension mode with no fault. Now the stalled motor's pull gives it away: the board faults,
    # in tension mode as soon as it is enabled and pulls, in length mode when the pull comes.
    from twin.control.pretension import pretension_straight

    params = PARAMS.replace({"effects.tension_gain_error": [-0.9, 0.0, 0.0, 0.0],
                             "effects.tendon_friction_coeff": friction})
    with open_device("sim://?seed=0", params=params) as device:
        zero = pretension_straight(device, params, mode=mode, tension_n=1.0)
        device.twin.clear_peak_tensions()
        if device.latest().enabled:
            if mode == "tensions":
                device.set_tensions([3.0, 1.0, 1.0, 1.0])
            else:
                device.set_lengths(zero - np.array([0.01, 0.0, 0.0, 0.0]))
            device.wait(2.0)
        sample = device.latest()
        peak_n = device.twin.peak_tensions_n()[0]
    assert sample.state is c.State.FAULT
    assert sample.fault_flags & c.Fault.LOADCELL_IMPLAUSIBLE and sample.fault_flags & c.Fault.IMPLAUSIBLE_CHANNEL_1
    assert peak_n <= BOUND * PARAMS.rig.tension_limit_n


def test_twin_validate_drives_the_board_with_the_configured_limit(tmp_path, capsys):
    # Before, --set rig.tension_limit_n was never sent: the board kept its 6 N and the sweep ran.
    # Every ENABLE now goes with the configured limit, which the 1.35 N pretension exceeds.
    from twin.cli import main as twin

    code = twin(["validate", "--quick", "--set", "rig.tension_limit_n=0.5", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code != 0 and "TENSION_LIMIT" in err, err[-2000:]


def test_a_board_that_restarted_drives_with_the_configured_limit_again():
    # A power-cycled board is back at its 6 N default; the host's next ENABLE sends the
    # parameter set's 3 N. The ground truth shows which one the board bounds tension with.
    params = PARAMS.replace({"rig.tension_limit_n": 3.0})
    with open_device("sim://?seed=0", params=params) as device:
        device.twin.reset()
        device.reconnect()
        device.tare()
        device.enable()
        device.twin.clear_peak_tensions()
        device.set_lengths([-0.01, 0.0, 0.01, 0.0])
        device.wait(3.0)
        peak_n = device.twin.peak_tensions_n()[0]
        sample = device.latest()
    # Pulled with all a motor may under a 3 N limit (0.9 of it), not under 6 N.
    assert 2.0 < peak_n <= BOUND * 3.0
    assert sample.state is c.State.FAULT and sample.fault_flags & c.Fault.TENSION_LIMIT


def test_a_robot_with_other_motors_is_bounded_by_its_own_motors():
    # The stiff, long robot (30 N limit, 5 kg cells) on motors of four times the thesis's stall
    # torque (2 N·m: 615 N at the tendon) and a heavier rotor. The host sends them (SET_MOTORS);
    # a board bounding the duty by the thesis's 154 N would let the plant's motor pull 4 × 0.9 of
    # the limit (108 N). A step out of reach pulls at the cap of these motors, 0.9 of the limit,
    # until the board trips the tension limit for a motor held at its cap against a still spool.
    from twin.control.pretension import pretension_straight
    from twin.robots import load_robot

    params = load_robot("stiff-long").replace({"rig.motor_stall_torque_nm": 2.0, "rig.motor_rotor_inertia_kgm2": 4e-6})
    limit_n = params.rig.tension_limit_n
    stall_n = params.rig.motor_stall_force_n
    assert stall_n == pytest.approx(4 * PARAMS.rig.motor_stall_force_n)
    with open_device("sim://?seed=0", params=params) as device:
        # The thesis motor's length gains, 4x the pull per metre that the board's defaults for
        # these motors ask: the loop saturates within the wait, and the cap is what holds it.
        device.set_gains("lengths", kp=60.0, ki=100.0, kd=0.0)
        zero = pretension_straight(device, params, mode="lengths")
        device.twin.clear_peak_tensions()
        target = zero.copy()
        target[0] -= 0.02
        device.drain()
        device.set_lengths(target)
        samples = []
        true_n = 0.0  # tendon 0's true tension the last time the board was seen driving
        for _ in range(60):
            device.wait(0.05)
            samples += device.drain()
            if samples and samples[-1].state is not c.State.ENABLED:
                break
            true_n = device.twin.true_tensions_n()[0]
        peak_n = device.twin.peak_tensions_n().max()
        duty = min(s.motor_commands[0] for s in samples)
    assert duty == pytest.approx(-0.9 * limit_n / stall_n, rel=0.02)
    assert true_n == pytest.approx(0.9 * limit_n, rel=0.05)
    assert peak_n <= BOUND * limit_n
    assert samples[-1].state is c.State.FAULT and samples[-1].fault_flags & c.Fault.TENSION_LIMIT


def test_weaker_motors_settle_a_bend_with_the_boards_default_gains():
    # 0.15 N·m on the stiff robot: 46 N at the tendon, 1.5x its 30 N limit. The board's default
    # length gains (duty per m) were made for the thesis's 154 N; with SET_MOTORS they are scaled to
    # ask the same pull of these motors. Unscaled, the bent robot did not come to rest in 6 s.
    from twin.control.pretension import pretension_straight
    from twin.experiments.protocols import wait_for_rest
    from twin.pcc import tendon_length_changes_m
    from twin.robots import load_robot

    params = load_robot("stiff-long").replace({"rig.motor_stall_torque_nm": 0.15})
    with open_device("sim://?seed=0", params=params) as device:
        zero = pretension_straight(device, params, mode="lengths")
        device.set_lengths(zero + tendon_length_changes_m(7.0, 180.0, params))
        wait_for_rest(device, tension_tolerance_n=np.inf, timeout_s=6.0)
        assert device.latest().state is c.State.ENABLED


def test_a_rig_with_another_spool_gearbox_and_encoder_runs_on_its_emulated_board():
    # The emulated board counts its plant's encoders as that rig's (1.23 µm a count here, not the
    # thesis's 0.94): the host accepts it, and the lengths the board reports are the spools' travel.
    from twin.control.pretension import pretension_straight

    params = PARAMS.replace({"rig.spool_radius_m": 0.004, "rig.gear_ratio": 5.0, "rig.encoder_counts_per_rev": 2048})
    count_m = params.rig.tendon_m_per_count
    with open_device("sim://?seed=0", params=params) as device:
        assert device.info.tendon_m_per_count == pytest.approx(count_m, rel=1e-6)
        zero = pretension_straight(device, params, mode="lengths")
        spools = device.twin.spool_positions_m()
        target = zero.copy()
        target[0] -= 0.0003
        device.set_lengths(target)
        device.wait(2.0)
        moved = device.twin.spool_positions_m() - spools
        sample = device.latest()
    assert sample.state is c.State.ENABLED
    assert moved[0] < -0.0002
    assert np.allclose(sample.tendon_lengths_m - zero, moved, atol=2 * count_m)


def test_motors_the_firmware_cannot_bound_are_refused_on_the_host():
    from twin.params import ParameterError

    with pytest.raises(ParameterError, match=r"stall_force_n = 0\.3\d*: must be in 1\.\.10000 N.*rig\.motor_stall_torque_nm"):
        PARAMS.replace({"rig.motor_stall_torque_nm": 0.001})
    with pytest.raises(ValueError, match=r"motors: reflected_mass_kg = 0\.0: must be in 0\.01\.\.1000 kg"):
        Device(None, motors=c.SetMotors(reflected_mass_kg=0.0))  # type: ignore[arg-type]


def main(argv: list[str]) -> int:
    count = int(argv[0]) if argv else 1000
    seed = int(argv[1]) if len(argv) > 1 else 0
    friction = float(argv[2]) if len(argv) > 2 else 0.0
    result = run_sequences(count, seed=seed, friction=friction)
    for limit, (peak, history) in result["worst"].items():
        print(f"limit {limit:g} N: worst true peak {peak:.3f} × limit over {count} sequences")
        for entry in history:
            print("   ", entry)
    print(f"largest blow of a tip mass hung at once: {result['load_blow']:.2f} × limit")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
