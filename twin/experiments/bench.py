"""The friction figure of ``twin bench``: what tendon friction hidden in the twin costs a
validation sweep through ``sim://``, in CPU time, against the same sweep without it."""

from __future__ import annotations

import math
import tempfile
import time

from twin.data.dataset import DatasetError, read_dataset
from twin.driver import open_device
from twin.driver.errors import DeviceError
from twin.experiments.protocols import ProtocolError, apply_calibration, nominal_calibration, run_validation
from twin.params import Params, load_params
from twin.sim.plant import SimulationError

__all__ = ["FRICTION_COEFFS", "bench_friction", "friction_grid"]


# Friction coefficients (per radian of wrap) of bench_friction: a braided line in a printed hole is
# of order 0.1 (twin.effects.tendon_friction); 0.6 is the strongest a lab is asked to try.
FRICTION_COEFFS = (0.1, 0.3, 0.6)


def friction_grid() -> list[tuple[int, float, float, float]]:
    """The 16 rows (config, κ 1/m, φ °, tip mass kg) of :func:`bench_friction`: κ 13 and 26.2 1/m
    (the thesis grid's middle and most bent) in the four planes, 0 and 10 g, in that order."""
    return [(i, k, p, m) for i, (k, p, m) in enumerate(
        (k, p, m) for k in (13.0, 26.2) for p in (0.0, 90.0, 180.0, 270.0) for m in (0.0, 0.01))]


def bench_friction(params: Params | None = None, *, coeffs=FRICTION_COEFFS, seed: int = 2) -> dict:
    """CPU time of a validation sweep through ``sim://`` with tendon friction hidden in the twin,
    against the same sweep without (``twin bench friction``).

    The sweep is the thesis protocol (:func:`twin.experiments.protocols.run_validation`) on the
    bent configurations of κ 13 and 26.2 1/m in the four planes, 0 and 10 g: 16 rows, the most
    bent (where friction acts most) included. CPU time is ``time.process_time`` of this process
    (the emulated board and the twin run in it), after an untimed warm-up of two rows.

    Returns:
        ``frictionless_cpu_s``; per μ in ``coeffs``: ``friction`` one
        ``{"mu", "cpu_s", "cpu_ratio", "rows", "stopped"}`` each (``stopped``: why the sweep did
        not complete, empty when it did); ``cpu_ratio``: the largest ratio (inf when a sweep
        stopped), ``completed``: every sweep measured every row.
    """
    params = params if params is not None else load_params()
    grid = friction_grid()
    _sweep_cpu(params, params, grid[:2], seed)  # warm-up: the first sweep of a process loads and compiles
    base = _sweep_cpu(params, params, grid, seed)
    runs = []
    for mu in coeffs:
        run = _sweep_cpu(params, params.replace({"effects.tendon_friction_coeff": mu}, source="twin bench friction"),
                         grid, seed)
        ratio = run["cpu_s"] / base["cpu_s"] if not run["stopped"] else math.inf
        runs.append({"mu": mu, "cpu_s": run["cpu_s"], "cpu_ratio": ratio, "rows": run["rows"], "stopped": run["stopped"]})
    return {"frictionless_cpu_s": base["cpu_s"], "frictionless_rows": base["rows"], "friction": runs,
            "cpu_ratio": max(r["cpu_ratio"] for r in runs),
            "completed": not base["stopped"] and all(not r["stopped"] for r in runs)}


def _sweep_cpu(model: Params, twin: Params, grid, seed: int) -> dict:
    """``{"cpu_s", "rows", "stopped"}`` of one sweep of ``grid`` on the twin built from ``twin``."""

    stopped = ""
    with tempfile.TemporaryDirectory(prefix="twin-bench-friction-") as folder, \
            open_device("sim://", params=twin, seed=seed) as device:
        device.connect()
        # The robot's own load cells, as `twin validate` reads them: the default robot's
        # calibration on another robot's cells read a stiff-long tendon at -0.55 N, which the
        # dataset refuses.
        calibration = nominal_calibration(model)
        apply_calibration(device, calibration)
        start = time.process_time()
        try:
            run_validation(device, folder, model, grid=grid, progress=False, calibration=calibration)
        except (ProtocolError, DeviceError, SimulationError) as exc:
            stopped = f"{type(exc).__name__}: {exc}"
        cpu_s = time.process_time() - start
        try:
            rows = len(read_dataset(folder))
        except (DatasetError, OSError):
            rows = 0  # stopped before its first row: no dataset
    return {"cpu_s": cpu_s, "rows": rows, "stopped": stopped}
