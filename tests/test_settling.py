"""The board's loops settle under tendon friction (twin.control.settling, ``twin bench hold``).

With friction in the disc holes a tendon held still by it (presliding) is a load tens of times
stiffer than the sliding rod, and the tension loop's proportional term, tuned on the sliding
rod, rang on it: holding a 5 g load at κ 8.7 1/m, every channel cycled at 10 Hz, 1.1-2.2 N peak
to peak with its mean 0.14-0.16 N off the setpoint (μ = 0.1 and 0.3, endoscope and long robot).
With the twin's friction following the spool travel through a lag (as the host's sliding state
does), held tensions on the endoscope and the soft-G endoscope stay within 0.05 N peak to peak
and their means within 0.02 N of the setpoints, and the length loop
reaches its targets within an encoder count. With the tuned proportional gain (loop gain 0.92
against the stall force) the 100 mm robot rang at μ = 0.3 (0.6 N peak to peak) and the helical
one at 0.065 N; the gains now come from the rig's stall force at loop gain 0.46
(:func:`twin.control.gains.tension_gains_for`), and they hold within the noise. The held tension
is judged on the twin's true tension, in 0.1 s means: stiff-long's 5 kg cells alone span ~0.13 N.
"""

from __future__ import annotations

import pytest

from twin.control.settling import hold_figures
from twin.robots import load_robot


@pytest.mark.parametrize("robot, mu", [
    ("endoscope", 0.1), ("endoscope", 0.3), ("endoscope-soft-g", 0.3), ("long", 0.1), ("long", 0.3),
    ("helical", 0.3),
])
def test_held_tensions_settle_under_friction(robot, mu):
    params = load_robot(robot).replace({"effects.tendon_friction_coeff": mu})
    figures = hold_figures(params, length_timeout_s=10.0, tension_settle_s=2.0, measure_s=1.0)
    assert figures["tension_ptp_n"] <= 0.05, figures
    assert figures["tension_offset_n"] <= 0.02, figures
    assert figures["length_error_counts"] <= 1.0, figures


def test_a_stuck_stiff_tendon_rings_with_the_cells_noise_not_by_itself():
    # stiff-long at μ = 0.3 holds one tendon at 16 N that friction sticks: a 25-40 Hz presliding
    # resonance. With noiseless cells its true tension is still (no limit cycle); with its 5 kg
    # cells' 25 mN of noise, the proportional term, through its lag (kTensionProportionalLagS),
    # passes ~0.1 N peak to peak of it into the tendon (0.43 N without the lag), and the 0.1 s
    # means hold within the goal.
    params = load_robot("stiff-long").replace({"effects.tendon_friction_coeff": 0.3})
    noisy = hold_figures(params)
    assert noisy["tension_ptp_n"] <= 0.05 and noisy["tension_offset_n"] <= 0.02, noisy
    assert noisy["tension_true_ptp_n"] < 0.2 and noisy["tension_cell_ptp_n"] > 0.1, noisy
    quiet = hold_figures(params.replace({"sensors.loadcell_noise_n": 1e-5}))
    assert quiet["tension_true_ptp_n"] < 0.005, quiet


def _held_near_the_clamp(tensions_n, seed: int = 1):
    """long at μ = 0.3 bent to κ 15.72 1/m, φ 270° in length mode, 10 g hung, then tension mode
    ramped to ``tensions_n`` (N); the true tensions at every board tick over the next 2 s, after 2 s
    to settle, and the setpoints."""
    from twin.control.settling import hold_commanded

    params = load_robot("long")
    hold = hold_commanded(params, tensions_n, kappa_per_m=15.72, phi_deg=270.0, mass_kg=0.010,
                          twin_params=params.replace({"effects.tendon_friction_coeff": 0.3}), robot="long", seed=seed)
    assert not hold.fault_flags
    return hold.true_n, hold.setpoints_n


def test_two_stuck_tendons_held_at_the_duty_clamp_do_not_cycle():
    # A compensation's command on long at μ = 0.3: two tendons at 95 % of the duty clamp's pull
    # (5.115 N), stuck by friction. With a 10 ms proportional lag they cycled stick-slip at 20 Hz,
    # 2 N peak to peak (noiseless cells too), and grew towards the 6 N limit as the rod bent on.
    import numpy as np

    true, setpoints = _held_near_the_clamp([2.7407, 3.4998, 5.1154, 5.1154])
    assert np.ptp(true, axis=0).max() <= 0.1, np.ptp(true, axis=0)
    assert np.abs(true.mean(axis=0) - setpoints).max() <= 0.02, true.mean(axis=0) - setpoints


@pytest.mark.parametrize("antagonists_n", [(2.0, 2.5), (2.154, 2.154)])
def test_two_stuck_tendons_held_at_the_duty_clamp_of_a_further_bend_do_not_cycle(antagonists_n):
    # Bent further, the stuck tendons rang at 20 Hz, 0.32 N (2.0 / 2.5 N) and 1.0 N (2.154 N, the
    # hold survey's 0.95/0.4) peak to peak, their 0.1 s means 0.07 and 0.18 N: the integral drove
    # the rotor's resonance on a tendon friction holds (0.15 N with kp = 0). Through the
    # integral's two lags (kTensionIntegralLagS) 0.08 and 0.06 N are left at this seed
    # (0.05-0.13 N at seeds 0-2), and the 0.1 s means hold the goals of twin bench hold.
    from twin.control.settling import hold_commanded

    params = load_robot("long")
    hold = hold_commanded(params, [*antagonists_n, 5.1154, 5.1154], kappa_per_m=15.72, phi_deg=270.0, mass_kg=0.010,
                          twin_params=params.replace({"effects.tendon_friction_coeff": 0.3}), robot="long", seed=1)
    figures = hold.figures()
    assert not hold.fault_flags
    assert figures["ptp_n"].max() <= 0.1, figures
    assert figures["mean_ptp_n"].max() <= 0.05, figures
    assert abs(figures["offset_n"]).max() <= 0.02, figures


def test_the_tension_loops_proportional_gain_follows_the_rigs_stall_force():
    # The loop gain kp × stall force is what makes a stuck tendon ring, so a spool of twice the
    # radius (half the stall force at the tendon) gets twice the kp; the integral stays as tuned.
    from twin.control.gains import PROPORTIONAL_LOOP_GAIN, TUNED_TENSION_GAINS, tension_gains_for

    params = load_robot("endoscope")
    gains = tension_gains_for(params)
    assert gains["kp"] * params.rig.motor_stall_torque_nm / params.rig.spool_radius_m == pytest.approx(
        PROPORTIONAL_LOOP_GAIN)
    assert gains["kp"] < TUNED_TENSION_GAINS["kp"] and gains["ki"] == TUNED_TENSION_GAINS["ki"]
    wide = params.replace({"rig.spool_radius_m": 2 * params.rig.spool_radius_m})
    assert tension_gains_for(wide)["kp"] == pytest.approx(2 * gains["kp"])


def test_twin_bench_hold_prints_the_figures_beside_their_goals(capsys):
    from twin.cli import main as twin

    code = twin(["bench", "hold", "--robot", "three-tendon", "--set", "effects.tendon_friction_coeff=0.1"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "tension_ptp_n" in out and "(goal <= 0.05: met)" in out
