"""The rendered picture of the bent endoscope (skipped, with the reason, when no GL backend works)."""

import numpy as np
import pytest

from twin.params import load_params
from twin.sim import Plant
from twin.sim.render import RenderError, render_png


def test_render_png_draws_the_bent_endoscope(tmp_path):
    plant = Plant(load_params(overrides=["sim.elements=10"]))
    plant.set_tensions([2.5, 1.35, 1.35, 1.35])
    plant.settle()
    try:
        path = render_png(plant, tmp_path / "bent.png", width=160, height=120)
    except RenderError as exc:
        pytest.skip(f"no headless OpenGL here: {exc}")
    import matplotlib.image

    pixels = matplotlib.image.imread(path)
    assert pixels.shape[:2] == (120, 160)
    assert np.ptp(pixels[..., :3]) > 0.2  # something was drawn on the background
