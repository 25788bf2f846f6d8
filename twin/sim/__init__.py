"""The MuJoCo twin of the endoscope and rig (issue 3).

Model generation (:mod:`twin.sim.model`), the plant the device layer wraps
(:mod:`twin.sim.plant`), the motor and sensor models, the effects real rigs have
(:mod:`twin.sim.effects`), rendering, the cross-check against the predictor and the benchmark.
"""

import os

if not os.environ.get("DISPLAY"):
    # Without a display GLFW cannot render; MuJoCo picks its GL backend when it is first
    # imported, so choose headless EGL here, before any twin.sim module imports mujoco.
    os.environ.setdefault("MUJOCO_GL", "egl")

from twin.sim.bench import bench_sim  # noqa: E402
from twin.sim.model import Layout, build_model, build_spec, model_xml  # noqa: E402
from twin.sim.plant import MODES, Plant, SettleResult, SimulationError  # noqa: E402
from twin.sim.sensors import LoadCellSample, TrackerSample  # noqa: E402

__all__ = [
    "MODES",
    "Layout",
    "LoadCellSample",
    "Plant",
    "SettleResult",
    "SimulationError",
    "TrackerSample",
    "bench_sim",
    "build_model",
    "build_spec",
    "model_xml",
]
