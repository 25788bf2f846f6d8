"""The MuJoCo twin of the endoscope and rig.

Model generation (:mod:`twin.sim.model`), the plant the device layer wraps
(:mod:`twin.sim.plant`), the motor and sensor models with the effects real rigs have
(:mod:`twin.effects`), rendering, the cross-check against the predictor and the benchmark.
"""

# twin/__init__.py has chosen MuJoCo's headless GL backend before anything here imports mujoco.
from typing import TYPE_CHECKING

from twin.lazy import lazy_exports

if TYPE_CHECKING:
    from twin.sim.bench import bench_sim
    from twin.sim.model import Layout, build_model, build_spec, model_xml
    from twin.sim.plant import DriveMode, Plant, SettleResult, SimulationError
    from twin.sim.sensors import LoadCellSample, TrackerSample

# name → the module that defines it, imported when the name is first used
_EXPORTS = {
    "bench_sim": "twin.sim.bench",
    "Layout": "twin.sim.model", "build_model": "twin.sim.model", "build_spec": "twin.sim.model",
    "model_xml": "twin.sim.model",
    "DriveMode": "twin.sim.plant", "Plant": "twin.sim.plant", "SettleResult": "twin.sim.plant",
    "SimulationError": "twin.sim.plant",
    "LoadCellSample": "twin.sim.sensors", "TrackerSample": "twin.sim.sensors",
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = [
    "DriveMode",
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
