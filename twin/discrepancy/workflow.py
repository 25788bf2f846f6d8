"""The discrepancy workflow: find → name → add → show, on one dataset.

Example:
    >>> from twin.data.dataset import read_dataset
    >>> result = run_discrepancy(read_dataset("runs/validate"))
    >>> print(result.effect, result.parameters(), result.rms_before_m, result.rms_after_m)
    >>> result.params_after.save("endoscope-fitted.toml")
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from twin.discrepancy.candidates import UNTESTABLE_EFFECTS, candidate_library
from twin.discrepancy.naming import Round, row_errors, rank_candidates, split_rows
from twin.discrepancy.residuals import ResidualMap, find_discrepancy, thesis_signature
from twin.data.dataset import Dataset
from twin.data.fitting import ParameterFit, fit_parameters
from twin.params import Params

__all__ = ["DiscrepancyResult", "run_discrepancy"]


@dataclasses.dataclass(frozen=True)
class DiscrepancyResult:
    """Everything the workflow found, named, added and measured.

    Attributes:
        dataset: the measurements.
        params_before: the model it started from.
        params_after: the model with every named effect's fitted values (source ``fitted: discrepancy …``).
        train, test: row masks of the split.
        seed: the split's seed.
        residuals: the Find step on all rows with ``params_before``.
        rounds: the greedy rounds (the last one named nothing, unless ``max_effects`` stopped it).
        named: the effects named, in order.
        fit: the fit of the named effects' parameters on the training rows, jointly when there are
            several (None if none named).
        errors_before_m, errors_after_m: (held-out rows, 3) p̂ − p* before and after (failures charged).
        converged_before, converged_after: (held-out rows,) which held-out predictions exist.
    """

    dataset: Dataset
    params_before: Params
    params_after: Params
    train: np.ndarray
    test: np.ndarray
    seed: int
    residuals: ResidualMap
    rounds: tuple[Round, ...]
    named: tuple[str, ...]
    fit: ParameterFit | None
    errors_before_m: np.ndarray
    errors_after_m: np.ndarray
    converged_before: np.ndarray
    converged_after: np.ndarray

    @property
    def effect(self) -> str:
        """The first named effect, or ``none``."""
        return self.named[0] if self.named else "none"

    @property
    def rms_before_m(self) -> float:
        """Held-out RMS of |p̂ − p*| with the starting model (m)."""
        return float(np.sqrt(np.mean(np.sum(self.errors_before_m**2, axis=1))))

    @property
    def rms_after_m(self) -> float:
        """Held-out RMS of |p̂ − p*| with the named effects added (m)."""
        return float(np.sqrt(np.mean(np.sum(self.errors_after_m**2, axis=1))))

    def heldout_table(self) -> list[dict]:
        """Per held-out configuration: its settings and |e| before and after (mm)."""
        d = self.dataset.subset(self.test)
        before = np.linalg.norm(self.errors_before_m, axis=1) * 1e3
        after = np.linalg.norm(self.errors_after_m, axis=1) * 1e3
        return [{"config": int(d["config"][i]), "kappa_cmd_per_m": float(d["kappa_cmd_per_m"][i]),
                 "phi_cmd_deg": float(d["phi_cmd_deg"][i]), "tip_mass_kg": float(d["tip_mass_kg"][i]),
                 "error_before_mm": float(before[i]), "error_after_mm": float(after[i])} for i in range(len(d))]

    def signatures(self) -> dict:
        """:func:`thesis_signature` of the held-out residuals before and after."""
        phi = self.dataset["phi_cmd_deg"][self.test]
        return {"before": thesis_signature(self.errors_before_m, phi),
                "after": thesis_signature(self.errors_after_m, phi)}

    def parameters(self) -> dict:
        """Fitted values with standard errors of every named effect's parameters (label → dict)."""
        if self.fit is None:
            return {}
        return {row["parameter"]: {"value": row["value"], "std_error": row["std_error"],
                                   "ci95": [row["ci95_low"], row["ci95_high"]]} for row in self.fit.table()}

    def to_dict(self) -> dict:
        """The ``twin discrepancy --json`` object."""
        first = self.rounds[0]
        return {
            "dataset": str(self.dataset.path) if self.dataset.path else None,
            "effect": self.effect,
            "effects": list(self.named),
            "parameters": self.parameters(),
            "rms_before_m": self.rms_before_m,
            "rms_after_m": self.rms_after_m,
            "ranking": [{"effect": s.effect, "score": s.score, "heldout_rms_m": s.heldout_rms_m,
                         "parameters": s.parameters, "beats_noise": s.beats_noise} for s in first.scores],
            "rounds": [r.to_dict() for r in self.rounds],
            "find": self.residuals.to_dict(),
            "split": {"seed": self.seed, "train_rows": int(self.train.sum()), "heldout_rows": int(self.test.sum())},
            "failed_heldout_before": int(np.count_nonzero(~self.converged_before)),
            "failed_heldout_after": int(np.count_nonzero(~self.converged_after)),
            "signature": self.signatures(),
            "untestable": UNTESTABLE_EFFECTS,
        }


def run_discrepancy(dataset: Dataset, params: Params | None = None, *, holdout_fraction: float = 1 / 3,
                    seed: int = 0, max_effects: int = 3, max_evaluations: int = 25,
                    progress: bool = False) -> DiscrepancyResult:
    """Find, name, add and show the effects missing from ``params`` for ``dataset``.

    Args:
        dataset: the measurements (e.g. a validation sweep).
        params: the model to start from (default the parameter set recorded with the data).
        holdout_fraction: share of configurations held out from every fit.
        seed: seed of the split.
        max_effects: stop after naming this many.
        max_evaluations: optimiser iterations per candidate fit.
        progress: progress bars on stderr.

    Raises:
        ValueError: ``max_effects`` < 1, no row can be predicted, or the dataset is too small to split.
    """
    if max_effects < 1:
        raise ValueError(f"max_effects = {max_effects!r}: must be >= 1")
    params = params or dataset.params
    residuals = find_discrepancy(dataset, params, progress=progress)
    train, test = split_rows(dataset, holdout_fraction, seed)
    name = dataset.path.name if dataset.path else "dataset"
    source = f"fitted: discrepancy {name} (training split, seed {seed})"
    library = candidate_library(params)
    current = params
    rounds: list[Round] = []
    named: list[str] = []
    fit: ParameterFit | None = None
    while len(named) < max_effects:
        remaining = [c for effect, c in library.items() if effect not in named]
        if not remaining:
            break
        ranked = rank_candidates(dataset, current, remaining, train, test, source=source,
                                 max_evaluations=max_evaluations, progress=progress,
                                 label=f"round {len(rounds) + 1}")
        if not rounds and not residuals.structure.beyond_noise:
            # Find and Name must agree: with no structure beyond noise in the residuals there is
            # nothing to name, even if a candidate's own F-test passes on the training rows.
            ranked = dataclasses.replace(ranked, winner=None)
        rounds.append(ranked)
        if ranked.winner is None:
            break
        named.append(ranked.winner.effect)
        fit = ranked.winner.fit
        if len(named) > 1:
            # Each greedy value was fitted with the earlier effects held, and an effect named
            # first has absorbed some of what a later one explains; refit them together before
            # the next round, or the leftover bias is named as yet another effect.
            parameters = [p for rnd in rounds if rnd.winner for p in rnd.winner.fit.parameters]
            # Discrete choices a winner made (friction's sliding direction) stay as chosen.
            carried = {key: fit.params.get(key) for effect in named for variant in library[effect].variants
                       for key in variant}
            start = params.replace(carried, source=source) if carried else params
            fit = fit_parameters(dataset, start, parameters, x0=[_value(fit.params, p) for p in parameters],
                                 source=f"{source}: {', '.join(named)}", max_evaluations=max_evaluations, rows=train)
        current = fit.params
    errors_before, ok_before = row_errors(dataset, params, test)
    errors_after, ok_after = row_errors(dataset, current, test)
    return DiscrepancyResult(dataset, params, current, train, test, seed, residuals, tuple(rounds), tuple(named),
                             fit, errors_before, errors_after, ok_before, ok_after)


def _value(params: Params, parameter) -> float:
    value = params.get(parameter.key)
    return float(value if parameter.index is None else value[parameter.index])
