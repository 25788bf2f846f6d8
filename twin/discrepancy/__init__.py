"""The discrepancy workflow: find where model and measurement disagree, name the missing effect,
add it to the parameter set, and show the gap shrink on held-out data.

Example:
    >>> from twin.data.dataset import read_dataset
    >>> from twin.discrepancy import run_discrepancy, write_report
    >>> result = run_discrepancy(read_dataset("runs/validate"), progress=True)
    >>> result.verdict, result.named, result.parameters(), result.remaining_rms_m
    >>> write_report(result, "reports/discrepancy")

Modules: :mod:`~twin.discrepancy.residuals` (find), :mod:`~twin.discrepancy.noise`,
:mod:`~twin.discrepancy.candidates` (the library), :mod:`~twin.discrepancy.naming` (fit, rank,
name), :mod:`~twin.discrepancy.workflow` (greedy find–name–add and the verdict), :mod:`~twin.discrepancy.report`
(show), :mod:`~twin.discrepancy.synthetic` (datasets with a hidden effect), ``commands`` (CLI).
"""

from typing import TYPE_CHECKING

from twin.lazy import lazy_exports

if TYPE_CHECKING:
    from twin.discrepancy.candidates import Candidate, candidate_library
    from twin.discrepancy.naming import CandidateScore, Round, rank_candidates, rank_pairs, split_rows
    from twin.discrepancy.noise import NoiseEstimate, estimate_noise
    from twin.discrepancy.report import write_report
    from twin.discrepancy.residuals import ResidualMap, StructureTest, find_discrepancy, thesis_signature
    from twin.discrepancy.synthetic import synthetic_validation_dataset
    from twin.discrepancy.verdict import Verdict
    from twin.discrepancy.workflow import DiscrepancyResult, run_discrepancy

# name → the module that defines it, imported when the name is first used
_EXPORTS = {
    "Candidate": "twin.discrepancy.candidates", "candidate_library": "twin.discrepancy.candidates",
    "CandidateScore": "twin.discrepancy.naming", "Round": "twin.discrepancy.naming",
    "rank_candidates": "twin.discrepancy.naming", "rank_pairs": "twin.discrepancy.naming",
    "split_rows": "twin.discrepancy.naming",
    "NoiseEstimate": "twin.discrepancy.noise", "estimate_noise": "twin.discrepancy.noise",
    "write_report": "twin.discrepancy.report",
    "ResidualMap": "twin.discrepancy.residuals", "StructureTest": "twin.discrepancy.residuals",
    "find_discrepancy": "twin.discrepancy.residuals", "thesis_signature": "twin.discrepancy.residuals",
    "synthetic_validation_dataset": "twin.discrepancy.synthetic",
    "DiscrepancyResult": "twin.discrepancy.workflow", "Verdict": "twin.discrepancy.verdict",
    "run_discrepancy": "twin.discrepancy.workflow",
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = [
    "Candidate", "CandidateScore", "DiscrepancyResult", "NoiseEstimate", "ResidualMap", "Round",
    "StructureTest", "candidate_library", "estimate_noise", "find_discrepancy", "rank_candidates", "rank_pairs",
    "run_discrepancy", "split_rows",
    "synthetic_validation_dataset", "thesis_signature", "Verdict", "write_report",
]
