"""The tip force of every row of a dataset (``twin force DATASET``, the rosbag export's wrenches)."""

from __future__ import annotations

from typing import Iterator

import numpy as np

from twin.force.estimator import WrenchEstimate, estimate_tip_wrench

__all__ = ["dataset_estimates"]


def dataset_estimates(dataset, params, **options) -> Iterator[WrenchEstimate]:
    """One estimate per row of ``dataset`` (a :class:`twin.data.dataset.Dataset`), in order: its
    load-cell tensions, tracked tip pose (position only where the row has no orientation), the
    dataset's base rotation and each row's recorded friction sliding state, on ``params``' robot.
    ``options`` go to :func:`twin.force.estimate_tip_wrench`."""
    from twin import effects
    from twin.pose import quat_to_matrix
    from twin.rod import RodModel

    model = RodModel.from_params(params)
    base = dataset.base_rotation
    tensions, lengths, sliding = dataset.tensions_n, dataset.lengths_m, dataset.sliding_state
    positions, quats = dataset.tip_positions_m, dataset.tip_quaternions
    sense = params.effects.tendon_friction_direction
    for i in range(len(dataset)):
        rotation = quat_to_matrix(quats[i]) if np.isfinite(quats[i]).all() else None
        yield estimate_tip_wrench(params, tensions[i], positions[i], rotation, base_rotation=base, model=model,
                                  friction_direction=effects.friction_direction(lengths[i], sense, sliding[i]),
                                  **options)
