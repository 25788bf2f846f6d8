"""The discrepancy workflow: find → name → add → show, on one dataset, with an honest verdict.

The steps (the ranking rule is in :mod:`twin.discrepancy.naming`):

* **Find first.** Nothing is named unless the Find step declared structured disagreement beyond
  noise (:mod:`twin.discrepancy.residuals`), so the two never contradict.
* **Greedy, jointly.** The round's winner goes into the model, and the remaining candidates are
  ranked again, each refitted jointly with everything named, until nothing beats noise (or
  ``max_effects`` are named). When no single candidate beats noise in the first round, the best
  few are tried in pairs.
* **Check what remains.** The fitted model goes through the Find step again (with the starting
  model's noise estimate): a named effect must leave residuals without structure beyond noise.

The verdict (:class:`Verdict`):

``none``
    no structured disagreement beyond noise, or none that matters (:func:`_material`) and
    nothing named, and the held-out error is within noise and model form (below): nothing to name.
``effect``
    the named effects leave residuals consistent with noise (no material structure), and a
    held-out error within noise and model form.
``ambiguous``
    two or more candidates explain the data equally well within their uncertainty (a tie,
    :data:`twin.discrepancy.naming.TIE_Z`), and the best of them leaves no structure beyond
    noise and a held-out error within noise and model form; they are listed, none is named for
    that round, and the search stops there.
``unexplained``
    structure beyond noise remains that no candidate (nor a pair) removes, or an error beyond
    noise and model form that is no function of the configuration (path dependence: hysteresis,
    friction without its sliding state; or drift): what was named, if anything, explains part
    of it (tied candidates that each explain part are listed, the stand-ins with their figures,
    never named); the verdict shows where the rest is and how large.

The Find step's structure test sees only disagreement that is a smooth function of (κ, φ, load);
an answer of ``none``, ``effect`` or ``ambiguous`` also needs the held-out error it leaves to be
within what the noise and the model-form level allow (:func:`twin.discrepancy.residuals.level_test`,
at the Find step's false-alarm rate), so a large disagreement of another shape is never ``none``
and an effect that explains part of it is never the ``effect``. That needs a noise measured in
the data (repeats, or the frames each row averages); against a stated noise the answer stands on
the structure test and its statement says that the error is beyond the stated noise.

Example:
    >>> from twin.data.dataset import read_dataset
    >>> result = run_discrepancy(read_dataset("runs/validate"))
    >>> print(result.verdict, result.named, result.rms_before_m, result.remaining_rms_m)
    >>> result.params_after.save("endoscope-fitted.toml")
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from tqdm import tqdm

from twin.discrepancy.candidates import UNTESTABLE_EFFECTS, candidate_library

from twin.discrepancy.naming import (MIN_HELDOUT_GAIN, PAIR_POOL, TIE_Z, Baseline, CandidateScore, Round,
                                     rank_candidates, rank_pairs, row_errors, split_rows, worse_z)
from twin.discrepancy.probes import PROBES, fit_probe
from twin.discrepancy.residuals import LevelTest, ResidualMap, find_discrepancy, level_test, thesis_signature
from twin.discrepancy.uncertainty import Uncertainty, honest_uncertainty, model_form_reference
from twin.discrepancy.verdict import Verdict
from twin.data.dataset import Dataset
from twin.data.fitting import ParameterFit
from twin.params import Params

__all__ = ["DiscrepancyResult", "Verdict", "run_discrepancy"]

# Configurations listed where a residual remains.
_WORST_SHOWN = 5
# Structured RMS, in noise RMS, that a tenth off the held-out RMS stands for (see _material).
_MATERIAL = math.sqrt(1.0 / (1.0 - MIN_HELDOUT_GAIN) ** 2 - 1.0)
# Structured RMS (m) the predictor's own model form may leave on data of a perfect rig: the twin
# and the predictor differ by up to 0.169 mm over the thesis grid (reports/crosscheck/crosscheck.md),
# and the clean twin's sweeps, judged at their averaged frames' noise (~0.09 mm), leave 0.08-0.10 mm
# of structure. Structure below it is not an effect's.
MODEL_FORM_M = 0.17e-3


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
        rounds: the rounds (the last one named nothing, unless ``max_effects`` stopped it or it tied);
            a round of pairs is last when one was tried.
        named: the effects named, in order.
        fit: the joint fit of the named effects' parameters on the training rows (None if none named).
        errors_before_m, errors_after_m: (held-out rows, 3) p̂ − p* before and after (failures charged).
        converged_before, converged_after: (held-out rows,) which held-out predictions exist.
        verdict: the answer (:class:`Verdict`, module doc).
        tied: the candidates of a round that tied, best first (the verdict is then ``ambiguous``,
            or ``unexplained`` when even the best of them leaves structure).
        remaining: the Find step on all rows with the model that leaves the least (``params_after``;
            for ``unexplained``, the stand-ins'), with the starting noise estimate.
        stand_ins: what the greedy search fitted but the verdict does not name (an ``unexplained``
            or ``ambiguous`` answer): their joint fit and figures, never in :attr:`named`, never
            written into ``params_after``; :attr:`errors_after_m` are theirs for ``unexplained``.
        outside: the causes outside the library (:mod:`twin.discrepancy.probes`) that explain
            the data as well as the answer or better, best first, with their fits.
        uncertainty: for an ``effect`` answer, each fitted value's honest uncertainty
            (:mod:`twin.discrepancy.uncertainty`: standard error, split-to-split scatter and
            model-form error together), in the order of :attr:`fit`'s parameters.
        left: :attr:`errors_after_m` against the noise and the model-form level
            (:func:`twin.discrepancy.residuals.level_test`).
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
    verdict: Verdict = Verdict.NONE
    tied: tuple[CandidateScore, ...] = ()
    remaining: ResidualMap | None = None
    stand_ins: tuple[CandidateScore, ...] = ()
    outside: tuple[CandidateScore, ...] = ()
    uncertainty: tuple[Uncertainty, ...] = ()
    left: LevelTest | None = None

    @property
    def effect(self) -> str:
        """The first named effect, or ``none`` (:attr:`verdict` says whether that is the answer)."""
        return self.named[0] if self.named else "none"

    @property
    def rms_before_m(self) -> float:
        """Held-out RMS of |p̂ − p*| with the starting model (m)."""
        return float(np.sqrt(np.mean(np.sum(self.errors_before_m**2, axis=1))))

    @property
    def rms_after_m(self) -> float:
        """Held-out RMS of |p̂ − p*| with the named effects added (m)."""
        return float(np.sqrt(np.mean(np.sum(self.errors_after_m**2, axis=1))))

    @property
    def remaining_rms_m(self) -> float:
        """Held-out RMS of |p̂ − p*| the answer leaves (m): :attr:`rms_after_m`, to set against
        the noise's ``residuals.noise.rms_3d_m``."""
        return self.rms_after_m

    def heldout_table(self) -> list[dict]:
        """Per held-out configuration: its settings and |e| before and after (mm); a free pose's κ
        and φ are its arc's (:meth:`twin.data.dataset.Dataset.bends`)."""
        d = self.dataset.subset(self.test)
        kappa, phi = d.bends()
        before = np.linalg.norm(self.errors_before_m, axis=1) * 1e3
        after = np.linalg.norm(self.errors_after_m, axis=1) * 1e3
        return [{"config": int(d["config"][i]), "kappa_cmd_per_m": round(float(kappa[i]), 3),
                 "phi_cmd_deg": round(float(phi[i]), 2), "tip_mass_kg": float(d["tip_mass_kg"][i]),
                 "error_before_mm": float(before[i]), "error_after_mm": float(after[i])} for i in range(len(d))]

    def signatures(self) -> dict:
        """:func:`thesis_signature` of the held-out residuals before and after."""
        phi = self.dataset.bends()[1][self.test]
        return {"before": thesis_signature(self.errors_before_m, phi),
                "after": thesis_signature(self.errors_after_m, phi)}

    def parameters(self) -> dict:
        """Every named effect's fitted values (label → dict): the value, its statistical standard
        error, the split-to-split scatter, the model-form term, the uncertainty u of all three and
        the 95 % interval value ± 1.96 u (``ci95``; ``ci95_statistical`` the standard error's
        alone), :class:`twin.discrepancy.uncertainty.Uncertainty`."""
        if self.fit is None:
            return {}
        if self.uncertainty:
            return {u.parameter: u.to_dict() for u in self.uncertainty}
        return {row["parameter"]: {"value": row["value"], "std_error": row["std_error"],
                                   "ci95": [row["ci95_low"], row["ci95_high"]],
                                   "ci95_statistical": [row["ci95_low"], row["ci95_high"]]} for row in self.fit.table()}

    def candidates(self) -> list[dict]:
        """Every explanation the data leave open, with figures, none of them named: a tie's
        candidates (``role`` ``tied``), the stand-ins the search fitted for an answer that is not
        ``effect`` (``stand-in``) and the causes outside the library that explain the data as
        well or better (``outside the library``). Each with its held-out RMS (m), score, how many
        standard errors its held-out squared error is above the best's, its fitted values, and
        the experiments that tell it from the rest (:func:`twin.discrepancy.decide.experiments_for`)."""
        from twin.discrepancy.decide import experiments_for

        out = []
        for role, scores in (("tied", self.tied), ("stand-in", self.stand_ins), ("outside the library", self.outside)):
            for s in scores:
                out.append({"effect": s.effect, "role": role, "heldout_rms_m": s.heldout_rms_m, "score": s.score,
                            "worse_z": s.worse_z,
                            "parameters": {row["parameter"]: {"value": row["value"], "std_error": row["std_error"]}
                                           for row in (s.fit.table() if s.fit else [])},
                            "deciding_experiments": experiments_for(s.effects)})
        return out

    def separations(self) -> list[dict]:
        """For each explanation the data cannot tell from the best one (a tie, or a cause outside
        the library), the experiments that would: ``{"between": [best, other], "experiments":
        [...], "runnable": [...]}``, runnable being what ``--device`` can run. The best is the
        tie's first, else the stand-ins."""
        from twin.discrepancy.decide import DESIGNS, experiments_for
        from twin.discrepancy.probes import PROBES

        best = self.tied[0] if self.tied else (self.stand_ins[0] if self.stand_ins else None)
        if best is None:
            return []
        out = []
        for other in list(self.tied[1:]) + list(self.outside):
            # A probe's own experiments tell it from the library; two library effects, the union of theirs.
            names = experiments_for(other.effects if other.effect in PROBES else best.effects + other.effects)
            out.append({"between": [best.effect, other.effect], "experiments": names,
                        "runnable": [n for n in names if n in DESIGNS]})
        return out

    def where(self) -> dict:
        """Where the residual of ``params_after`` is (all rows): per axis, bending plane, curvature
        and tip load, the worst configurations, and the Find step's test of it."""
        r = self.remaining or self.residuals
        worst = sorted(r.by_configuration(), key=lambda row: -row["error_mm"])[:_WORST_SHOWN]
        return {"rms_m": r.rms_m(), "noise_rms_m": r.noise.rms_3d_m, "beyond_noise": r.structure.beyond_noise,
                "structured_rms_m": r.structure.structured_rms_m, "p_value": r.structure.p_value,
                "by_axis": r.by_axis(), "by_plane": r.by("phi_cmd_deg"), "by_curvature": r.by("kappa_cmd_per_m"),
                "by_load": r.by("tip_mass_kg"), "worst": worst}

    def statement(self) -> str:
        """The verdict in one or two sentences for a person."""
        noise = self.residuals.noise.rms_3d_m * 1e3
        left = (f"{self.remaining_rms_m * 1e3:.3g} mm held-out RMS left (from {self.rms_before_m * 1e3:.3g} mm) "
                f"against {noise:.3g} mm of noise")
        beyond_level = self.left is not None and not self.left.within
        if beyond_level:
            assert self.left is not None
            left += f" (noise and model form allow {self.left.allowed_rms_m * 1e3:.3g} mm)"
        # A stated noise (no repeats, no frame errors) cannot tell a noisier rig from a shapeless
        # disagreement: the answer stands on the structure test, and says what would tell.
        caveat = ("; beyond the stated noise, which these rows (no repeats, no frame standard errors) cannot tell "
                  "from path dependence or drift: repeat configurations to tell") if beyond_level else ""
        if self.verdict == Verdict.NONE:
            return f"none: no structured disagreement beyond noise ({left}){caveat}."
        if self.verdict == Verdict.EFFECT:
            return f"effect: {_listed(self.named)} the disagreement; {left}{caveat}."
        if self.verdict == Verdict.AMBIGUOUS:
            tie = ", ".join(f"{_shown(s)} {s.heldout_rms_m * 1e3:.3g} mm" for s in self.tied + self.outside)
            rms = [s.heldout_rms_m for s in self.tied + self.outside]
            spread = (max(rms) - min(rms)) * 1e3
            first = f" after {', '.join(s.effect for s in self.stand_ins)}" if self.stand_ins else ""
            return (f"ambiguous{first}: {tie} held-out explain the data equally within their uncertainty "
                    f"(spread {spread:.2g} mm; noise {noise:.3g} mm); none of them is added: {left}"
                    f"{self._separated()}.")
        w = self.where()
        axis = max(w["by_axis"], key=lambda a: a["rms_mm"])
        plane = max(w["by_plane"], key=lambda g: g["rms_mm"])
        kappa = max(w["by_curvature"], key=lambda g: g["rms_mm"])
        # An error beyond noise and model form without structure in the configuration: its shape
        # is the finding, not a candidate's failure to remove it.
        shapeless = beyond_level and not w["beyond_noise"]
        if self.tied:
            part = f"the best candidates tie ({', '.join(s.effect for s in self.tied)}) and none removes it; "
        elif self.stand_ins:
            part = f"{_listed([s.effect for s in self.stand_ins])} part of it (not named); "
        elif shapeless:
            part = ""
        else:
            part = "no candidate nor pair removes it; "
        if self.outside:
            best = self.outside[0]
            values = ", ".join(f"{row['parameter']} = {row['value']:.3g}" for row in (best.fit.table() if best.fit else []))
            part += (f"a cause outside the library, {best.effect} ({values}), explains it "
                     f"(held-out {best.heldout_rms_m * 1e3:.3g} mm); ")
        if shapeless:
            rest = "the rest is" if part else "a"
            shape = (f"{rest} disagreement beyond noise that is not a function of the configuration (over all rows "
                     f"a smooth function of κ, φ and load takes {w['structured_rms_m'] * 1e3:.3g} mm of "
                     f"{w['rms_m'] * 1e3:.3g} mm, p = {w['p_value']:.2g}): path dependence (hysteresis, friction "
                     f"without the sliding state) or drift")
            return (f"unexplained: {part}{shape}; {left}; largest along {axis['axis']} ({axis['rms_mm']:.3g} mm "
                    f"RMS), in the plane φ = {plane['phi_cmd_deg']:g}° ({plane['rms_mm']:.3g} mm), at κ = "
                    f"{kappa['kappa_cmd_per_m']:g} 1/m ({kappa['rms_mm']:.3g} mm); worst configurations "
                    f"{', '.join(str(c['config']) for c in w['worst'])}{self._separated()}.")
        return (f"unexplained: {part}{left}; over all rows {w['structured_rms_m'] * 1e3:.3g} mm of structure "
                f"remains (p = {w['p_value']:.2g}), largest along {axis['axis']} ({axis['rms_mm']:.3g} mm RMS), in the "
                f"plane φ = {plane['phi_cmd_deg']:g}° ({plane['rms_mm']:.3g} mm), at κ = {kappa['kappa_cmd_per_m']:g} "
                f"1/m ({kappa['rms_mm']:.3g} mm); worst configurations "
                f"{', '.join(str(c['config']) for c in w['worst'])}{self._separated()}.")

    def _separated(self) -> str:
        """``; <a> and <b> are told apart by <experiments>`` for each separation, or empty."""
        parts = []
        for sep in self.separations():
            if sep["experiments"]:
                parts.append(f"{sep['between'][0]} and {sep['between'][1]} are told apart by "
                             f"{' or '.join(sep['experiments'])}")
        return "; " + "; ".join(parts) if parts else ""

    def to_dict(self) -> dict:
        """The ``twin discrepancy --json`` object."""
        first = self.rounds[0]
        return {
            "dataset": str(self.dataset.path) if self.dataset.path else None,
            "verdict": self.verdict,
            "statement": self.statement(),
            "effect": self.effect,
            "effects": list(self.named),
            "candidates": self.candidates(),
            "separations": self.separations(),
            "parameters": self.parameters(),
            "rms_before_m": self.rms_before_m,
            "rms_after_m": self.rms_after_m,
            "remaining_rms_m": self.remaining_rms_m,
            "noise_rms_m": self.residuals.noise.rms_3d_m,
            "remaining": self.where(),
            "left": self.left.to_dict() if self.left else None,
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


def _material(found: ResidualMap, model_form_m: float = MODEL_FORM_M) -> bool:
    """Structure beyond noise that is large enough to matter: removing it would take a tenth off
    the RMS of noise and structure together (the held-out gain that names an effect,
    :data:`twin.discrepancy.naming.MIN_HELDOUT_GAIN`), i.e. a structured RMS of at least
    √(1/(1 − g)² − 1) ≈ 0.48 times the noise, and above what the model form alone leaves
    (``model_form_m``, :data:`MODEL_FORM_M`). Smaller structure that the F-test still resolves
    is the predictor's and the rig's model-form difference (``reports/crosscheck``), not an effect."""
    s = found.structure
    return s.beyond_noise and s.structured_rms_m >= max(_MATERIAL * found.noise.rms_3d_m, model_form_m)


def _shown(score: CandidateScore) -> str:
    """A candidate's name, marked when it is a cause outside the library."""
    from twin.discrepancy.probes import PROBES

    return f"{score.effect} (outside the library)" if score.effect in PROBES else score.effect


def _listed(named) -> str:
    """``a explains`` / ``a, b explain``."""
    return f"{', '.join(named)} {'explains' if len(named) == 1 else 'explain'}"


def run_discrepancy(dataset: Dataset, params: Params | None = None, *, holdout_fraction: float = 1 / 3,
                    seed: int = 0, max_effects: int = 3, max_evaluations: int = 25,
                    progress: bool = False, model_form_m: float = MODEL_FORM_M) -> DiscrepancyResult:
    """Find, name, add and show the effects missing from ``params`` for ``dataset``, and judge (module doc).

    Args:
        dataset: the measurements (e.g. a validation sweep).
        params: the model to start from (default the parameter set recorded with the data).
        holdout_fraction: share of configurations held out from every fit.
        seed: seed of the split.
        max_effects: stop after naming this many.
        max_evaluations: optimiser iterations per candidate fit.
        progress: progress bars on stderr.
        model_form_m: structured RMS (m) the model's form may leave on a perfect rig's data: less
            is not an effect (default :data:`MODEL_FORM_M`, the twin's; a rig's is larger).

    Raises:
        ValueError: ``max_effects`` < 1, no row can be predicted, or the dataset is too small to
            estimate its noise or to split.
    """
    if max_effects < 1:
        raise ValueError(f"max_effects = {max_effects!r}: must be >= 1")
    if not (math.isfinite(model_form_m) and model_form_m >= 0):
        raise ValueError(f"model_form_m = {model_form_m!r}: must be a finite length >= 0 (m)")
    params = params or dataset.params
    train, test = split_rows(dataset, holdout_fraction, seed)
    # Each row's solution with the starting model: every later solve of the row starts from it.
    solutions: list = [None] * len(dataset)
    residuals = find_discrepancy(dataset, params, progress=progress, guesses=solutions)
    name = dataset.path.name if dataset.path else "dataset"
    source = f"fitted: discrepancy {name} (training split, seed {seed})"
    library = candidate_library(params)
    current = params
    rounds: list[Round] = []
    named: list[str] = []
    fit: ParameterFit | None = None
    tied: tuple[CandidateScore, ...] = ()
    options: dict[str, Any] = dict(source=source, max_evaluations=max_evaluations, progress=progress, guesses=solutions)
    while len(named) < max_effects:
        remaining = [c for effect, c in library.items() if effect not in named]
        if not remaining:
            break
        ranked = rank_candidates(dataset, current, remaining, train, test, named=fit.parameters if fit else (),
                                 label=f"round {len(rounds) + 1}", **options)
        if not residuals.structure.beyond_noise:
            # Find and Name must agree: with no structure beyond noise in the residuals there is
            # nothing to name, even if a candidate's own F-test passes on the training rows.
            rounds.append(dataclasses.replace(ranked, winner=None, ties=()))
            break
        rounds.append(ranked)
        if ranked.winner is None and not named and max_effects >= 2:
            pool = [library[s.effect] for s in ranked.scores if np.isfinite(s.score)][:PAIR_POOL]
            if len(pool) >= 2:
                tries = len(remaining) + len(pool) * (len(pool) - 1) // 2
                ranked = rank_pairs(dataset, current, pool, train, test, tries=tries, **options)
                rounds.append(ranked)
        if ranked.ties:
            tied = ranked.tied
            break
        if ranked.winner is None:
            break
        named.extend(ranked.winner.effects)
        fit = ranked.winner.fit
        assert fit is not None, "a round's winner is a fitted candidate"
        current = fit.params
    held = np.flatnonzero(test)
    errors_before, ok_before = row_errors(dataset, params, test, [solutions[i] for i in held])
    errors_after, ok_after = row_errors(dataset, current, test, [solutions[i] for i in held])
    after = find_discrepancy(dataset, current, noise=residuals.noise, guesses=list(solutions)) if named else residuals
    # Only a noise measured in the data (repeats, frames) sets a level a shapeless error can be
    # judged against: a stated one may be off by the rig's own factor, which rows without repeats
    # cannot tell from a disagreement (the statement says so instead).
    measured = residuals.noise.source != "prior"
    if not residuals.structure.beyond_noise or (not named and not tied and not _material(residuals, model_form_m)):
        verdict = Verdict.NONE
    elif tied:
        # A tie is the answer only if the tied explanations explain: when even the best of them
        # leaves material structure, what is missing is none of them alone.
        assert tied[0].fit is not None, "a tied candidate is a fitted one"
        best = find_discrepancy(dataset, tied[0].fit.params, noise=residuals.noise, guesses=list(solutions))
        leaves = tied[0].heldout_errors_m
        beyond = measured and leaves is not None and not level_test(leaves, residuals.noise, model_form_m).within
        verdict = Verdict.UNEXPLAINED if beyond or _material(best, model_form_m) else Verdict.AMBIGUOUS
    elif not named or _material(after, model_form_m):
        verdict = Verdict.UNEXPLAINED
    else:
        verdict = Verdict.EFFECT
    if (measured and verdict in (Verdict.NONE, Verdict.EFFECT)
            and not level_test(errors_after, residuals.noise, model_form_m).within):
        # What the structure test cannot see (a disagreement that is no smooth function of the
        # configuration) is still a disagreement: nothing, or what was named, does not explain it.
        verdict = Verdict.UNEXPLAINED
    stand_ins: tuple[CandidateScore, ...] = ()
    outside: tuple[CandidateScore, ...] = ()
    if verdict != Verdict.NONE:
        base = Baseline.of(dataset, params, train, test, source=source, max_evaluations=max_evaluations,
                           tries=len(library) + len(PROBES), guesses=solutions)
        answer = _joint_score(base, rounds, named, fit, errors_after) if named and fit is not None else None
        reference = tied[0] if tied else answer
        probes = _probe_scores(base, dataset, params, solutions, max_evaluations, progress)
        # With more than one effect named, a single library candidate may explain as much.
        others = [s for s in rounds[0].scores if len(named) > 1 and s.beats_noise and not set(s.effects) & set(named)]
        better, equal = _equivalents(reference, probes + others)
        if verdict == Verdict.UNEXPLAINED and reference is None:
            outside = tuple(sorted((p for p in probes if p.beats_noise), key=lambda p: p.score))
        elif better:
            verdict, outside = Verdict.UNEXPLAINED, tuple(better + equal)
        elif equal:
            library_ties = tuple(e for e in equal if e.effect not in PROBES)
            if verdict == Verdict.EFFECT and answer is not None:
                verdict, tied = Verdict.AMBIGUOUS, (answer,) + library_ties
            outside = tuple(e for e in equal if e.effect in PROBES)
        if verdict != Verdict.EFFECT and named:
            # Only what the verdict names goes into the answer: the rest are stand-ins, with figures.
            if answer is not None and not (tied and tied[0] is answer):
                stand_ins = (answer,)
            named, fit, current = [], None, params
            if verdict == Verdict.AMBIGUOUS:
                errors_after, ok_after, after = errors_before, ok_before, residuals
    uncertainty: tuple[Uncertainty, ...] = ()
    if verdict == Verdict.EFFECT and fit is not None:
        left = after.structure.structured_rms_m if after.structure.beyond_noise else 0.0
        from twin.sim.plant import SimulationError

        try:
            form_reference = model_form_reference(dataset, params, rows=train)
        except SimulationError:  # a twin of these parameters that MuJoCo cannot settle: no shift known
            form_reference = None
        uncertainty = tuple(honest_uncertainty(dataset, fit, rows=train, model_form_m=model_form_m,
                                               structured_rms_m=left, max_evaluations=max_evaluations,
                                               reference_errors_m=form_reference, seed=seed, progress=progress))
    return DiscrepancyResult(dataset, params, current, train, test, seed, residuals, tuple(rounds), tuple(named),
                             fit, errors_before, errors_after, ok_before, ok_after, verdict, tied, after,
                             stand_ins, outside, uncertainty, level_test(errors_after, residuals.noise, model_form_m))


def _joint_score(base: Baseline, rounds: list[Round], named: list[str], fit: ParameterFit,
                 errors_after: np.ndarray) -> CandidateScore:
    """The named effects together as one candidate scored against the starting model (the
    first round's winner itself when one effect was named)."""
    first = rounds[0].winner
    if first is not None and list(first.effects) == list(named):
        return first
    rss = fit.rms_m**2 * len(base.base_train)
    return base.judge("+".join(named), fit, len(fit.parameters), rss, fit.rms_m, errors_after)


def _probe_scores(base: Baseline, dataset: Dataset, params: Params, solutions: list, max_evaluations: int,
                  progress: bool) -> list[CandidateScore]:
    """Each cause outside the library (:data:`twin.discrepancy.probes.PROBES`) fitted on the
    training rows and scored against the starting model as a candidate is."""
    out = []
    for probe in tqdm(PROBES.values(), desc="outside the library", unit="probe", disable=not progress, leave=False):
        fit = fit_probe(probe, dataset, params, base.train, base.test, guesses=solutions,
                        max_evaluations=max_evaluations)
        out.append(base.judge(probe.name, fit, len(probe.labels), fit.rss_m2, fit.rms_m, fit.heldout_errors_m,
                              "" if fit.converged else f"fit not converged: {fit.message}"))
    return out


def _equivalents(reference: CandidateScore | None,
                 alternatives: list[CandidateScore]) -> tuple[list[CandidateScore], list[CandidateScore]]:
    """(better, equal): the alternatives that beat noise and explain the held-out rows better
    than ``reference`` by :data:`twin.discrepancy.naming.TIE_Z` standard errors, and those the
    held-out rows cannot tell from it (each with ``worse_z`` against it), best first."""
    if reference is None or reference.heldout_errors_m is None:
        return [], []
    better, equal = [], []
    for alt in alternatives:
        if not alt.beats_noise or alt.heldout_errors_m is None:
            continue
        worse = worse_z(reference.heldout_errors_m, alt.heldout_errors_m)
        better_by = worse_z(alt.heldout_errors_m, reference.heldout_errors_m)
        alt = dataclasses.replace(alt, worse_z=worse)
        if better_by >= TIE_Z:
            better.append(alt)
        elif worse < TIE_Z:
            equal.append(alt)
    return sorted(better, key=lambda a: a.worse_z), sorted(equal, key=lambda a: a.worse_z)
