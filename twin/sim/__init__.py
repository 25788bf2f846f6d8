"""The MuJoCo twin of the endoscope and rig.

Model generation (:mod:`twin.sim.model`), the plant the device layer wraps
(:mod:`twin.sim.plant`), the motor and sensor models with the effects real rigs have
(:mod:`twin.effects`), rendering, the cross-check against the predictor and the benchmark.
"""

# twin/__init__.py has chosen MuJoCo's headless GL backend before anything here imports mujoco.
from twin.sim.bench import bench_sim
from twin.sim.model import Layout, build_model, build_spec, model_xml
from twin.sim.plant import MODES, Plant, SettleResult, SimulationError
from twin.sim.sensors import LoadCellSample, TrackerSample

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
