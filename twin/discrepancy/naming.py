"""Name: fit every candidate effect on a training split, rank them on held-out rows, name a winner.

The rule (documented here because the ranking and the verdict follow from it):

* **Split.** Configurations (κ, φ, tip mass; repeats stay together) are shuffled with a given
  seed and a fraction is held out; candidates are fitted on the rest only.
* **Joint.** A candidate is fitted together with the effects already named (their parameters
  refitted with its own, from their fitted values): an effect named first has absorbed some of
  what a later one explains, and a candidate fitted against that leftover bias would be named
  for it.
* **Every fit is bounded and determined.** Each parameter stays within its physical bounds
  (:attr:`twin.effects.FitParameter.bounds`), and one the data leave undetermined — a standard
  error above half its value (log-fitted) or above its typical size ``scale`` (others), or a
  value on a bound — is dropped and the rest refitted (:func:`twin.data.fitting.fit_determined`),
  so it keeps its prior value and is not written into the parameter set as if measured. A
  candidate none of whose own parameters is determined is no answer (score +inf).
* **Score** of a candidate with k fitted parameters of its own, lower is better::

      S = N_h · ln(MSE_h / MSE_h,0) + k · ln(N_t)

  MSE_h is the mean squared per-axis error on the N_h held-out residuals (3 per row; a failed
  prediction counts as the fitting penalty), MSE_h,0 that of the current model, N_t the number
  of training residuals. The first term is the held-out log-likelihood gain under Gaussian
  noise; the second the Bayesian information criterion's price per parameter, so a 4-parameter
  candidate must earn more than a 1-parameter one. The current model scores 0.
* **The winner is the best score**, and only if it **beats noise**: S < 0 *and* the training
  fit passes an F-test against the current model, F = ((RSS₀ − RSS₁)/k) / (RSS₁/(N_t − k)) with
  p < :data:`NAME_ALPHA` divided by the number of candidates (Bonferroni: eight tries at chance
  must not name one) *and* the held-out RMS falls by at least :data:`MIN_HELDOUT_GAIN` (a
  tenth): the predictor and the twin themselves agree only to a few hundredths of a millimetre
  (``reports/crosscheck``), and with averaged tracker frames the statistics alone resolve such
  model-form differences — naming an effect for them would be a false alarm on data with no
  effect. If the best does not beat noise, nothing is named.
* **Ties.** Another candidate that beats noise *ties* with the winner when its held-out squared
  error exceeds the winner's by less than :data:`TIE_Z` standard errors of that difference
  (:func:`worse_z`): the held-out data cannot tell the two apart, and the workflow answers
  ``ambiguous`` instead of picking one (:mod:`twin.discrepancy.workflow`).
* **Pairs.** When no single candidate beats noise, the best :data:`PAIR_POOL` are fitted in
  pairs (:func:`rank_pairs`), scored the same way with both effects' parameters counted.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import Sequence

import numpy as np
from scipy import stats
from tqdm import tqdm

from twin.discrepancy.candidates import Candidate
from twin.discrepancy.noise import configuration_keys
from twin.data.dataset import Dataset
from twin.data.prediction import predict_rows
from twin.data.fitting import FitParameter, ParameterFit, current_value, fit_determined
from twin.params import Params

__all__ = ["NAME_ALPHA", "MIN_HELDOUT_GAIN", "TIE_Z", "PAIR_POOL", "Baseline", "CandidateScore", "Round",
           "split_rows", "row_errors", "rank_candidates", "rank_pairs", "worse_z"]

NAME_ALPHA = 1e-3
# Smallest relative drop of the held-out RMS that names an effect (see the module rule).
MIN_HELDOUT_GAIN = 0.10
# Standard errors by which a candidate's held-out squared error must exceed the winner's for the
# held-out data to tell them apart (about 98 % one-sided); below it the two tie.
TIE_Z = 2.0
# How many of the best single candidates are tried in pairs when none beats noise alone.
PAIR_POOL = 3
# Optimiser tolerance of the candidates' fits (twin.data.fitting.fit_parameters): a millionth of a
# parameter's scale, or of the cost, is far below what the noise resolves.
FIT_TOLERANCE = 1e-6
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


def row_errors(dataset: Dataset, params: Params, rows: np.ndarray,
               guesses: list | None = None) -> tuple[np.ndarray, np.ndarray]:
    """p̂ − p* on the ``rows`` mask: (errors_m (n, 3), failures charged :data:`FAILED_ROW_PENALTY_M`; converged (n,)).

    ``guesses`` (one per selected row) warm-starts each row as :func:`twin.data.prediction.predict_rows` does.
    """
    data = dataset.subset(rows)
    tip, ok, _, _ = predict_rows(params, data.base_rotation, data.tensions_n, data["tip_mass_kg"], data.lengths_m,
                                 guesses=guesses, sliding_state=data.sliding_state)
    err = tip - data.tip_positions_m
    err[~ok] = FAILED_ROW_PENALTY_M
    return err, ok


def _rms3(errors_m: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(errors_m**2, axis=1))))


@dataclasses.dataclass(frozen=True)
class CandidateScore:
    """One candidate's outcome in a round.

    Attributes:
        effect: the effect's name (for a pair, both names joined by ``+``).
        fit: its fit on the training rows, jointly with the effects already named (None when it
            does not apply to the dataset or nothing of it is determined).
        parameters: number k of its own fitted parameters (a discrete choice counts one).
        train_rms_m, heldout_rms_m: RMS of |p̂ − p*| (m) on the training and held-out rows.
        score: S of the module rule (0 = no better than the current model; +inf when not
            applicable or not determined).
        f_statistic, p_value: training F-test against the current model.
        beats_noise: S < 0, p < :data:`NAME_ALPHA` / candidates, some parameter determined, and the
            held-out RMS at least :data:`MIN_HELDOUT_GAIN` lower.
        note: why it was not fitted, or what was dropped, if anything.
        heldout_errors_m: (held-out rows, 3) p̂ − p* with the candidate added (m).
        worse_z: standard errors by which its held-out squared error exceeds the round's best
            (0 for the best itself; NaN when not compared).
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
    heldout_errors_m: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)
    worse_z: float = math.nan

    @property
    def effects(self) -> tuple[str, ...]:
        """The effect names (two for a pair)."""
        return tuple(self.effect.split("+"))

    def to_dict(self) -> dict:
        out = {"effect": self.effect, "score": self.score, "parameters": self.parameters,
               "train_rms_m": self.train_rms_m, "heldout_rms_m": self.heldout_rms_m,
               "f_statistic": self.f_statistic, "p_value": self.p_value, "beats_noise": self.beats_noise}
        if math.isfinite(self.worse_z):
            out["worse_z"] = self.worse_z
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
        winner: the best candidate when it beats noise, or None.
        ties: the other candidates that beat noise and that the held-out data cannot tell from
            the winner (module rule), best first; empty when the winner stands alone.
    """

    baseline_train_rms_m: float
    baseline_heldout_rms_m: float
    scores: tuple[CandidateScore, ...]
    winner: CandidateScore | None
    ties: tuple[CandidateScore, ...] = ()

    @property
    def tied(self) -> tuple[CandidateScore, ...]:
        """The winner and its ties, when there are ties; else empty."""
        return (self.winner,) + self.ties if self.winner is not None and self.ties else ()

    def to_dict(self) -> dict:
        return {"baseline_train_rms_m": self.baseline_train_rms_m,
                "baseline_heldout_rms_m": self.baseline_heldout_rms_m,
                "winner": self.winner.effect if self.winner else "none",
                "ties": [s.effect for s in self.ties],
                "ranking": [s.to_dict() for s in self.scores]}


@dataclasses.dataclass
class Baseline:
    """The current model on both splits, and what every candidate of a round shares."""

    dataset: Dataset
    params: Params
    train: np.ndarray
    test: np.ndarray
    source: str
    max_evaluations: int
    alpha: float
    base_train: np.ndarray
    base_test: np.ndarray
    train_guesses: list
    test_guesses: list

    @classmethod
    def of(cls, dataset, params, train, test, *, source, max_evaluations, tries, guesses=None) -> "Baseline":
        guesses = guesses if guesses is not None else [None] * len(dataset)
        train_guesses = [guesses[i] for i in np.flatnonzero(train)]
        test_guesses = [guesses[i] for i in np.flatnonzero(test)]
        base_train, _ = row_errors(dataset, params, train, train_guesses)
        base_test, _ = row_errors(dataset, params, test, test_guesses)
        return cls(dataset, params, train, test, source, max_evaluations, NAME_ALPHA / max(1, tries), base_train,
                   base_test, train_guesses, test_guesses)

    def score(self, effect: str, named: Sequence[FitParameter], own: Sequence[FitParameter], x0: Sequence[float],
              variants: Sequence[dict]) -> CandidateScore:
        """Fit ``own`` jointly with ``named`` (each variant; the best training fit kept) and score it."""
        parameters = list(named) + list(own)
        start = [current_value(self.params, p) for p in named] + list(x0)
        source = f"{self.source}: {effect}"
        fit, dropped = None, []
        for fixed in variants or ({},):
            trial_params = self.params.replace(fixed, source=source) if fixed else self.params
            options = dict(source=source, rows=self.train, guesses=self.train_guesses, tolerance=FIT_TOLERANCE)
            trial, lost = fit_determined(self.dataset, trial_params, parameters, x0=start,
                                         max_evaluations=self.max_evaluations, **options)
            if trial is not None and (fit is None or trial.rms_m < fit.rms_m):
                fit, dropped = trial, lost
        kept = [p for p in (fit.parameters if fit is not None else ()) if p in own]
        note = "; ".join(f"not determined, kept: {p.label} ({v:.3g} ± {e:.2g})" for p, v, e in dropped)
        if fit is None or not kept:
            return CandidateScore(effect, fit, 0, _rms3(self.base_train), _rms3(self.base_test), math.inf, 0.0, 1.0,
                                  False, note or "not determined by the data")
        k = len(kept) + (1 if len(variants) > 1 else 0)
        fitted_test, _ = row_errors(self.dataset, fit.params, self.test, list(self.test_guesses))
        rss1 = fit.rms_m**2 * len(self.base_train)  # the fit's rows carry the same failure penalty
        return self.judge(effect, fit, k, rss1, fit.rms_m, fitted_test, note)

    def judge(self, effect: str, fit, k: int, rss1: float, train_rms_m: float, fitted_test: np.ndarray,
              note: str = "") -> CandidateScore:
        """Score a fitted explanation with ``k`` parameters of its own (module rule) from its
        training residual sum of squares ``rss1`` (m²) and its held-out errors (rows, 3) m."""
        rss0, mse0 = float(np.sum(self.base_train**2)), float(np.mean(self.base_test**2))
        n_train, n_test = self.base_train.size, self.base_test.size
        mse1 = float(np.mean(fitted_test**2))
        score = n_test * math.log(mse1 / mse0) + k * math.log(n_train)
        f_stat, p_value = _f_test(rss0, rss1, k, n_train)
        gain = 1.0 - math.sqrt(mse1 / mse0)
        beats = score < 0 and p_value < self.alpha and gain >= MIN_HELDOUT_GAIN
        if score < 0 and p_value < self.alpha and not beats:
            note = (note + "; " if note else "") + f"held-out RMS only {gain:.0%} lower"
        return CandidateScore(effect, fit, k, train_rms_m, _rms3(fitted_test), score, float(f_stat), p_value,
                              bool(beats), note, fitted_test)

    def round(self, scores: list[CandidateScore]) -> Round:
        """Rank ``scores``: the best wins if it beats noise; the others that beat noise and are
        not worse on the held-out rows by :data:`TIE_Z` standard errors tie with it."""
        scores = sorted(scores, key=lambda s: s.score)
        best = scores[0] if scores and scores[0].beats_noise else None
        ties = []
        if best is not None:
            scores[0] = dataclasses.replace(best, worse_z=0.0)
            best = scores[0]
            for i, s in enumerate(scores[1:], start=1):
                if s.heldout_errors_m is None or best.heldout_errors_m is None:
                    continue
                scores[i] = s = dataclasses.replace(s, worse_z=worse_z(best.heldout_errors_m, s.heldout_errors_m))
                if s.beats_noise and s.worse_z < TIE_Z:
                    ties.append(s)
        return Round(_rms3(self.base_train), _rms3(self.base_test), tuple(scores), best, tuple(ties))


def _f_test(rss0: float, rss1: float, k: int, n: int) -> tuple[float, float]:
    """(F, p) of k more parameters taking the residual sum of squares from rss0 to rss1 on n residuals."""
    if rss1 < rss0 and n > k > 0:
        f_stat = ((rss0 - rss1) / k) / (rss1 / (n - k))
        return float(f_stat), float(stats.f.sf(f_stat, k, n - k))
    return 0.0, 1.0


def worse_z(best_m: np.ndarray, other_m: np.ndarray) -> float:
    """How many standard errors Σ|e_other|² exceeds Σ|e_best|² over the held-out rows.

    With δ = e_other − e_best (the two models' predictions differ by it, not by noise), the
    per-row difference is 2 e_best·δ + |δ|²; if the two explained the rows equally well its sum
    would be 0 with variance 4 Σ δᵀ S δ, S the per-axis mean square of e_best (noise and whatever
    the best leaves). So two models whose predictions differ by less than the residual's scale
    on the held-out rows cannot be told apart however their RMS compares.
    """
    delta = other_m - best_m
    excess = float(np.sum(other_m**2) - np.sum(best_m**2))
    spread = np.mean(best_m**2, axis=0)
    se = 2.0 * math.sqrt(float(np.sum(delta**2 * spread)))
    if se == 0:
        return math.inf if excess > 0 else 0.0
    return excess / se


def _applicable(candidate: Candidate, dataset: Dataset, train: np.ndarray) -> bool:
    return bool(candidate.applies(dataset.subset(train)))


def rank_candidates(dataset: Dataset, params: Params, candidates: Sequence[Candidate], train: np.ndarray,
                    test: np.ndarray, *, source: str, named: Sequence[FitParameter] = (), max_evaluations: int = 25,
                    progress: bool = False, label: str = "candidates", guesses: list | None = None) -> Round:
    """Fit each candidate on ``train`` jointly with ``named``, score it on ``test`` (module rule)
    and pick the winner.

    Args:
        dataset: the measurements.
        params: the current model (with the named effects' fitted values).
        candidates: what to try.
        train, test: row masks.
        source: provenance written for fitted keys (the effect's name is appended).
        named: the parameters of the effects already named, refitted with each candidate.
        max_evaluations: optimiser iterations per fit (see :func:`twin.data.fitting.fit_parameters`).
        progress: show a progress bar on stderr.
        label: the progress bar's title.
        guesses: per row of ``dataset``, a solution to start its solves from (e.g. of a nearby
            model; not changed).
    """
    base = Baseline.of(dataset, params, train, test, source=source, max_evaluations=max_evaluations,
                        tries=len(candidates), guesses=guesses)
    scores = []
    bar = tqdm(candidates, desc=label, unit="effect", disable=not progress, leave=False)
    for candidate in bar:
        bar.set_postfix_str(candidate.effect)
        if not _applicable(candidate, dataset, train):
            scores.append(CandidateScore(candidate.effect, None, len(candidate.parameters), _rms3(base.base_train),
                                         _rms3(base.base_test), math.inf, 0.0, 1.0, False,
                                         note="the data cannot show it"))
            continue
        scores.append(base.score(candidate.effect, named, candidate.parameters, candidate.x0(params),
                                 candidate.variants))
    return base.round(scores)


def rank_pairs(dataset: Dataset, params: Params, candidates: Sequence[Candidate], train: np.ndarray,
               test: np.ndarray, *, source: str, tries: int, max_evaluations: int = 25,
               progress: bool = False, guesses: list | None = None) -> Round:
    """Fit every pair of ``candidates`` jointly on ``train`` and score it on ``test`` as one candidate
    with both effects' parameters (module rule).

    Args:
        tries: how many candidates and pairs are tried in all (the Bonferroni divisor).
        (others as for :func:`rank_candidates`)
    """
    base = Baseline.of(dataset, params, train, test, source=source, max_evaluations=max_evaluations, tries=tries,
                        guesses=guesses)
    usable = [c for c in candidates if _applicable(c, dataset, train)]
    pairs = list(itertools.combinations(usable, 2))
    scores = []
    for a, b in tqdm(pairs, desc="pairs", unit="pair", disable=not progress, leave=False):
        unvaried: tuple[dict, ...] = ({},)
        variants = [{**va, **vb} for va in (a.variants or unvaried) for vb in (b.variants or unvaried)]
        score = base.score(f"{a.effect}+{b.effect}", (), a.parameters + b.parameters, a.x0(params) + b.x0(params),
                           variants if len(variants) > 1 else ())
        scores.append(score)
    return base.round(scores)
