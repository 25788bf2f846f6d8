"""The twin against known answers: the arc of a pure end moment, the Timoshenko cantilever,
a released tendon, and convergence with the number of elements."""

import numpy as np
import pytest

from twin.params import load_params
from twin.pose import HORIZONTAL, UP
from twin.sim import Plant


def _cantilever_deflection_m(elements: int, tip_mass_kg: float = 0.001) -> tuple[float, float]:
    """(twin, Euler-Bernoulli + Timoshenko shear) tip deflection of the nearly weightless
    horizontal rod (0.1 mg: its own sag is 4e-5 of the tip load's)."""
    params = load_params(overrides=[f"sim.elements={elements}", "backbone.mass_kg=1e-7"])
    plant = Plant(params, base_rotation=HORIZONTAL)
    plant.set_tensions(np.zeros(4))  # tendons free: the spools follow without pulling
    plant.set_tip_mass_kg(tip_mass_kg)
    assert plant.settle(tol_m=1e-8, timeout_s=3.0).settled
    b = params.backbone
    force = tip_mass_kg * params.environment.gravity_m_s2
    expected = force * (b.length_m**3 / (3 * b.bending_stiffness_nm2) + b.length_m / b.shear_stiffness_n)
    return -plant.tip_pose()[0][2], expected


def test_small_tip_load_matches_timoshenko_within_half_a_percent():
    twin, expected = _cantilever_deflection_m(10)
    assert twin == pytest.approx(expected, rel=5e-3)


def test_cantilever_converges_with_the_number_of_elements_as_the_midpoint_rule():
    errors = {}
    for n in (10, 20, 30):
        twin, expected = _cantilever_deflection_m(n)
        errors[n] = twin / expected - 1
    assert abs(errors[10]) > abs(errors[20]) > abs(errors[30])
    # Lumped bending misses 1/(4N^2) of the bending part of the deflection; what is left at
    # large N is the geometric nonlinearity small-deflection theory leaves out.
    b = load_params().backbone
    bending = b.length_m**2 / (3 * b.bending_stiffness_nm2)
    bending_share = bending / (bending + 1 / b.shear_stiffness_n)
    assert errors[10] - errors[30] == pytest.approx(-bending_share / 4 * (1 / 100 - 1 / 900), rel=0.15)


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
