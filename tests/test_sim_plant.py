"""The plant API the device layer wraps: modes, sensors and their rates, determinism, effects."""

import json

import numpy as np
import pytest

from twin.cli import main
from twin.params import load_params
from twin.sim import Plant

FAST = ["sim.elements=10"]


def _plant(*overrides, seed=0, **kw):
    return Plant(load_params(overrides=FAST + list(overrides)), seed=seed, **kw)


def test_sensors_sample_at_their_rates_and_hold_between():
    plant = _plant()
    plant.step(1.0)
    assert plant.loadcell_sample().index == 80
    assert plant.tracker_probes().index == 40
    held = plant.loadcell_sample()
    plant.step(0.005)
    assert plant.loadcell_sample() is held
    plant.step(0.01)
    assert plant.loadcell_sample().index == 81
    # Taken at the first physics step at or after its due time (the clock sums steps: 1e-9 s of
    # rounding when the step divides the period).
    assert 81 / 80 - 1e-9 <= plant.loadcell_sample().time_s < 81 / 80 + plant.timestep_s


def test_a_seed_reproduces_a_run_and_another_seed_does_not():
    runs = []
    for seed in (7, 7, 8):
        plant = _plant(seed=seed)
        plant.set_tensions([2.0, 1.35, 1.35, 1.35])
        plant.step(0.3)
        runs.append((plant.loadcell_raw_counts(), plant.tracker_probes().positions_m, plant.tip_pose()[0]))
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])
    assert not np.array_equal(runs[0][0], runs[2][0])
    assert np.array_equal(runs[0][2], runs[2][2])  # noise only touches the sensors


def test_tension_mode_holds_the_tensions_and_the_load_cells_report_them():
    params = load_params(overrides=FAST + ["sensors.loadcell_noise_n=0.0"])
    plant = Plant(params)
    tensions = np.array([2.5, 1.35, 1.0, 1.35])
    plant.set_tensions(tensions)
    assert plant.settle().settled
    assert np.allclose(plant.true_tensions_n(), tensions, atol=1e-4)
    plant.step(0.02)
    s = params.sensors
    expected = np.rint(np.asarray(s.loadcell_offset_counts) + s.loadcell_gain_counts_per_n * plant.true_tensions_n())
    assert np.array_equal(plant.loadcell_raw_counts(), expected)


def test_length_mode_places_the_spools_and_the_encoders_count_them():
    plant = _plant()
    lengths = np.array([-0.003, 0.0, 0.003, 0.0])
    plant.set_tendon_lengths(lengths)
    assert plant.settle().settled
    assert np.allclose(plant.spool_positions_m(), lengths, atol=1e-6)
    expected = lengths / plant.params.rig.tendon_m_per_count
    assert np.all(np.abs(plant.encoder_counts() - expected) <= 2)
    assert plant.true_tensions_n()[0] > 0.1          # pulled in: bends the rod, taut
    assert plant.tip_pose()[0][2] < -0.01            # horizontal base, tendon 0 below: bends down


def test_switching_from_tension_to_length_mode_keeps_the_tensions():
    plant = _plant()
    plant.set_tensions([2.35, 1.35, 1.35, 1.35])
    plant.settle()
    plant.set_tendon_lengths(plant.spool_positions_m())
    plant.settle()
    assert np.allclose(plant.true_tensions_n(), [2.35, 1.35, 1.35, 1.35], atol=0.05)


def test_pwm_pays_out_for_positive_duty_and_pulls_for_negative():
    plant = _plant()
    plant.set_tensions([1.35] * 4)
    plant.settle()
    start = plant.encoder_counts()
    plant.set_motor_pwm([-0.05, 0.01, 0.0, 0.0])
    plant.step(0.2)
    change = plant.encoder_counts() - start
    assert change[0] < -100 and change[1] > 0
    assert plant.true_tensions_n()[0] > 1.35


def test_a_slack_tendon_is_taken_up_in_short_steps_and_one_resting_slack_is_not():
    """Engaging a slack line in one full step spikes its tension (the spring is linearised where
    the step starts); the plant takes short steps only while a tendon could close that fast."""
    params = load_params(overrides=FAST)
    duty = -0.035
    plant = Plant(params)
    plant.set_tensions(np.full(4, params.tendons.pretension_n))
    plant.settle()
    plant.set_tendon_lengths([0.001, 0.0, 0.0, 0.0])  # tendon 0 slack by 1 mm
    plant.settle()
    plant.set_motor_pwm(np.zeros(4))
    plant.step(0.05)
    before, peak_n = plant.short_steps, 0.0
    for k in range(200):  # pulled in as a PID would: the duty ramps over four 5 ms ticks
        plant.set_motor_pwm([duty * min(1.0, (k + 1) / 4), 0.0, 0.0, 0.0])
        plant.step(0.005)
        peak_n = max(peak_n, plant.true_tensions_n()[0])
    assert plant.short_steps > before
    # The line engages with a bump and then loads up as the rod bends: the tension's largest
    # value is the last one (taken up in full steps, the bump is about twice that).
    assert peak_n <= plant.true_tensions_n()[0] + 0.05

    # One motor bends the rod, the other spools are braked: the tendons beside it sag to the
    # slack edge and rest there, which needs no short steps.
    plant.set_tensions(np.full(4, params.tendons.pretension_n))
    plant.settle()
    plant.set_motor_pwm([-0.02, 0.0, 0.0, 0.0])
    plant.step(1.0)
    assert plant.true_tensions_n()[1] == pytest.approx(0.0, abs=1e-3)
    resting = plant.short_steps
    plant.step(1.0)
    assert plant.short_steps == resting


def test_tip_mass_can_be_hung_and_removed():
    plant = _plant()
    plant.set_tensions([1.35] * 4)
    plant.settle()
    z0 = plant.tip_pose()[0][2]
    plant.set_tip_mass_kg(0.01)
    plant.settle()
    assert plant.tip_pose()[0][2] < z0 - 0.002
    plant.set_tip_mass_kg(0.0)
    plant.settle()
    assert plant.tip_pose()[0][2] == pytest.approx(z0, abs=1e-5)


def test_holder_keeps_the_rod_straight_while_pretensioning():
    plant = _plant()
    plant.engage_holder()
    plant.set_tensions([1.35] * 4)
    plant.settle()
    held = plant.tip_pose()[0]
    plant.release_holder()
    plant.settle()
    assert abs(held[2]) < 0.2 * abs(plant.tip_pose()[0][2])


def test_friction_makes_loading_and_unloading_differ():
    def tip_after(path):
        plant = _plant("effects.tendon_friction_coeff=0.3")
        for t in path:
            plant.set_tensions([t, 1.35, 1.35, 1.35])
            plant.settle(tol_m=1e-5)
        return plant.tip_pose()[0], plant.true_tensions_n()[0]

    loaded, t_load = tip_after([1.35, 2.5])
    unloaded, t_unload = tip_after([1.35, 3.5, 2.5])
    assert t_load == pytest.approx(2.5, abs=1e-3) and t_unload == pytest.approx(2.5, abs=1e-3)
    # Pulled in, the tip sees less than the spool; paid out, more: it bends further.
    assert unloaded[2] < loaded[2] - 1e-3


def test_friction_follows_the_spool_tension_only_up_to_twice_the_rig_limit():
    # A snap-taut spike far beyond the rig's limit, fed back as friction forces on a bent rod,
    # diverged the twin; tensions the board can hold or trip on are followed in full.
    def tip_z(*overrides):
        plant = _plant(*overrides)
        plant.set_tensions([1.35] * 4)
        plant.settle(tol_m=1e-5)
        plant.set_tensions([3.5, 1.35, 1.35, 1.35])
        assert plant.settle(tol_m=1e-5).settled
        return plant.tip_pose()[0][2]

    followed = tip_z("effects.tendon_friction_coeff=0.3", "rig.tension_limit_n=6")
    assert tip_z("effects.tendon_friction_coeff=0.3", "rig.tension_limit_n=1.8") == pytest.approx(followed, abs=1e-9)
    capped = tip_z("effects.tendon_friction_coeff=0.3", "rig.tension_limit_n=1")
    # Pulled in, tendon 0 loses less tension to the holes when the friction follows 2 N, not 3.5 N.
    assert tip_z() < capped < followed - 1e-3


def test_sensor_effects_change_only_what_the_sensor_reports():
    base = _plant("sensors.loadcell_noise_n=0.0", "sensors.tracker_noise_m=0.0", "sensors.tracker_noise_rad=0.0")
    off = _plant("sensors.loadcell_noise_n=0.0", "sensors.tracker_noise_m=0.0", "sensors.tracker_noise_rad=0.0",
                 "effects.tension_gain_error=[0.1,0,0,0]", "effects.tracker_offset_m=[0,0,0.002]")
    for plant in (base, off):
        plant.set_tensions([2.0, 1.35, 1.35, 1.35])
        plant.settle()
        plant.step(0.03)
    gain = base.params.sensors.loadcell_gain_counts_per_n
    assert np.array_equal(base.tip_pose()[0], off.tip_pose()[0])
    assert (off.loadcell_raw_counts() - base.loadcell_raw_counts())[0] == pytest.approx(0.1 * 2.0 * gain, abs=2)
    shift = off.tracker_probes().positions_m - base.tracker_probes().positions_m
    assert np.allclose(np.linalg.norm(shift, axis=1), 0.002, atol=1e-9)


def test_base_tilt_and_tip_load_error_move_the_tip():
    tips = []
    for extra in ([], ["effects.base_tilt_deg=[0,2]"], ["effects.tip_load_error_fraction=0.2"]):
        plant = _plant(*extra)
        plant.set_tensions([1.35] * 4)
        plant.set_tip_mass_kg(0.01)
        plant.settle()
        tips.append(plant.tip_pose()[0])
    assert np.linalg.norm(tips[1] - tips[0]) > 1e-3
    assert tips[2][2] < tips[0][2] - 5e-4


def test_twin_sim_command_prints_the_settled_state(capsys):
    code = main(["sim", "--tensions", "2.35,1.35,1.35,1.35", "--tip-mass-kg", "0.005", "--set", "sim.elements=10",
                 "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0
    for key in ("tip_position_m", "tip_rotation", "tendon_lengths_m", "tensions_n", "encoder_counts", "settle_time_s"):
        assert key in out
    assert out["tensions_n"][0] == pytest.approx(2.35, abs=0.03)


def test_twin_sim_reports_a_state_that_did_not_settle(capsys):
    code = main(["sim", "--lengths=-0.003,0,0.003,0", "--timeout-s", "0.02", "--set", "sim.elements=10"])
    assert code == 1
    assert "did not settle" in capsys.readouterr().err


@pytest.mark.parametrize("force_n, moment_nm", [((0.0, 0.05, 0.0), (0.0, 0.0, 0.0)),
                                                ((0.0, 0.0, 0.0), (0.0, 0.0, 0.002)),  # bends; about world x it twists
                                                ((0.03, 0.03, -0.02), (0.0, 0.001, 0.001))])
def test_a_sideways_tip_force_and_moment_bend_the_twin_as_the_predictor(force_n, moment_nm):
    from twin.rod import RodModel, solve

    params = load_params()
    plant, tensions = Plant(params), np.full(4, 1.2)
    plant.set_tensions(tensions)
    plant.settle()
    unloaded = plant.tip_pose()[0]
    plant.set_tip_load(force_n, moment_nm)
    assert plant.settle().settled
    tip = plant.tip_pose()[0]
    rod = solve(RodModel.from_params(params), tensions, tip_force_n=force_n, tip_moment_nm=moment_nm,
                base_rotation=plant.base_rotation).tip_position_m
    assert np.linalg.norm(tip - unloaded) > 3e-3          # the load moves the tip by millimetres
    assert np.linalg.norm(tip - rod) < 0.01 * params.backbone.length_m
    plant.set_tip_load()
    plant.settle()
    assert np.allclose(plant.tip_pose()[0], unloaded, atol=1e-5)


def test_a_tip_load_adds_to_the_friction_forces_and_sim_applies_it(capsys):
    # The friction hook writes the forces of the bodies the tendons pass, not the tip load's.
    plant = _plant("effects.tendon_friction_coeff=0.1")
    plant.set_tensions([1.2] * 4)
    plant.settle()
    before = plant.tip_pose()[0]
    plant.set_tip_load((0.0, 0.05, 0.0))
    plant.settle()
    assert plant.tip_pose()[0][1] - before[1] > 3e-3
    assert main(["sim", "--tensions", "1.2,1.2,1.2,1.2", "--tip-force", "0,0.05,0", "--json"] + sum(
        (["--set", o] for o in FAST), [])) == 0
    assert json.loads(capsys.readouterr().out)["tip_position_m"][1] > 3e-3
    with pytest.raises(ValueError, match="expected 3 finite numbers"):
        plant.set_tip_load((0.0, float("nan"), 0.0))
    # Six numbers split 2 + 4 are not a force and a moment.
    with pytest.raises(ValueError, match=r"force_n = \(0.0, 0.05\): expected 3 finite numbers"):
        plant.set_tip_load((0.0, 0.05), (0.0, 0.0, 0.0, 0.0))


def test_the_holder_closes_on_a_helical_robot_without_untwisting_it():
    """The pretension alone twists a helically routed rod (17° at the tip); the holder's channel
    straightens it but keeps that twist, rather than snapping it out against the tendons."""
    from twin.robots import load_robot
    plant = Plant(load_robot("helical"))
    plant.set_tensions([1.35] * 4)
    plant.step(0.5)
    before = plant.tip_pose()[1].copy()
    plant.engage_holder()
    plant.step(0.5)
    plant.raise_warnings()
    after = plant.tip_pose()[1]
    # The tip's twist about its own axis is what it was; the tensions stayed at the pretension.
    twist = lambda rot: np.arctan2(rot[1, 0], rot[0, 0])
    assert abs(np.degrees(twist(before.T @ after))) < 1.0
    assert np.allclose(plant.true_tensions_n(), 1.35, atol=0.01)
