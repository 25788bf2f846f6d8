"""The RK4 stand-in ``twin bench peers`` times the kernel against integrates the same rod."""

import numpy as np
import pytest

from twin.pcc import validation_grid
from twin.robots import load_robot
from twin.rod import RodModel, solve
from twin.rod.bench import standin_integration
from twin.rod.grid import pcc_tensions_n


@pytest.mark.parametrize("robot", ["endoscope", "helical", "three-tendon"])
def test_standin_tip_agrees_with_the_kernel(robot):
    params = load_robot(robot)
    model = RodModel.from_params(params, with_effects=False)
    _, kappa, phi, _ = validation_grid()[100]
    sol = solve(model, pcc_tensions_n(kappa, phi, params), base_rotation=params.rig.base_rotation)
    seconds, tip = standin_integration(model, sol, count=10)
    assert seconds > 0
    # Both RK4 at the model's step count, of two forms of the same equations: they differ by about
    # their RK4 errors (1.6e-7 m against 640 steps on the endoscope, 2e-7 m helical), and a
    # stand-in of another rod would be millimetres off.
    assert np.linalg.norm(tip - sol.tip_position_m) < 1e-6


def test_standin_refuses_what_it_does_not_model():
    params = load_robot("endoscope")
    model = RodModel.from_params(params, with_effects=False)
    sol = solve(model, [1.0] * model.tendon_count)
    with pytest.raises(ValueError, match="point masses"):
        standin_integration(model.replace(point_masses=((0.03, 0.001),)), sol)
