"""The generated model: checked-in files match the generator; every scene steps without warnings."""

import numpy as np
import pytest

from twin.params import load_params
from twin.pose import HORIZONTAL, UP, rot_x
from twin.sim import Plant, model_xml
from twin.sim.model import Layout
from twin.robots import MODELS_DIR, load_robot, robot_names
from twin.sim.modelfiles import index_text, readme_text

FAST = ["sim.elements=10"]


@pytest.mark.parametrize("name", robot_names())
def test_checked_in_model_files_match_the_generator(name):
    params = load_robot(name)
    stale = f"models/{name}/ is stale: run .venv/bin/python -m twin.sim.modelfiles"
    assert (MODELS_DIR / name / f"{name}.xml").read_text() == model_xml(params, base_rotation=params.rig.base_rotation), stale
    assert (MODELS_DIR / name / "README.md").read_text() == readme_text(params, name), stale
    assert (MODELS_DIR / name / "CHANGELOG.md").is_file(), f"models/{name}/CHANGELOG.md is missing"


def test_the_zoo_index_lists_every_robot():
    assert (MODELS_DIR / "README.md").read_text() == index_text(), \
        "models/README.md is stale: run .venv/bin/python -m twin.sim.modelfiles"
    assert {"endoscope", "three-tendon", "two-segment", "helical", "long", "endoscope-soft-g"} <= set(robot_names())
    assert robot_names()[0] == "endoscope"


def test_layout_puts_discs_and_mass_where_the_parameters_say():
    params = load_params(overrides=FAST)
    layout = Layout.from_params(params)
    assert np.allclose(layout.disc_s_m, np.arange(1, 11) * 0.006)
    assert np.allclose(layout.rest_length_m, 0.05 + 0.06)
    plant = Plant(params)
    backbone = sum(plant.model.body(f"b{k}").mass[0] for k in range(1, 11))
    # The clamp holds the first half-element, so the chain carries (1 - 1/(2N)) of the mass.
    assert backbone == pytest.approx(params.backbone.mass_kg * (1 - 1 / 20))


SCENES = {
    "horizontal, pwm": dict(pose=HORIZONTAL, mode=("pwm", [-0.05, 0.02, 0.0, 0.02])),
    "up, tension": dict(pose=UP, mode=("tension", [2.0, 1.35, 1.35, 1.35])),
    "tilted, length": dict(pose=rot_x(0.3) @ HORIZONTAL, mode=("length", [-0.002, 0.0, 0.002, 0.0])),
    "coast with tip mass": dict(pose=HORIZONTAL, mode=("coast", None), mass=0.01),
    "holder engaged": dict(pose=HORIZONTAL, mode=("tension", [1.35] * 4), holder=True),
    "all effects": dict(pose=HORIZONTAL, mode=("tension", [2.5, 1.35, 1.35, 1.35]), mass=0.005, overrides=[
        "effects.tendon_friction_coeff=0.1", "effects.tendon_compliance_m_per_n=5e-5",
        "effects.tension_gain_error=[0.05,0,0,-0.03]", "effects.tension_offset_error_n=[0.1,0,0,0]",
        "effects.disc_mass_fraction=0.5", "effects.base_tilt_deg=[2,-1]",
        "effects.tip_load_error_fraction=0.1", "effects.tracker_offset_m=[0.001,0,0.002]"]),
}


@pytest.mark.parametrize("name", SCENES)
def test_every_scene_steps_without_warnings(name):
    scene = SCENES[name]
    plant = Plant(load_params(overrides=FAST + scene.get("overrides", [])), base_rotation=scene["pose"])
    mode, value = scene["mode"]
    if scene.get("holder"):
        plant.engage_holder()
    plant.set_tip_mass_kg(scene.get("mass", 0.0))
    {"pwm": plant.set_motor_pwm, "tension": plant.set_tensions, "length": plant.set_tendon_lengths,
     "coast": lambda _: plant.coast()}[mode](value)
    plant.step(0.3)
    assert plant.warnings() == {}
    assert np.all(np.isfinite(plant.data.qpos)) and np.all(np.isfinite(plant.data.qvel))
