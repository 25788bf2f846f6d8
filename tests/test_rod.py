"""The Cosserat rod–tendon predictor against known answers."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from twin import load_params
from twin.pcc import validation_grid
from twin.pose import HORIZONTAL, rot_z
from twin.rod import ConvergenceError, RodModel, SolverStatus, TendonRoute, solve, tip_jacobian
from twin.rod.grid import GRAVITY_TIP_FORCE_N, pcc_tensions_n

PARAMS = load_params()
MODEL = RodModel.from_params(PARAMS)
WEIGHTLESS = MODEL.replace(gravity_m_s2=0.0)
EI = PARAMS.backbone.bending_stiffness_nm2
GA = PARAMS.backbone.shear_stiffness_n
L = PARAMS.backbone.length_m
R_T = PARAMS.tendons.radius_m


def test_single_tendon_gives_constant_curvature():
    tau = 0.8
    sol = solve(WEIGHTLESS, [tau, 0, 0, 0], base_rotation=np.eye(3))
    curvature = np.linalg.norm(sol.strains[:, 3:6], axis=1)
    assert np.allclose(curvature, tau * R_T / EI, rtol=1e-9)
    # Inextensible limit: the tip lies on the ideal arc.
    stiff = WEIGHTLESS.replace(axial_stiffness_n=1e12, shear_stiffness_n=1e12)
    tip = solve(stiff, [tau, 0, 0, 0]).tip_position_m
    k = tau * R_T / EI
    assert np.allclose(tip, [(1 - np.cos(k * L)) / k, 0, np.sin(k * L) / k], atol=1e-9)


def test_tendon_on_body_x_bends_towards_x():
    tip = solve(WEIGHTLESS, [1.0, 0, 0, 0]).tip_position_m
    assert tip[0] > 0.01 and abs(tip[1]) < 1e-12


@pytest.mark.parametrize("shear_modulus_pa", [4.7586e4, 3.0e6])
def test_small_tip_load_matches_timoshenko(shear_modulus_pa):
    model = WEIGHTLESS.replace(shear_stiffness_n=shear_modulus_pa * PARAMS.backbone.area_m2)
    force = 1e-4
    sol = solve(model, [0, 0, 0, 0], tip_force_n=[0, 0, -force], base_rotation=HORIZONTAL)
    expected = force * L**3 / (3 * EI) + force * L / model.shear_stiffness_n
    assert -sol.tip_position_m[2] == pytest.approx(expected, rel=2e-3)


def _elastica_tip(force_n, ei, length):
    """Inextensible, unshearable cantilever under a dead tip load: EI θ'' = −P cos θ, θ(0)=0, θ'(L)=0."""

    def shoot(k0):
        ode = lambda s, y: [y[1], -force_n / ei * np.cos(y[0]), np.cos(y[0]), np.sin(y[0])]
        return solve_ivp(ode, (0, length), [0, k0, 0, 0], rtol=1e-12, atol=1e-14)

    k0 = brentq(lambda k: shoot(k).y[1, -1], 0.0, force_n * length / ei * 1.01)
    y = shoot(k0).y[:, -1]
    return y[2], y[3]


def test_large_tip_load_agrees_with_elastica():
    model = WEIGHTLESS.replace(shear_stiffness_n=1e10, axial_stiffness_n=1e10, steps=80)
    force = 0.1  # tip bends by ~50 degrees
    x, drop = _elastica_tip(force, EI, L)
    tip = solve(model, [0, 0, 0, 0], tip_force_n=[0, 0, -force], base_rotation=HORIZONTAL).tip_position_m
    assert drop > 0.2 * L
    assert tip[0] == pytest.approx(x, abs=1e-7)
    assert -tip[2] == pytest.approx(drop, abs=1e-7)


def test_rotating_tensions_by_90_degrees_rotates_the_shape():
    a = solve(MODEL, [2.0, 1.2, 1.0, 1.4], tip_force_n=[0, 0, -0.05])
    b = solve(MODEL, [1.4, 2.0, 1.2, 1.0], tip_force_n=[0, 0, -0.05])
    assert np.allclose(b.positions_m, a.positions_m @ rot_z(np.pi / 2).T, atol=1e-12)


def test_zero_tension_without_gravity_stays_straight():
    sol = solve(WEIGHTLESS, [0, 0, 0, 0], base_rotation=HORIZONTAL)
    assert np.allclose(sol.tip_position_m, [L, 0, 0], atol=1e-15)
    assert np.allclose(sol.tendon_lengths_m, L)


def test_pretension_shortens_rod_and_tendons_axially():
    tau = 1.35
    sol = solve(WEIGHTLESS, [tau] * 4)
    strain = 4 * tau / PARAMS.backbone.axial_stiffness_n
    assert np.allclose(sol.tip_position_m, [0, 0, L * (1 - strain)], atol=1e-12)
    assert np.allclose(sol.tendon_lengths_m, L * (1 - strain), atol=1e-12)


def test_convergence_with_resolution_is_fourth_order():
    case = dict(tip_force_n=[0, 0, -0.098], base_rotation=HORIZONTAL)
    tensions = pcc_tensions_n(26.2, 180.0, PARAMS)
    ref = solve(MODEL.replace(steps=640), tensions, **case).tip_position_m
    errors = [np.linalg.norm(solve(MODEL.replace(steps=n), tensions, **case).tip_position_m - ref)
              for n in (5, 10, 20)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[0] / errors[1] > 10  # RK4: ~16x per halving
    assert errors[2] < 1e-6


def test_lumped_disc_masses_sag_like_point_loads():
    mass = 1e-4  # small: linear regime
    base = WEIGHTLESS.replace(gravity_m_s2=9.81, line_mass_kg_per_m=0.0)
    n = PARAMS.discs.count
    lumped = base.replace(point_masses=tuple(((k + 1) * L / n, mass / n) for k in range(n)))
    uniform = base.replace(line_mass_kg_per_m=mass / L)
    drop_l = -solve(lumped, [0] * 4, base_rotation=HORIZONTAL).tip_position_m[2]
    drop_u = -solve(uniform, [0] * 4, base_rotation=HORIZONTAL).tip_position_m[2]
    p = mass / n * 9.81
    a = (np.arange(n) + 1) * L / n
    expected_l = np.sum(p * a**2 * (3 * L - a) / (6 * EI) + p * a / GA)
    q = mass * 9.81 / L
    expected_u = q * L**4 / (8 * EI) + q * L**2 / (2 * GA)
    assert drop_l == pytest.approx(expected_l, rel=2e-3)
    assert drop_u == pytest.approx(expected_u, rel=2e-3)


def test_helical_routing_bends_out_of_plane():
    turns = 0.5
    omega = 2 * np.pi * turns / L
    model = WEIGHTLESS.replace(tendons=tuple(TendonRoute(R_T, a, helix_rad_per_m=omega) for a in (0, 90, 180, 270)))
    straight = solve(model, [0, 0, 0, 0])
    assert np.allclose(straight.tendon_lengths_m, L * np.sqrt(1 + (R_T * omega) ** 2), rtol=1e-10)
    bent = solve(model, [1.0, 0, 0, 0])
    assert bent.converged
    assert abs(bent.tip_position_m[1]) > 1e-3  # a helix pulls the tip out of the x-z plane


def test_tendon_ending_midway_bends_only_the_proximal_half():
    model = WEIGHTLESS.replace(
        tendons=(TendonRoute(R_T, 0.0, end_m=L / 2), TendonRoute(R_T, 180.0)), steps=20)
    sol = solve(model, [0.5, 0.0])
    kappa = np.linalg.norm(sol.strains[:, 3:6], axis=1)
    assert np.allclose(kappa[sol.s_m < L / 2 - 1e-9], 0.5 * R_T / EI, rtol=1e-9)
    assert np.allclose(kappa[sol.s_m > L / 2 + 1e-9], 0.0, atol=1e-9)
    assert sol.tendon_lengths_m[0] < L / 2  # path length base → termination, shortened by the bend


def test_converging_routing_loses_moment_arm_towards_the_tip():
    model = WEIGHTLESS.replace(tendons=(TendonRoute(R_T, 0.0, tip_radius_m=R_T / 3),))
    sol = solve(model, [0.5])
    kappa = np.linalg.norm(sol.strains[:, 3:6], axis=1)
    assert kappa[0] > 2.5 * kappa[-1] > 0


@pytest.mark.parametrize("shear_modulus_pa", [4.7586e4, 3.0e6])
def test_whole_thesis_grid_converges(shear_modulus_pa):
    params = load_params(overrides={"backbone.shear_modulus_pa": shear_modulus_pa})
    model = RodModel.from_params(params)
    g = params.environment.gravity_m_s2
    failures = []
    for config, kappa, phi, mass in validation_grid():
        sol = solve(model, pcc_tensions_n(kappa, phi, params), tip_force_n=GRAVITY_TIP_FORCE_N(mass, g),
                    base_rotation=HORIZONTAL, raise_on_failure=False)
        if not sol.converged:
            failures.append(config)
        elif kappa == 26.2 and phi == 180 and mass == 0.010:
            assert sol.tip_position_m[2] > 0.01  # the heavy, upward-bending case the thesis lost
    assert failures == []


def test_continuation_rescues_a_solve_the_direct_newton_cannot_start():
    model = MODEL.replace(max_iterations=3)
    tensions = [20.0, 1.35, 1.35, 1.35]  # bends the tip through ~270 degrees
    direct = solve(model, tensions, base_rotation=HORIZONTAL, tip_force_n=[0, 0, -0.2], continuation=False,
                   raise_on_failure=False)
    assert not direct.converged
    rescued = solve(model, tensions, base_rotation=HORIZONTAL, tip_force_n=[0, 0, -0.2])
    assert rescued.converged and rescued.continuation_steps > 0
    reference = solve(MODEL, tensions, base_rotation=HORIZONTAL, tip_force_n=[0, 0, -0.2])
    assert np.allclose(rescued.tip_position_m, reference.tip_position_m, atol=1e-9)


def test_failure_is_never_returned_as_an_answer():
    model = MODEL.replace(max_iterations=1)
    with pytest.raises(ConvergenceError) as info:
        solve(model, [60.0, 0, 0, 0], continuation=False)
    assert info.value.residual_nm > 0 and "residual" in str(info.value)
    report = solve(model, [60.0, 0, 0, 0], continuation=False, raise_on_failure=False)
    assert not report.converged and np.isnan(report.tip_position_m).all()


def test_warm_start_converges_in_fewer_integrations():
    tensions = pcc_tensions_n(13.0, 60.0, PARAMS)
    cold = solve(MODEL, tensions, base_rotation=HORIZONTAL)
    warm = solve(MODEL, tensions + 0.01, base_rotation=HORIZONTAL, guess_nm=cold.base_moment_nm)
    assert warm.integrations < cold.integrations


@pytest.mark.parametrize("bad", [dict(tensions_n=[1, 0, 0]), dict(tensions_n=[-1, 0, 0, 0]),
                                 dict(tensions_n=[np.nan, 0, 0, 0]),
                                 dict(tensions_n=[1, 0, 0, 0], base_rotation=2 * np.eye(3))])
def test_bad_input_is_refused(bad):
    with pytest.raises(ValueError):
        solve(MODEL, **bad)


def test_jacobian_matches_finite_differences_of_full_solves():
    tensions = np.array([2.5, 1.35, 1.6, 1.35])
    force = np.array([0.0, 0.01, -0.05])
    sol = solve(MODEL, tensions, tip_force_n=force, base_rotation=HORIZONTAL)
    jac = tip_jacobian(MODEL, sol)
    h = 1e-4
    for j in range(7):
        dt, df = np.zeros(4), np.zeros(3)
        (dt if j < 4 else df)[j if j < 4 else j - 4] = h
        plus = solve(MODEL, tensions + dt, tip_force_n=force + df, base_rotation=HORIZONTAL)
        minus = solve(MODEL, tensions - dt, tip_force_n=force - df, base_rotation=HORIZONTAL)
        fd_pos = (plus.tip_position_m - minus.tip_position_m) / (2 * h)
        drot = plus.tip_rotation @ minus.tip_rotation.T
        fd_rot = 0.5 * np.array([drot[2, 1] - drot[1, 2], drot[0, 2] - drot[2, 0], drot[1, 0] - drot[0, 1]]) / (2 * h)
        assert np.allclose(jac.matrix[:3, j], fd_pos, rtol=1e-3, atol=2e-5 * np.abs(fd_pos).max() + 1e-9)
        assert np.allclose(jac.matrix[3:, j], fd_rot, rtol=1e-3, atol=2e-5 * np.abs(fd_rot).max() + 1e-9)
    assert jac.position_wrt_tension.shape == (3, 4) and jac.position_wrt_force.shape == (3, 3)


def test_friction_makes_pulling_and_releasing_differ():
    model = WEIGHTLESS.replace(friction_coeff=0.2)
    pulled = solve(model, [1.0, 0, 0, 0], friction_direction=[1, 1, 1, 1])
    released = solve(model, [1.0, 0, 0, 0], friction_direction=[-1, -1, -1, -1])
    free = solve(WEIGHTLESS, [1.0, 0, 0, 0])
    assert pulled.tip_position_m[0] < free.tip_position_m[0] < released.tip_position_m[0]
    # Tension decays with wrap: at the tip exp(−μ θ) with θ the bend angle.
    theta = np.arccos(pulled.tip_rotation[2, 2])
    assert pulled.tendon_tensions_n[-1, 0] == pytest.approx(np.exp(-0.2 * theta), rel=1e-3)


def test_status_is_an_enum_on_success_and_failure():
    sol = solve(MODEL, pcc_tensions_n(13.0, 60.0, PARAMS), base_rotation=HORIZONTAL)
    assert sol.status is SolverStatus.CONVERGED and sol.to_dict()["status"] == "converged"
    report = solve(MODEL.replace(max_iterations=1), [60.0, 0, 0, 0], continuation=False, raise_on_failure=False)
    assert report.status is SolverStatus.ITERATION_LIMIT and report.to_dict()["status"] == "iteration limit"


def test_trace_records_every_newton_iteration():
    tensions = pcc_tensions_n(13.0, 60.0, PARAMS)
    cold = solve(MODEL, tensions, base_rotation=HORIZONTAL)
    trace = cold.trace
    # One entry per iteration plus the iterate the solve ended on.
    assert len(trace) == cold.iterations + 1 and [t.iteration for t in trace] == list(range(len(trace)))
    assert trace[-1].residual_nm == cold.residual_nm
    residuals = [t.residual_nm for t in trace]
    assert all(b < a for a, b in zip(residuals, residuals[1:]))
    assert trace[0].residual_nm > 1e3 * MODEL.tolerance * MODEL.moment_scale_nm
    assert all(t.step_fraction > 0 and t.step_nm > 0 for t in trace[:-1])
    assert trace[-1].step_fraction == 0 and trace[-1].step_nm == 0
    # A cold solve starts with finite differences (3 integrations) and goes on with Broyden
    # updates; with full steps each iteration adds one trial integration to the first one.
    assert trace[0].fresh_jacobian
    assert all(t.step_fraction == 1.0 for t in trace[:-1])
    assert cold.integrations == 1 + sum(1 + 3 * t.fresh_jacobian for t in trace[:-1])
    warm = solve(MODEL, tensions + 0.01, base_rotation=HORIZONTAL, guess_nm=cold.base_moment_nm,
                 guess_jacobian=cold.shooting_jacobian)
    assert not warm.trace[0].fresh_jacobian  # the carried Jacobian, Broyden-updated
    assert warm.trace[-1].residual_nm == warm.residual_nm


def test_trace_follows_the_continuation_runs():
    model = MODEL.replace(max_iterations=3)
    rescued = solve(model, [20.0, 1.35, 1.35, 1.35], base_rotation=HORIZONTAL, tip_force_n=[0, 0, -0.2])
    factors = [t.load_factor for t in rescued.trace]
    assert 0.0 in factors and any(0.0 < f < 1.0 for f in factors)
    assert factors[-1] == 1.0 and rescued.trace[-1].residual_nm == rescued.residual_nm


def test_convergence_error_carries_status_and_trace():
    with pytest.raises(ConvergenceError) as info:
        solve(MODEL.replace(max_iterations=1), [60.0, 0, 0, 0], continuation=False)
    error = info.value
    assert error.status is SolverStatus.ITERATION_LIMIT and "iteration limit" in str(error)
    assert len(error.trace) == 2  # the one iteration and the iterate it reached
    assert error.trace[-1].residual_nm == error.residual_nm
    assert error.trace[0].residual_nm > error.residual_nm


@pytest.mark.parametrize("angles_deg", [[0.0, 120.0, 240.0], [0.0, 90.0, 180.0, 270.0],
                                        [0.0, 60.0, 120.0, 180.0, 240.0, 300.0], [10.0, 100.0, 170.0, 250.0, 300.0]])
def test_the_grid_tensions_bend_any_tendon_layout_to_the_commanded_plane_and_curvature(angles_deg):
    from twin.rod.grid import pcc_realisable

    n = len(angles_deg)
    params = PARAMS.replace({"tendons.angles_deg": angles_deg, "effects.tension_gain_error": [0.0] * n,
                             "effects.tension_offset_error_n": [0.0] * n,
                             "sensors.loadcell_offset_counts": [0.0] * n})
    model = RodModel.from_params(params)
    bends = []
    for phi in (0.0, 45.0, 60.0, 135.0, 200.0, 315.0):
        assert pcc_realisable(phi, params)
        sol = solve(model, pcc_tensions_n(13.0, phi, params))
        x, y, _ = sol.tip_position_m
        miss_deg = (np.degrees(np.arctan2(y, x)) - phi + 180.0) % 360.0 - 180.0
        assert abs(miss_deg) < 0.05
        bends.append(np.degrees(np.arccos(sol.tip_rotation[2, 2])))
    # The same curvature in every plane: what sets the bend is κ, not the tendons nearest to φ.
    assert np.ptp(bends) < 0.1 and bends[0] == pytest.approx(np.degrees(13.0 * params.backbone.length_m), abs=3.0)


def test_a_plane_no_tendon_pair_brackets_is_refused_not_bent_elsewhere():
    from twin.rod.grid import pcc_realisable

    two = PARAMS.replace({"tendons.angles_deg": [0.0, 180.0], "effects.tension_gain_error": [0.0] * 2,
                          "effects.tension_offset_error_n": [0.0] * 2, "sensors.loadcell_offset_counts": [0.0] * 2})
    assert pcc_realisable(0.0, two) and pcc_realisable(180.0, two) and not pcc_realisable(90.0, two)
    with pytest.raises(ValueError, match="cannot bend towards it"):
        pcc_tensions_n(13.0, 90.0, two)


def test_a_stiffness_run_off_to_zero_is_a_failed_solve_not_a_crash():
    # A fit's trial with an undetermined shear modulus run off to 1e-278 Pa: GA underflows.
    from twin.robots import load_robot

    params = load_robot("stiff-long").replace({"backbone.shear_modulus_pa": 5.8e-278})
    model = RodModel.from_params(params)
    sol = solve(model, [0.0, 0.02, 0.003], base_rotation=params.rig.base_rotation, raise_on_failure=False)
    assert not sol.converged


def test_the_step_count_follows_the_robots_length():
    from twin.robots import load_robot

    endoscope, stiff = load_robot("endoscope"), load_robot("stiff-long")
    assert endoscope.predictor_steps() == endoscope.solver.steps == 12
    # 150 mm at no more than 5 mm a step.
    assert stiff.predictor_steps() == 30 and RodModel.from_params(stiff).steps == 30


def test_solutions_built_without_their_init_are_whole_and_match_a_stream_of_cold_solves():
    # The hot path builds LoadCase and RodSolution without the dataclass __init__: every field
    # must be there (a missing one would surface only where it is read), and none may need a
    # __post_init__. A warm stream must give what cold solves give.
    import dataclasses

    from twin.rod import Predictor
    from twin.rod.solver import LoadCase, RodSolution

    predictor = Predictor(MODEL)
    pose = PARAMS.rig.base_rotation
    for kappa in (5.0, 6.0, 7.0):
        tensions = pcc_tensions_n(kappa, 30.0, PARAMS)
        force = GRAVITY_TIP_FORCE_N(0.005, PARAMS.environment.gravity_m_s2)
        warm = predictor.solve(tensions, tip_force_n=force, base_rotation=pose)
        cold = solve(MODEL, tensions, tip_force_n=force, base_rotation=pose)
        assert warm.converged and np.allclose(warm.positions_m, cold.positions_m, atol=1e-9)
        for obj, cls in ((warm, RodSolution), (warm.load, LoadCase)):
            assert set(vars(obj)) >= {f.name for f in dataclasses.fields(cls)}
            assert not hasattr(cls, "__post_init__")
        assert not warm.tendon_tensions_n.flags.writeable
        assert np.array_equal(warm.tendon_tensions_n, np.broadcast_to(tensions, warm.tendon_tensions_n.shape))
        assert np.allclose(warm.internal_force_n[-1], force)
