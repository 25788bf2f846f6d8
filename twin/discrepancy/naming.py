"""Name: fit every candidate effect on a training split, rank them on held-out rows, name a winner.

The rule (documented here because the ranking and the verdict follow from it):

* **Split.** Configurations (κ, φ, tip mass; repeats stay together) are shuffled with a given
  seed and a fraction is held out; candidates are fitted on the rest only.
* **Score** of a candidate with k fitted parameters, lower is better::

      S = N_h · ln(MSE_h / MSE_h,0) + k · ln(N_t)

  MSE_h is the mean squared per-axis error on the N_h held-out residuals (3 per row; a failed
  prediction counts as the fitting penalty), MSE_h,0 that of the current model, N_t the number
  of training residuals. The first term is the held-out log-likelihood gain under Gaussian
  noise; the second the Bayesian information criterion's price per parameter, so a 4-parameter
  candidate must earn more than a 1-parameter one. The current model scores 0.
* **Beats noise** when S < 0 *and* the training fit passes an F-test against the current
  model, F = ((RSS₀ − RSS₁)/k) / (RSS₁/(N_t − k)) with p < :data:`NAME_ALPHA` divided by the
  number of candidates (Bonferroni: eight tries at chance must not name one) *and* the
  held-out RMS falls by at least :data:`MIN_HELDOUT_GAIN` (a tenth): the predictor and the twin
  themselves agree only to a few hundredths of a millimetre (``reports/crosscheck``), and with
  averaged tracker frames the statistics alone resolve such model-form differences — naming an
  effect for them would be a false alarm on data with no effect. The winner is the lowest score
  among those that beat noise; if none does, the answer is ``none``.
* **Undetermined parameters are dropped.** A fitted parameter whose standard error exceeds half
  its value (log-fitted) or its typical size ``scale`` (others) is not determined by the data
  (e.g. G, once tendon tension carries most of the shear); the candidate is refitted without it,
  so it stays at its prior value and is not written into the parameter set as if measured.
* **Find first.** Nothing is named in the first round unless the Find step declared structured
  disagreement beyond noise (:mod:`twin.discrepancy.residuals`), so the two never contradict.
* **Greedy.** The winner's fitted values go into the model, and the remaining candidates are
  ranked again against it, until nothing beats noise (or ``max_effects`` are named).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np
from scipy import stats
from tqdm import tqdm

from twin.discrepancy.candidates import Candidate
from twin.discrepancy.noise import configuration_keys
from twin.data.dataset import Dataset
from twin.data.prediction import predict_rows
from twin.data.fitting import ParameterFit, fit_parameters
from twin.params import Params

__all__ = ["NAME_ALPHA", "MIN_HELDOUT_GAIN", "CandidateScore", "Round", "split_rows", "row_errors", "rank_candidates"]

NAME_ALPHA = 1e-3
# Smallest relative drop of the held-out RMS that names an effect (see the module rule).
MIN_HELDOUT_GAIN = 0.10
# Error (m per axis) charged for a held-out row the model cannot predict; as in twin.data.fitting.
FAILED_ROW_PENALTY_M = 0.05


def split_rows(dataset: Dataset, holdout_fraction: float = 1 / 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic split by configuration: (train mask, held-out mask), repeats kept together.

    Raises:
        ValueError: a fraction outside (0, 1), or too few configurations to split.
    """
    if not 0 < holdout_fraction < 1:
        raise ValueError(f"holdout_fraction = {holdout_fraction!r}: must be in (0, 1)")
    labels = configuration_keys(dataset)
    unique = np.unique(labels)
    held = int(round(holdout_fraction * len(unique)))
    if held < 1 or held >= len(unique):
        raise ValueError(f"{len(unique)} configurations cannot be split with holdout_fraction = {holdout_fraction!r}")
    chosen = np.random.default_rng(seed).permutation(unique)[:held]
    test = np.isin(labels, chosen)
    return ~test, test


def row_errors(dataset: Dataset, params: Params, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """p̂ − p* on the ``rows`` mask: (errors_m (n, 3), failures charged :data:`FAILED_ROW_PENALTY_M`; converged (n,))."""
    data = dataset.subset(rows)
    tip, ok, _, _ = predict_rows(params, data.base_rotation, data.tensions_n, data["tip_mass_kg"], data.lengths_m)
    err = tip - data.tip_positions_m
    err[~ok] = FAILED_ROW_PENALTY_M
    return err, ok


def _undetermined(fit: ParameterFit) -> list[int]:
    """Indices of parameters the data leave undetermined (module rule)."""
    out = []
    for i, (p, value, std) in enumerate(zip(fit.parameters, fit.values, fit.std_errors)):
        limit = 0.5 * abs(value) if p.log else p.scale
        if not np.isfinite(std) or std > limit:
            out.append(i)
    return out


def _rms3(errors_m: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(errors_m**2, axis=1))))


@dataclasses.dataclass(frozen=True)
class CandidateScore:
    """One candidate's outcome in a round.

    Attributes:
        effect: the effect's name.
        fit: its fit on the training rows (None when it does not apply to the dataset).
        parameters: number of fitted parameters k.
        train_rms_m, heldout_rms_m: RMS of |p̂ − p*| (m) on the training and held-out rows.
        score: S of the module rule (0 = no better than the current model; +inf when not applicable).
        f_statistic, p_value: training F-test against the current model.
        beats_noise: S < 0, p < :data:`NAME_ALPHA` / candidates, some parameter determined, and the
            held-out RMS at least :data:`MIN_HELDOUT_GAIN` lower.
        note: why it was not fitted, if it was not.
    """

    effect: str
    fit: ParameterFit | None
    parameters: int
    train_rms_m: float
    heldout_rms_m: float
    score: float
    f_statistic: float
    p_value: float
    beats_noise: bool
    note: str = ""

    def to_dict(self) -> dict:
        out = {"effect": self.effect, "score": self.score, "parameters": self.parameters,
               "train_rms_m": self.train_rms_m, "heldout_rms_m": self.heldout_rms_m,
               "f_statistic": self.f_statistic, "p_value": self.p_value, "beats_noise": self.beats_noise}
        if self.fit is not None:
            out["fit"] = self.fit.table()
        if self.note:
            out["note"] = self.note
        return out


@dataclasses.dataclass(frozen=True)
class Round:
    """One greedy round: every candidate ranked against the current model.

    Attributes:
        baseline_train_rms_m, baseline_heldout_rms_m: the current model's RMS (m).
        scores: candidates, best (lowest score) first.
        winner: the named candidate, or None.
    """

    baseline_train_rms_m: float
    baseline_heldout_rms_m: float
    scores: tuple[CandidateScore, ...]
    winner: CandidateScore | None

    def to_dict(self) -> dict:
        return {"baseline_train_rms_m": self.baseline_train_rms_m,
                "baseline_heldout_rms_m": self.baseline_heldout_rms_m,
                "winner": self.winner.effect if self.winner else "none",
                "ranking": [s.to_dict() for s in self.scores]}


def rank_candidates(dataset: Dataset, params: Params, candidates: Sequence[Candidate], train: np.ndarray,
                    test: np.ndarray, *, source: str, max_evaluations: int = 25, progress: bool = False,
                    label: str = "candidates") -> Round:
    """Fit each candidate on ``train``, score it on ``test`` (module rule) and pick the winner.

    Args:
        dataset: the measurements.
        params: the current model.
        candidates: what to try.
        train, test: row masks.
        source: provenance written for fitted keys (the effect's name is appended).
        max_evaluations: optimiser iterations per candidate (see :func:`twin.data.fitting.fit_parameters`).
        progress: show a progress bar on stderr.
        label: the progress bar's title.
    """
    base_train, _ = row_errors(dataset, params, train)
    base_test, _ = row_errors(dataset, params, test)
    rss0, mse0 = float(np.sum(base_train**2)), float(np.mean(base_test**2))
    n_train, n_test = base_train.size, base_test.size
    alpha = NAME_ALPHA / max(1, len(candidates))
    scores = []
    bar = tqdm(candidates, desc=label, unit="effect", disable=not progress, leave=False)
    for candidate in bar:
        bar.set_postfix_str(candidate.effect)
        k = len(candidate.parameters)
        if not candidate.applies(dataset.subset(train)):
            scores.append(CandidateScore(candidate.effect, None, k, _rms3(base_train), _rms3(base_test), math.inf,
                                         0.0, 1.0, False, note="the data cannot show it"))
            continue
        x0 = candidate.x0(params)
        fit, start = None, params
        for fixed in candidate.variants or ({},):
            trial_params = params.replace(fixed, source=f"{source}: {candidate.effect}") if fixed else params
            trial = fit_parameters(dataset, trial_params, candidate.parameters, x0=x0,
                                   source=f"{source}: {candidate.effect}", max_evaluations=max_evaluations, rows=train)
            if fit is None or trial.rms_m < fit.rms_m:
                fit, start = trial, trial_params
        loose = _undetermined(fit)
        determined = len(loose) < k
        note = "" if determined else "not determined by the data"
        if loose and len(loose) < k:
            note = "not determined, kept: " + ", ".join(
                f"{fit.parameters[i].label} ({fit.values[i]:.3g} ± {fit.std_errors[i]:.2g})" for i in loose)
            keep = [i for i in range(k) if i not in loose]
            fit = fit_parameters(dataset, start, [candidate.parameters[i] for i in keep], x0=[x0[i] for i in keep],
                                 source=f"{source}: {candidate.effect}", max_evaluations=max_evaluations, rows=train)
            k = len(keep)
        k += 1 if len(candidate.variants) > 1 else 0
        fitted_test, _ = row_errors(dataset, fit.params, test)
        rss1 = fit.rms_m**2 * len(base_train)  # the fit's rows carry the same failure penalty
        mse1 = float(np.mean(fitted_test**2))
        score = n_test * math.log(mse1 / mse0) + k * math.log(n_train)
        if rss1 < rss0 and n_train > k:
            f_stat = ((rss0 - rss1) / k) / (rss1 / (n_train - k))
            p_value = float(stats.f.sf(f_stat, k, n_train - k))
        else:
            f_stat, p_value = 0.0, 1.0
        gain = 1.0 - math.sqrt(mse1 / mse0)
        beats = score < 0 and p_value < alpha and determined and gain >= MIN_HELDOUT_GAIN
        if score < 0 and p_value < alpha and determined and not beats:
            note = (note + "; " if note else "") + f"held-out RMS only {gain:.0%} lower"
        scores.append(CandidateScore(candidate.effect, fit, k, fit.rms_m, _rms3(fitted_test), score,
                                     float(f_stat), p_value, bool(beats), note))
    scores.sort(key=lambda s: s.score)
    winner = next((s for s in scores if s.beats_noise), None)
    return Round(_rms3(base_train), _rms3(base_test), tuple(scores), winner)
