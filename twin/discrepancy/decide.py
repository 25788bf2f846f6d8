"""The experiment that decides: when static data leave candidate effects tied (or the best of
them leaves structure), measure what tells them apart, on the rig or the twin, and decide.

Each effect names the experiments that reveal it (:attr:`twin.effects.Effect.deciding_experiments`);
for a set of contenders the workflow runs the union of theirs (:func:`designs_for`), through the
device interface, appends the rows to the dataset (their ``experiment`` column names the design)
and runs the workflow again on the whole (:func:`decide`). An experiment's rows join the dataset
only once it has completed: it runs on a copy, which then replaces the dataset's files, so one
that stops half-way (the device, a diverging twin, Ctrl-C) leaves the dataset as it was.

=============  ==========================================================  ==========================
design         what it measures                                            tells apart
=============  ==========================================================  ==========================
``reapproach`` the same configurations approached from the other side      friction (history) from
               (each tendon overshoots its target and comes back, so its   every static effect
               sliding state flips)
``pretension`` the same configurations at a higher pretension              load-cell offset / gain /
                                                                           tendon stretch from
                                                                           stiffness and weight
``tip-load``   the same bending planes with a heavier tip mass             stiffness, weight, tip
                                                                           load from the load cells
``planes``     bending planes between those measured                       tracker offset from base
                                                                           tilt
=============  ==========================================================  ==========================

The causes outside the library (:mod:`twin.discrepancy.probes`) mimic library effects on every
static sweep of one pose; what tells them apart needs a hand on the rig, so ``--device`` does not
run these (:data:`MANUAL_EXPERIMENTS`), the verdict names them:

=============  ==========================================================  ==========================
experiment     what it measures                                            tells apart
=============  ==========================================================  ==========================
``pose``       the sweep again with the base turned (another dataset)      a world-fixed tip moment
                                                                           from anything the robot
                                                                           carries with it
``register``   the clamp's pose measured with the tracker's probe          a tracker-frame rotation
                                                                           from a tilt or an offset
``zero``       each load cell read with its tendon unhooked                a load-cell offset from a
                                                                           curved backbone
=============  ==========================================================  ==========================
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import tempfile
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from twin import effects
from twin.data.dataset import Dataset
from twin.discrepancy.residuals import grouping_values
from twin.discrepancy.verdict import Verdict
from twin.params import Params

__all__ = ["DESIGNS", "MANUAL_EXPERIMENTS", "Design", "contenders", "decide", "designs_for", "experiments_for"]

# (κ, φ) groups a design re-measures: 12 groups × the dataset's tip masses is about a sixth of
# the thesis sweep (216 rows), enough rows for each tied parameter to be fitted on both sides.
_GROUPS = 12
# How far past its target each tendon goes before it comes back (a fraction of its move, at least
# _MIN_OVERSHOOT_M): far beyond the friction's presliding travel, little enough that the pulled
# tendons stay well inside the tension limit.
_OVERSHOOT = 0.25
_MIN_OVERSHOOT_M = 2e-4
# Pretension of the ``pretension`` design, relative to the dataset's: a third more moves an
# offset's share of each tension by a quarter while the shapes stay within the sweep's tensions.
_PRETENSION_FACTOR = 4 / 3
# Longest wait for the robot to come to rest in a configuration of a deciding experiment (device
# s): the validation sweep's 10 s is too short where the heavier tip of ``tip-load`` goes on at once
# over a bend that lifts it. The long robot at κ 15.72 1/m, φ 180° (the tip above the clamp) under
# 20 g falls sideways out of its plane, and tendon friction of μ 0.6 slows that fall: at rest after
# 18.8 and 19.2 s (sim://, seeds 0 and 1; 0.9 s without friction, 1.5 s at μ 0.3). 30 s covers it
# with a half to spare; a robot still moving after that stops the experiment as before.
_SETTLE_TIMEOUT_S = 30.0
# Rounds of deciding experiments: each runs the designs of the contenders left that were not run yet.
_MAX_ROUNDS = 3
# Candidates whose held-out RMS is within this fraction of the best's count as contenders when
# the workflow named or tied nothing decisive (see :func:`contenders`).
_CONTENDER_SPREAD = 0.25


@dataclasses.dataclass(frozen=True)
class Design:
    """One deciding experiment.

    Attributes:
        name: the design's name, the ``experiment`` its rows carry is ``decide-<name>``.
        purpose: one line: what it tells apart.
        plan: ``(dataset, params) -> (grid, options)``: the (κ 1/m, φ deg, tip mass kg) rows to
            measure and the keyword options of :func:`twin.experiments.protocols.run_validation`.
    """

    name: str
    purpose: str
    plan: Callable[[Dataset, Params], tuple[list[tuple[float, float, float]], dict]]

    @property
    def experiment(self) -> str:
        return f"decide-{self.name}"


def _groups(dataset: Dataset, count: int = _GROUPS) -> list[tuple[float, float]]:
    """Up to ``count`` bent (κ, φ) groups of the dataset's own rows, the most bent first and the
    planes spread: friction, offsets and tilts all grow with the bend."""
    kappa, phi = _commands(dataset)
    pairs = sorted({(float(k), float(p)) for k, p in zip(kappa, phi) if k > 0}, key=lambda g: (-g[0], g[1]))
    # An even stride through the list, which runs from the most bent level through its planes.
    return pairs if len(pairs) <= count else pairs[::len(pairs) // count][:count]


def _commands(dataset: Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Each row's (κ 1/m, φ deg) to command again: its own, or for a free pose its arc's
    (:meth:`Dataset.bends`), rounded to groups (:func:`grouping_values`) so that nearby poses
    are one configuration."""
    return grouping_values(dataset, "kappa_cmd_per_m"), grouping_values(dataset, "phi_cmd_deg")


def _masses(dataset: Dataset) -> list[float]:
    return sorted({float(m) for m in dataset["tip_mass_kg"]})


def _again(dataset: Dataset) -> list[tuple[float, float, float]]:
    """The :func:`_groups` configurations with every tip mass the dataset has."""
    return [(k, p, m) for k, p in _groups(dataset) for m in _masses(dataset)]


def _reapproach(dataset: Dataset, params: Params):
    return _again(dataset), {"overshoot": _OVERSHOOT, "min_overshoot_m": _MIN_OVERSHOOT_M}


def _pretension(dataset: Dataset, params: Params):
    return _again(dataset), {"pretension_n": params.tendons.pretension_n * _PRETENSION_FACTOR}


def _tip_load(dataset: Dataset, params: Params):
    heaviest = max(_masses(dataset))
    # Twice the heaviest measured (10 g when only unloaded rows were taken).
    masses = (0.0, 2 * heaviest if heaviest > 0 else 0.01)
    return [(k, p, m) for k, p in _groups(dataset) for m in masses], {}


def _planes(dataset: Dataset, params: Params):
    # Halfway between neighbouring planes of all the bent rows, not only of the groups re-measured.
    planes = sorted({float(p) for k, p in zip(*_commands(dataset)) if k > 0})
    spacing = min(np.diff(planes + [planes[0] + 360.0])) if len(planes) > 1 else 90.0
    return [(k, (p + spacing / 2) % 360.0, m) for k, p, m in _again(dataset)], {}


DESIGNS: dict[str, Design] = {d.name: d for d in (
    Design("reapproach", "the same configurations approached from the other side: friction remembers how a "
           "state was reached, no static effect does", _reapproach),
    Design("pretension", "the same configurations at a third more pretension: a load-cell offset, gain or tendon "
           "stretch scales differently with tension than the backbone's stiffness or weight", _pretension),
    Design("tip-load", "a heavier tip mass: stiffness, weight and tip load change the sag, the load cells do not",
           _tip_load),
    Design("planes", "bending planes between those measured: a tracker offset turns with the tip, a base tilt "
           "does not", _planes),
)}


# Experiments that tell a cause outside the library from the library's effects, by name: what to
# do, by hand (see the module doc).
MANUAL_EXPERIMENTS = {
    "pose": "the sweep again with the base turned (a new dataset): a moment fixed in the world keeps its direction "
            "while the robot turns, a load-cell offset or a curved backbone turns with it",
    "register": "the clamp's position and axis measured with the tracker's probe: a turned tracker frame shows "
                "there, a tilted clamp or an offset cap does not",
    "zero": "each load cell read with its tendon unhooked: an offset reads its offset, a curved backbone's cells "
            "read zero",
}


def experiments_for(names: Sequence[str]) -> list[str]:
    """The experiments that tell ``names`` (effects, or causes outside the library) from the
    rest: the union of each one's ``deciding_experiments``, in their order; a pair ``a+b`` counts
    as both."""
    from twin.discrepancy.probes import PROBES

    out: list[str] = []
    for name in names:
        for part in name.split("+"):
            entry = effects.EFFECTS.get(part) or PROBES.get(part)
            out += [e for e in (entry.deciding_experiments if entry else ()) if e not in out]
    return out


def designs_for(effect_names: Sequence[str]) -> list[Design]:
    """The deciding experiments of ``effect_names`` that a device can run: the union of each
    effect's :attr:`twin.effects.Effect.deciding_experiments` (:func:`experiments_for`) without
    the :data:`MANUAL_EXPERIMENTS`, in the effects' order."""
    return [DESIGNS[n] for n in experiments_for(effect_names) if n in DESIGNS]


def contenders(result) -> tuple[str, ...]:
    """The effects the static data could not tell apart in ``result``
    (:class:`twin.discrepancy.workflow.DiscrepancyResult`): when the answer is ``ambiguous`` or
    ``unexplained``, a tie's candidates, the stand-ins, the causes outside the library that
    explain as well, and every first-round candidate whose held-out RMS is within a quarter of
    the best's. Empty when the verdict needs no deciding."""
    if result.verdict not in (Verdict.AMBIGUOUS, Verdict.UNEXPLAINED):
        return ()
    names = list(result.named) + [e for s in result.tied + result.stand_ins + result.outside for e in s.effects]
    scores = [s for s in result.rounds[0].scores if np.isfinite(s.score)] if result.rounds else []
    if scores:
        best = min(s.heldout_rms_m for s in scores)
        names += [e for s in scores if s.heldout_rms_m <= best * (1 + _CONTENDER_SPREAD) for e in s.effects]
    return tuple(dict.fromkeys(names))


@dataclasses.dataclass(frozen=True)
class Decision:
    """What :func:`decide` ran and what the workflow then answered.

    Attributes:
        contenders: the effects it had to tell apart (over all its rounds).
        designs: the experiments run (names), each appended to the dataset.
        rows_added: rows appended.
        result: the workflow's result on the extended dataset.
    """

    contenders: tuple[str, ...]
    designs: tuple[str, ...]
    rows_added: int
    result: object


def decide(result, device, dataset_folder: str | Path, params: Params, *, progress: bool = True,
           run_workflow: Callable | None = None, max_rounds: int = _MAX_ROUNDS) -> Decision | None:
    """Run the experiments that tell ``result``'s contenders apart on ``device``, append them to
    the dataset in ``dataset_folder`` and run the workflow again on all of it; while the answer
    is still undecided and new contenders bring experiments not yet run, once more (at most
    ``max_rounds`` rounds).

    Args:
        result: the workflow's result on the dataset as it was.
        device: a connected :class:`twin.driver.Device` with fixture and tracker (the rig the
            dataset was taken on, or the twin built as that rig).
        dataset_folder: the dataset's folder; rows are appended to it.
        params: the model the workflow tests (its pretension and geometry set the setpoints).
        run_workflow: ``dataset -> result`` (default :func:`twin.discrepancy.workflow.run_discrepancy`
            with its defaults).

    Returns:
        the decision, or None when nothing needs deciding or no design applies.

    Raises:
        whatever stops an experiment (:class:`twin.driver.errors.DeviceError`,
        :class:`twin.experiments.protocols.ProtocolError`, :class:`twin.sim.plant.SimulationError`,
        ``KeyboardInterrupt``): the dataset then holds the experiments completed before it.
    """
    from twin.data.dataset import read_dataset
    from twin.discrepancy.workflow import run_discrepancy
    from twin.experiments.protocols import run_validation

    run = run_workflow or (lambda d: run_discrepancy(d, params, progress=progress))
    dataset = read_dataset(dataset_folder)
    before = len(dataset)
    seen: list[str] = []
    ran: list[str] = []
    for _ in range(max_rounds):
        names = contenders(result)
        seen += [n for n in names if n not in seen]
        designs = [d for d in designs_for(names) if d.name not in ran]
        if not designs:
            break
        first = int(np.max(dataset["config"])) + 1
        for design in designs:
            grid, options = design.plan(dataset, params)
            rows = [(first + i, k, p, m) for i, (k, p, m) in enumerate(grid)]
            first += len(rows)
            _staged(dataset_folder, lambda folder: run_validation(
                device, folder, params, grid=rows, experiment=design.experiment, progress=progress,
                settle_timeout_s=_SETTLE_TIMEOUT_S, **options))
            ran.append(design.name)
        dataset = read_dataset(dataset_folder)
        result = run(dataset)
    if not ran:
        return None
    return Decision(tuple(seen), tuple(ran), len(dataset) - before, result)


def _staged(dataset_folder: str | Path, experiment: Callable[[Path], object]) -> None:
    """Run ``experiment(folder)`` on a copy of the dataset beside it and, once it returns, move
    the copy's files over the dataset's (each replaced atomically); when it raises, the copy is
    removed and the dataset is untouched."""
    from twin.data.dataset import MEASUREMENTS, METADATA

    folder = Path(dataset_folder)
    with tempfile.TemporaryDirectory(prefix=f".{folder.name}-deciding-", dir=folder.parent) as scratch:
        copy = Path(scratch) / folder.name
        shutil.copytree(folder, copy)
        experiment(copy)
        # The rows first: metadata an appending writer rewrote describes them.
        for name in (MEASUREMENTS, METADATA):
            os.replace(copy / name, folder / name)
