"""Shared fixtures: synthetic datasets made with the predictor (fast, known truth), and the
repository's scripts loaded as modules."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from twin import load_params
from twin.data.dataset import write_dataset
from twin.pose import HORIZONTAL
from twin.rod import RodModel, solve


def load_script(path: Path):
    """The Python file at ``path`` (a script, not a package module) loaded as a module named after it."""
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def synthetic_rows(true_params, cases, *, noise_m=0.0, seed=0):
    """Rows measured on a perfect predictor of ``true_params``: cases = (config, κ, φ, mass, tensions, lengths)."""
    rng = np.random.default_rng(seed)
    model = RodModel.from_params(true_params, with_effects=False)
    rows = []
    for config, kappa, phi, mass, tensions, lengths in cases:
        sol = solve(model, tensions, tip_force_n=[0, 0, -mass * true_params.environment.gravity_m_s2],
                    base_rotation=HORIZONTAL)
        tip = sol.tip_position_m + rng.normal(0, noise_m, 3)
        row = {"config": config, "kappa_cmd_per_m": kappa, "phi_cmd_deg": phi, "tip_mass_kg": mass,
               "tip_x_m": tip[0], "tip_y_m": tip[1], "tip_z_m": tip[2]}
        for i in range(4):
            row[f"tension_{i + 1}_n"] = tensions[i]
            row[f"length_{i + 1}_m"] = lengths[i]
        rows.append(row)
    return rows


@pytest.fixture
def make_dataset(tmp_path):
    counter = iter(range(1000))

    def make(rows, *, experiment="validation", params=None):
        return write_dataset(tmp_path / f"ds{next(counter)}", rows, experiment=experiment, device="synthetic",
                             params=params or load_params(), base_rotation=HORIZONTAL)

    return make
