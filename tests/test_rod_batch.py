"""``solve_batch``: many load cases in one compiled call give what ``solve`` gives for each."""

import numpy as np
import pytest

from twin import load_params
from twin.pcc import validation_grid
from twin.pose import HORIZONTAL
from twin.rod import Predictor, RodModel, solve, solve_batch
from twin.rod.grid import GRAVITY_TIP_FORCE_N, pcc_tensions_n

PARAMS = load_params()
MODEL = RodModel.from_params(PARAMS)
GRID = validation_grid()[::9]
TENSIONS = np.array([pcc_tensions_n(k, phi, PARAMS) for _, k, phi, _ in GRID])
FORCES = np.array([GRAVITY_TIP_FORCE_N(m, 9.81) for *_, m in GRID])


def test_batch_matches_one_solve_per_case():
    batch = solve_batch(MODEL, TENSIONS, tip_force_n=FORCES, base_rotation=HORIZONTAL)
    assert len(batch) == len(GRID)
    for sol, t, f in zip(batch, TENSIONS, FORCES):
        one = solve(MODEL, t, tip_force_n=f, base_rotation=HORIZONTAL)
        assert sol.converged and sol.residual_nm <= MODEL.tolerance * MODEL.moment_scale_nm
        assert np.linalg.norm(sol.tip_position_m - one.tip_position_m) < 1e-9
        assert np.allclose(sol.internal_force_n, one.internal_force_n, atol=1e-12)
        assert sol.trace[-1].residual_nm == sol.residual_nm


def test_guesses_start_each_case_from_its_own_solution():
    first = solve_batch(MODEL, TENSIONS, tip_force_n=FORCES, base_rotation=HORIZONTAL)
    again = solve_batch(MODEL, TENSIONS, tip_force_n=FORCES, base_rotation=HORIZONTAL, guesses=first)
    # Started at its own solution, every case converges without a Newton step.
    assert all(sol.iterations == 0 and sol.integrations == 1 for sol in again)
    assert all(np.array_equal(a.base_moment_nm, b.base_moment_nm) for a, b in zip(first, again))


def test_each_case_starts_from_the_nearest_solved_one():
    # The grid's order, then its first case again: met before, that load costs one integration.
    tensions = np.vstack([TENSIONS, TENSIONS[:1]])
    forces = np.vstack([FORCES, FORCES[:1]])
    batch = solve_batch(MODEL, tensions, tip_force_n=forces, base_rotation=HORIZONTAL)
    assert batch[-1].integrations == 1
    assert np.linalg.norm(batch[-1].tip_position_m - batch[0].tip_position_m) < 1e-9
    # Each case started from a solved neighbour moved by the estimated change of m(0) costs
    # fewer integrations than a Predictor stream through the same cases.
    predictor = Predictor(MODEL)
    stream = [predictor.solve(t, tip_force_n=f, base_rotation=HORIZONTAL) for t, f in zip(TENSIONS, FORCES)]
    assert sum(sol.integrations for sol in batch[1:-1]) < sum(sol.integrations for sol in stream[1:])


def test_the_load_moment_estimate_follows_the_solved_base_moment():
    from twin.rod.solver import _load_moments

    solved = np.array([sol.base_moment_nm for sol in
                       solve_batch(MODEL, TENSIONS, tip_force_n=FORCES, base_rotation=HORIZONTAL)])
    estimate = _load_moments(MODEL, HORIZONTAL, TENSIONS, FORCES, np.zeros_like(FORCES))
    error = np.linalg.norm(estimate - solved, axis=1) / np.linalg.norm(solved, axis=1)
    # The arc the tendons bend the rod into puts the loads' moment within a few percent (the
    # weight's sag it leaves out); the straight rod's shape is tens of percent off once it bends.
    assert np.median(error) < 0.05


def test_a_case_that_fails_is_reported_not_dropped():
    model = MODEL.replace(max_iterations=1)
    tensions = np.vstack([TENSIONS[:2], [[40.0, 0.0, 0.0, 0.0]]])
    batch = solve_batch(model, tensions, base_rotation=HORIZONTAL, continuation=False, raise_on_failure=False)
    assert len(batch) == 3
    failed = [sol for sol in batch if not sol.converged]
    assert failed and all(np.isnan(sol.tip_position_m).all() for sol in failed)


@pytest.mark.parametrize("kwargs, message", [
    (dict(tensions_n=[[1.0, 1.0, 1.0]]), "tensions_n"),
    (dict(tensions_n=[[1.0, -1.0, 1.0, 1.0]]), ">= 0"),
    (dict(tensions_n=[[1.0] * 4] * 2, tip_force_n=[[0.0, 0.0, 1.0]] * 3), "tip_force_n"),
    (dict(tensions_n=[[1.0] * 4], guesses=[None, None]), "guesses"),
])
def test_bad_input_names_the_argument(kwargs, message):
    with pytest.raises(ValueError, match=message):
        solve_batch(MODEL, **kwargs)
