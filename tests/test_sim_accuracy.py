"""The twin against known answers: the arc of a pure end moment and of tendon tension, the
Euler-Bernoulli and Timoshenko cantilevers, the axial shortening under the tendons, a released
tendon, and convergence with the number of elements."""

import numpy as np
import pytest

from twin.params import load_params
from twin.pose import HORIZONTAL, UP
from twin.rod.grid import pcc_tensions_n
from twin.sim import Plant

# The thesis's fitted shear modulus, which needs shear slides at every station.
THESIS_G = ["backbone.shear_modulus_pa=4.7586e4", "sim.shear_joints=true", "sim.slide_stride=1"]


def _cantilever_deflection_m(elements: int, *overrides: str, tip_mass_kg: float = 0.001) -> tuple[float, float, float]:
    """(twin, theory, bending share of theory): tip deflection of the nearly weightless horizontal
    rod (0.1 mg: its own sag is 4e-5 of the tip load's). Theory is Euler-Bernoulli, plus the
    Timoshenko shear term when the twin has shear joints."""
    params = load_params(overrides=[f"sim.elements={elements}", "backbone.mass_kg=1e-7", *overrides])
    plant = Plant(params, base_rotation=HORIZONTAL)
    plant.set_tensions(np.zeros(4))  # tendons free: the spools follow without pulling
    plant.set_tip_mass_kg(tip_mass_kg)
    assert plant.settle(tol_m=1e-8, timeout_s=3.0).settled
    b = params.backbone
    force = tip_mass_kg * params.environment.gravity_m_s2
    bending = b.length_m**3 / (3 * b.bending_stiffness_nm2)
    shear = b.length_m / b.shear_stiffness_n if params.sim.shear_joints else 0.0
    return -plant.tip_pose()[0][2], force * (bending + shear), bending / (bending + shear)


@pytest.mark.parametrize("overrides", [(), ("sim.shear_joints=false",)], ids=["timoshenko", "euler-bernoulli"])
def test_small_tip_load_matches_beam_theory_within_half_a_percent(overrides):
    # By default the shear slides of five stations sit at the middle one: exact for the
    # constant shear force of a tip load.
    twin, expected, _ = _cantilever_deflection_m(10, *overrides)
    assert twin == pytest.approx(expected, rel=5e-3)


def test_with_the_thesis_shear_modulus_a_tip_load_matches_timoshenko_within_half_a_percent():
    twin, expected, bending_share = _cantilever_deflection_m(10, *THESIS_G)
    assert bending_share < 0.8  # shear is a real part of this answer
    assert twin == pytest.approx(expected, rel=5e-3)


@pytest.mark.parametrize("overrides", [(), THESIS_G], ids=["default", "thesis G"])
def test_cantilever_converges_with_the_number_of_elements_as_the_midpoint_rule(overrides):
    errors, share = {}, None
    for n in (10, 20, 30):
        twin, expected, share = _cantilever_deflection_m(n, *overrides)
        errors[n] = twin / expected - 1
    assert abs(errors[10]) > abs(errors[20]) > abs(errors[30])
    # Lumped bending misses 1/(4N^2) of the bending part of the deflection; what is left at
    # large N is the geometric nonlinearity small-deflection theory leaves out.
    assert errors[10] - errors[30] == pytest.approx(-share / 4 * (1 / 100 - 1 / 900), rel=0.15)


def _tendon_arc_error_m(elements: int, kappa_per_m: float, phi_deg: float) -> float:
    """Distance (m) of the weightless twin's tip from the arc that the PCC tensions make."""
    params = load_params(overrides=[f"sim.elements={elements}", "environment.gravity_m_s2=0.0",
                                    "sim.axial_joints=false"])
    plant = Plant(params, base_rotation=UP)
    plant.set_tensions(pcc_tensions_n(kappa_per_m, phi_deg, params))
    assert plant.settle(tol_m=1e-8).settled
    theta, phi = kappa_per_m * params.backbone.length_m, np.radians(phi_deg)
    arc = np.array([(1 - np.cos(theta)) * np.cos(phi), (1 - np.cos(theta)) * np.sin(phi), np.sin(theta)]) / kappa_per_m
    return float(np.linalg.norm(plant.tip_pose()[0] - arc))


@pytest.mark.parametrize("phi_deg", [0.0, 45.0])
def test_continuous_tendons_bend_the_rod_into_the_arc_converging_as_the_midpoint_rule(phi_deg):
    # Out of the tendons' planes (45 deg) two hinges share each bend; the twin alternates their
    # order so the unresisted twist of two rotations in a row cancels instead of adding up.
    errors = [_tendon_arc_error_m(n, 26.2, phi_deg) for n in (10, 20)]
    length = load_params().backbone.length_m
    assert errors[0] < 3e-3 * length
    assert errors[1] == pytest.approx(errors[0] / 4, rel=0.2)


def test_continuous_pretension_leaves_the_rod_alone_and_disc_chords_bend_it():
    def sag_m(routing: str, tension_n: float) -> float:
        # Without shear slides: the tendons' tension also stiffens shear (their second-order
        # length), which lessens the sag by 3 µm at 12 N; that is the next test's.
        params = load_params(overrides=[f'sim.tendon_routing="{routing}"', "sim.axial_joints=false",
                                        "sim.shear_joints=false"])
        plant = Plant(params, base_rotation=HORIZONTAL)
        plant.set_tensions(np.full(4, tension_n))
        assert plant.settle(tol_m=1e-8).settled
        return -plant.tip_pose()[0][2]

    assert sag_m("continuous", 3.0) == pytest.approx(sag_m("continuous", 0.0), abs=1e-6)
    # Each chord across a bent joint lies towards the centre of curvature of the sag.
    assert sag_m("discs", 3.0) > sag_m("discs", 0.0) + 1e-4


@pytest.mark.parametrize("torsion", ["EJ", "GJ"])
def test_the_tendons_tension_stiffens_twist_by_sum_t_r_squared(torsion):
    # A tendon at r grows by r²θ²/(2L) when the rod twists by θ: under tension T it resists the
    # twist as a spring of T·r²/L, so a tip moment M twists the rod by M L / (K_t + ΣT·r²).
    params = load_params(overrides=["environment.gravity_m_s2=0.0", f'backbone.torsion="{torsion}"'])
    b, tension_n, moment_nm = params.backbone, 2.0, 1e-3
    plant = Plant(params, base_rotation=UP)
    plant.set_tensions(np.full(4, tension_n))
    tip = plant.model.body(f"b{plant.layout.elements}").id
    for _ in range(40):
        plant.data.xfrc_applied[tip, 3:] = plant.tip_pose()[1] @ np.array([0.0, 0.0, moment_nm])
        plant.step(0.05)
    rotation = plant.tip_pose()[1]
    twist = np.arctan2(rotation[1, 0], rotation[0, 0])
    stiffened = moment_nm * b.length_m / (b.torsional_stiffness_nm2 + 4 * tension_n * params.tendons.radius_m**2)
    assert twist == pytest.approx(stiffened, rel=1e-4)
    assert twist < 0.9 * moment_nm * b.length_m / b.torsional_stiffness_nm2


def test_the_tendons_tension_stiffens_shear_as_in_the_predictor():
    # With the thesis's G (GA = 1.35 N) the tendons' 8 N carry most of the shear stiffness: the
    # tip load's deflection falls by a fifth, in the predictor as in the twin.
    from twin.rod import RodModel, solve

    params = load_params(overrides=["backbone.mass_kg=1e-7", *THESIS_G])
    force_n = 1e-3 * params.environment.gravity_m_s2
    deflections = {}
    for tension_n in (0.0, 2.0):
        plant = Plant(params, base_rotation=HORIZONTAL)
        plant.set_tensions(np.full(4, tension_n))
        plant.set_tip_mass_kg(1e-3)
        assert plant.settle(tol_m=1e-9, timeout_s=5.0).settled
        rod = solve(RodModel.from_params(params), np.full(4, tension_n), tip_force_n=(0.0, 0.0, -force_n),
                    base_rotation=HORIZONTAL)
        deflections[tension_n] = (-plant.tip_pose()[0][2], -rod.tip_position_m[2])
    (twin_bare, rod_bare), (twin, rod) = deflections[0.0], deflections[2.0]
    assert twin == pytest.approx(rod, rel=5e-3)
    assert twin < 0.85 * twin_bare and rod < 0.85 * rod_bare


def test_the_tendons_shorten_the_backbone_by_their_compression():
    params = load_params(overrides=["environment.gravity_m_s2=0.0"])
    plant = Plant(params, base_rotation=UP)
    plant.set_tensions(np.full(4, 2.0))
    assert plant.settle(tol_m=1e-9).settled
    b = params.backbone
    shortening = b.length_m - plant.tip_pose()[0][2]
    assert shortening == pytest.approx(4 * 2.0 * b.length_m / b.axial_stiffness_n, rel=1e-3)


def test_pure_end_moment_bends_the_rod_into_the_ideal_arc():
    params = load_params(overrides=["sim.elements=10", "environment.gravity_m_s2=0.0"])
    plant = Plant(params, base_rotation=UP)
    plant.set_tensions(np.zeros(4))
    ei, length = params.backbone.bending_stiffness_nm2, params.backbone.length_m
    kappa = 15.0
    tip = plant.model.body("b10").id
    # A moment about body y bends the rod towards +x, a couple: no force.
    plant.data.xfrc_applied[tip, 3:] = plant.tip_pose()[1] @ np.array([0.0, ei * kappa, 0.0])
    for _ in range(20):
        plant.data.xfrc_applied[tip, 3:] = plant.tip_pose()[1] @ np.array([0.0, ei * kappa, 0.0])
        plant.step(0.05)
    theta = kappa * length
    expected = np.array([(1 - np.cos(theta)) / kappa, 0.0, np.sin(theta) / kappa])
    position, rotation = plant.tip_pose()
    assert np.linalg.norm(position - expected) < 2e-3 * length
    assert np.degrees(np.arccos(rotation[2, 2])) == pytest.approx(np.degrees(theta), abs=0.1)
    # Every station lies on the circle of radius 1/kappa about (1/kappa, 0, 0).
    stations = plant.backbone_positions_m()[1:-1]
    radius = np.linalg.norm(stations - [1 / kappa, 0.0, 0.0], axis=1)
    assert np.allclose(radius, 1 / kappa, rtol=2e-3)


def test_released_tendon_reads_zero_and_the_rod_returns_straight():
    params = load_params(overrides=["sim.elements=10"])
    plant = Plant(params, base_rotation=UP, seed=3)
    plant.set_tensions([2.0, 0.0, 0.0, 0.0])
    assert plant.settle().settled
    assert np.linalg.norm(plant.tip_pose()[0][:2]) > 0.01
    plant.set_tensions(np.zeros(4))
    assert plant.settle().settled
    assert np.linalg.norm(plant.tip_pose()[0] - [0.0, 0.0, params.backbone.length_m]) < 1e-5
    assert np.all(plant.true_tensions_n() < 1e-4)
    plant.step(0.05)
    s = params.sensors
    read = (plant.loadcell_raw_counts() - np.asarray(s.loadcell_offset_counts)) / s.loadcell_gain_counts_per_n
    assert np.all(np.abs(read) < 5 * s.loadcell_noise_n)
