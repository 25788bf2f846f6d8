"""Predict each measurement of a dataset with the Cosserat model, and the errors against it.

Each row is predicted from its measured tensions and its known loads (tip mass, gravity), the
base orientation in the metadata, and a parameter set (by default the one recorded with the
data). The effects in that parameter set are applied the way :mod:`twin.effects` defines them,
so a parameter file written by the discrepancy workflow predicts with the named effect included.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from tqdm import tqdm

from twin import effects
from twin.data.dataset import Dataset
from twin.params import Params
from twin.rod import RodModel, solve_batch

__all__ = ["Predictions", "predict_dataset", "predict_rows"]

# Rows per compiled call: large enough that the call costs little beside its solves, small
# enough that the progress bar moves every fraction of a second.
_CHUNK_ROWS = 128


@dataclasses.dataclass(frozen=True)
class Predictions:
    """Predicted tip (tracker origin) positions for a dataset's rows, base frame.

    Attributes:
        tip_m: (rows, 3) predicted positions (NaN where the solve failed).
        measured_m: (rows, 3) measured positions.
        converged: (rows,) bool.
        residual_nm: (rows,) boundary residual of each solve (N·m).
        solve_time_s: (rows,) wall time per solve.
    """

    tip_m: np.ndarray
    measured_m: np.ndarray
    converged: np.ndarray
    residual_nm: np.ndarray
    solve_time_s: np.ndarray

    @property
    def errors_m(self) -> np.ndarray:
        """(rows, 3) predicted − measured (m)."""
        return self.tip_m - self.measured_m

    @property
    def error_norm_m(self) -> np.ndarray:
        """(rows,) |p̂ − p*| (m), the thesis's e_p."""
        return np.linalg.norm(self.errors_m, axis=1)

    @property
    def failures(self) -> int:
        return int(np.count_nonzero(~self.converged))

    def rms_m(self) -> float:
        """RMS of |p̂ − p*| over the converged rows (m)."""
        e = self.error_norm_m[self.converged]
        return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")


def predict_rows(params: Params, base_rotation, tensions_n, tip_mass_kg, lengths_m, *, progress: bool = False,
                 model: RodModel | None = None, guesses: list | None = None,
                 sliding_state=None, tip_moment_nm=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Predict tracker positions (base frame, m) for arrays of measurements.

    Args:
        sliding_state: (n, tendons) the friction's sliding state recorded with each row
            (:attr:`twin.data.dataset.Dataset.sliding_state`), or None (a dataset without it): the
            friction's direction is then guessed from the lengths (:func:`twin.effects.friction_direction`).
        guesses: one entry per row, the row's last converged :class:`twin.rod.RodSolution` or
            None: each row starts from its own entry instead of the previous row's solution, and
            its entry is replaced by the new one. Repeated predictions of the same rows under
            nearby parameter sets (a fit's evaluations) then converge in a Newton step or two.
        tip_moment_nm: a constant external moment at the tip (N·m, world frame) on every row, as a
            cable or a contact would put there (no parameter carries it; the discrepancy
            workflow's probes do), or None.

    Returns:
        (tip_m (n, 3), converged (n,), residual_nm (n,), solve_time_s (n,)).
    """
    model = model or RodModel.from_params(params)
    rotation = effects.clamp_rotation(params, base_rotation)
    tensions = np.clip(effects.true_tensions_n(params, tensions_n), 0.0, None)
    n = len(tip_mass_kg)
    tip = np.full((n, 3), np.nan)
    converged = np.zeros(n, dtype=bool)
    residual = np.full(n, np.nan)
    times = np.zeros(n)
    forces = np.array([effects.tip_force_n(params, mass) for mass in tip_mass_kg]).reshape(n, 3)
    directions = np.array([effects.friction_direction(lengths_m[i], params.effects.tendon_friction_direction,
                                                      None if sliding_state is None else sliding_state[i])
                           for i in range(n)]).reshape(n, model.tendon_count)
    # The rows are solved in chunks by one compiled call each (a progress bar moves per chunk);
    # a row without a guess of its own starts from the row before it, across chunks too.
    last = None
    with tqdm(total=n, desc="predicting", unit="row", disable=not progress, leave=False) as bar:
        for start in range(0, n, _CHUNK_ROWS):
            rows = range(start, min(n, start + _CHUNK_ROWS))
            starts = [None if guesses is None else guesses[i] for i in rows]
            if starts[0] is None:
                starts[0] = last
            solutions = solve_batch(model, tensions[rows.start:rows.stop], tip_force_n=forces[rows.start:rows.stop],
                                    tip_moment_nm=tip_moment_nm, base_rotation=rotation,
                                    friction_direction=directions[rows.start:rows.stop],
                                    guesses=starts, raise_on_failure=False)
            for i, sol in zip(rows, solutions):
                converged[i] = sol.converged
                residual[i] = sol.residual_nm
                times[i] = sol.solve_time_s
                if sol.converged:
                    tip[i] = effects.tracked_point_m(params, sol.tip_position_m, sol.tip_rotation)
                    if guesses is not None:
                        guesses[i] = sol
            last = solutions[-1] if solutions and solutions[-1].converged else None
            bar.update(len(rows))
    return tip, converged, residual, times


def predict_dataset(dataset: Dataset, params: Params | None = None, *, progress: bool = False,
                    guesses: list | None = None) -> Predictions:
    """Predict every row of ``dataset`` with ``params`` (default: the dataset's own parameter set);
    ``guesses`` as for :func:`predict_rows`.

    Raises:
        DatasetError: ``params`` is of a robot with another tendon count than the data's.
    """
    params = params or dataset.params
    dataset.check_robot(params)
    tip, converged, residual, times = predict_rows(
        params, dataset.base_rotation, dataset.tensions_n, dataset["tip_mass_kg"], dataset.lengths_m,
        progress=progress, guesses=guesses, sliding_state=dataset.sliding_state)
    return Predictions(tip, dataset.tip_positions_m, converged, residual, times)
