"""The pose a device runs in is the pose its dataset records and its predictions use.

The twin is built in the clamp orientation of its URL (``pose`` or ``base_quat``) or, without
one, of the parameter set's ``rig.base_quat``; :attr:`Device.base_rotation` carries it to the
dataset, the predictions, the env's targets and the controllers.
"""

import numpy as np
import pytest

from twin import load_params
from twin.data.dataset import read_dataset
from twin.driver import open_device
from twin.experiments.analysis import analyse_validation
from twin.experiments.protocols import nominal_calibration, run_validation
from twin.params import ParameterError
from twin.pose import HORIZONTAL, UP, quat_to_matrix, rot_x

PARAMS = load_params()
# κ 13 and 26.2 1/m in two planes, unloaded and with 10 g: gravity acts differently in every pose.
GRID = [(i, kappa, phi, mass) for i, (kappa, phi, mass) in
        enumerate((k, p, m) for k in (13.0, 26.2) for p in (0.0, 90.0) for m in (0.0, 0.01))]
# Base pointing down into a phantom: turned 180° about world x (backbone along −z).
DOWN_QUAT = "0,1,0,0"


def _validate(tmp_path, url: str, params=PARAMS):
    with open_device(url, params=params) as device:
        cal = nominal_calibration(params)
        device.set_calibration(gain_counts_per_n=cal["gain_counts_per_n"], offset_counts=cal["offset_counts"])
        run_validation(device, tmp_path, params, grid=GRID, progress=False)
        pose = device.base_rotation
    dataset = read_dataset(tmp_path)
    return pose, dataset, analyse_validation(dataset, params).summary()


@pytest.fixture(scope="module")
def horizontal(tmp_path_factory):
    return _validate(tmp_path_factory.mktemp("horizontal"), "sim://?seed=2")


@pytest.mark.parametrize("url, expected", [("sim://?seed=2&pose=up", UP),
                                           (f"sim://?seed=2&base_quat={DOWN_QUAT}", rot_x(np.pi))])
def test_an_upright_or_hanging_twin_validates_as_well_as_the_horizontal_one(tmp_path, horizontal, url, expected):
    _, flat_dataset, flat = horizontal
    pose, dataset, summary = _validate(tmp_path, url)
    assert np.allclose(pose, expected, atol=1e-12)
    assert np.allclose(dataset.base_rotation, expected, atol=1e-12)
    # The same tip positions in the clamp's frame would mean the pose never reached the twin.
    assert np.max(np.abs(dataset.tip_positions_m - flat_dataset.tip_positions_m)) > 0.01
    assert summary["failed_predictions"] == 0
    assert flat["median_error_mm"] < 0.3
    assert summary["median_error_mm"] < 2.0 * flat["median_error_mm"]
    assert summary["worst_error_mm"] < 2.0 * flat["worst_error_mm"]


def test_the_parameter_sets_base_pose_is_the_default_of_every_device():
    up = PARAMS.replace({"rig.base_quat": [1.0, 0.0, 0.0, 0.0]})
    with open_device("sim://", params=up) as device:
        assert np.array_equal(device.base_rotation, UP)
    with open_device("sim://", params=PARAMS) as device:
        assert np.array_equal(device.base_rotation, HORIZONTAL)
    tilted = [0.9, 0.1, 0.3, 0.0]
    with open_device("sim://", params=PARAMS.replace({"rig.base_quat": tilted})) as device:
        assert np.allclose(device.base_rotation, quat_to_matrix(tilted))
    # The twin is built in it: gravity bends the unloaded tip along world −z in every pose.
    with open_device("sim://", params=up) as device:
        device.wait(0.5)
        tip = device.twin.tip_pose()[0]
    assert abs(tip[0]) < 1e-3 and abs(tip[1]) < 1e-3 and tip[2] > 0.05


def test_a_device_url_pose_is_checked():
    with pytest.raises(ValueError, match="base_quat = '0,0,0,0'"):
        open_device("sim://?base_quat=0,0,0,0")
    with pytest.raises(ValueError, match="pose or base_quat, not both"):
        open_device("sim://?pose=up&base_quat=1,0,0,0")
    with pytest.raises(ValueError, match="pose = 'sideways'"):
        open_device("sim://?pose=sideways")
    with pytest.raises(ParameterError, match="rig.base_quat"):
        PARAMS.replace({"rig.base_quat": [0.0, 0.0, 0.0, 0.0]})


def test_the_env_aims_at_targets_in_the_devices_pose():
    from twin.envs.reach import EndoscopeReachEnv

    for url, rotation in (("sim://?pose=up", UP), ("sim://", HORIZONTAL)):
        env = EndoscopeReachEnv(device_url=url)
        try:
            env.reset(seed=0)
            # Targets lie on the arc of the 60 mm segment, along the clamp's axis.
            axial = rotation[:, 2] @ env.target_m
            assert 0.04 < axial < 0.0601
        finally:
            env.close()
