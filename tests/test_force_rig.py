"""The tip force estimate on the rig-like path: hidden loads on the twin behind sim://."""

from __future__ import annotations

import numpy as np
import pytest

from twin.driver import open_device
from twin.dynamics.force_rig import rig_summary, rig_trials
from twin.params import load_params


@pytest.mark.parametrize("friction", [0.0, 0.3])
def test_hidden_tip_loads_on_the_twin_are_estimated_from_the_devices_telemetry(friction):
    params = load_params().replace({"effects.tendon_friction_coeff": friction}, source="test")
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


def test_a_load_appearing_at_the_moving_tip_is_flagged_fast_and_a_clean_run_is_not():
    params = load_params()
    from twin.dynamics.force_rig import contact_run

    loads = [[0.0, 0.03, 0.0], [-0.1, 0.0, 0.08]]
    with open_device("sim://?seed=2", params=params) as device:
        out = contact_run(device, params, clean_s=4.0, loads_n=loads, quiet_s=1.0, load_hold_s=0.5)
    assert out["false_alarms"] == 0
    assert len(out["latencies_s"]) == 2
    assert all(np.isfinite(t) and t <= 0.1 for t in out["latencies_s"])


def test_the_contact_detector_latches_on_a_step_and_ignores_noise():
    from twin.force.contact import ContactDetector
    from twin.force.estimator import WrenchEstimate

    rng = np.random.default_rng(0)
    cov = np.diag([1e-6, 1e-6, 0.0])  # 1 mN in x and y; z unobservable

    def estimate(force):
        nan3 = np.full(3, np.nan)
        return WrenchEstimate(nan3, cov, np.array([True, True, False]), np.asarray(force, float), cov,
                              np.array([[0.0, 0.0, 1.0]]), None, None, None, None, np.ones(3), True, 1, 0.0,
                              None, 0.0, nan3, np.eye(3))

    detector = ContactDetector()
    flags = [detector.update(estimate([*rng.normal(0, 1e-3, 2), 0.0])).contact for _ in range(2000)]
    assert not any(flags)
    after = [detector.update(estimate([0.01 + rng.normal(0, 1e-3), rng.normal(0, 1e-3), 0.0])).contact
             for _ in range(4)]
    assert after[-1] and after.index(True) <= 1  # flagged at once and latched
    detector.reset()
    assert not detector.update(estimate([0.01, 0.0, 0.0])).contact
