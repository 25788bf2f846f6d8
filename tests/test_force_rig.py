"""The tip force estimate on the rig-like path: hidden loads on the twin behind sim://."""

from __future__ import annotations

import numpy as np

from twin.device import open_device
from twin.force.rig import rig_summary, rig_trials
from twin.params import load_params


def test_hidden_tip_loads_on_the_twin_are_estimated_from_the_devices_telemetry():
    params = load_params()
    forces = [[0.0, 0.0, 0.0], [0.0, 0.15, 0.0], [0.1, -0.05, -0.05]]
    with open_device("sim://?seed=1", params=params) as device:
        rows = rig_trials(device, params, forces, poses=(("bent", 5.0, 0.0),), frames=4)
    assert len(rows) >= 10
    (summary,) = rig_summary(rows)
    assert summary["median_error_over_goal"] <= 1.0
    assert summary["coverage"] >= 0.75  # 12 estimates: a looser bar than the 90 % goal over many
    assert summary["converged"] == 1.0
    # The loads are seen: the error is far below the load itself.
    loaded = [r for r in rows if np.linalg.norm(r["true_force_n"]) > 0]
    assert max(r["error_n"] for r in loaded) < 0.02
