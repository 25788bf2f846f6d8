"""Contact detection: a load appearing at the tip, flagged from the live force estimate.

Each estimate is compared with a baseline, the slowly followed estimate of the unloaded tip (an
exponential average): the predictor's model-form error moves with the pose, and following it
keeps a moving robot's slow drift from looking like a contact, while a contact is a step. The
squared Mahalanobis distance of the difference in the observable directions,

    d²_k = (f_k − b_k)ᵀ (Σ_k + Σ_b)⁺ (f_k − b_k),

is χ² with as many degrees of freedom as observable directions when nothing touches the tip; a
one-sided CUSUM g_k = max(0, g_{k−1} + d²_k − ν) (ν its 99.9 % quantile) raises the flag when g
exceeds ``threshold``. A 20 mN contact seen to 2 mN gives d² ≈ 100 and is flagged at the first
estimate; the CUSUM's memory catches a weaker one over a few.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.stats import chi2

from twin.force.estimator import WrenchEstimate

__all__ = ["ContactDetector", "ContactState"]


@dataclasses.dataclass(frozen=True)
class ContactState:
    """One step of the detector.

    Attributes:
        contact: whether a contact is flagged (latched until :meth:`ContactDetector.reset`).
        statistic: d² of this estimate against the baseline (dimensionless).
        cusum: the CUSUM g (dimensionless).
        baseline_n: (3,) the baseline force in the observable directions (N).
    """

    contact: bool
    statistic: float
    cusum: float
    baseline_n: np.ndarray


class ContactDetector:
    """CUSUM on the live force estimate's distance from its slowly followed unloaded baseline.

    Args:
        threshold: the CUSUM level that flags a contact; default 60, a starting value: on the
            default robot moving on the twin it gave 3 false alarms in a clean 10-minute run and
            none in a clean minute (``twin bench contact`` measures it).
        baseline_time_s: time constant of the baseline's exponential average (s); default 2 s,
            slower than a contact (a step) and faster than the model error's drift with the pose
            at the robot's speeds.
        rate_hz: estimates per second (the telemetry rate; 40 Hz on the thesis's rig).
        quantile: ν is this χ² quantile (default 0.999: an estimate of the unloaded tip rarely adds).
    """

    def __init__(self, *, threshold: float = 60.0, baseline_time_s: float = 2.0, rate_hz: float = 40.0,
                 quantile: float = 0.999):
        if not threshold > 0:
            raise ValueError(f"threshold = {threshold}: must be > 0")
        if not baseline_time_s > 0 or not rate_hz > 0:
            raise ValueError(f"baseline_time_s = {baseline_time_s}, rate_hz = {rate_hz}: must be > 0")
        if not 0 < quantile < 1:
            raise ValueError(f"quantile = {quantile}: must be in (0, 1)")
        self.threshold = float(threshold)
        self.alpha = 1.0 - np.exp(-1.0 / (baseline_time_s * rate_hz))
        self.quantile = float(quantile)
        self.reset()

    def reset(self) -> None:
        """Forget the baseline and the flag: the next estimate is the new unloaded tip."""
        self.baseline: np.ndarray | None = None
        self.baseline_cov: np.ndarray | None = None
        self.cusum = 0.0
        self.contact = False

    def update(self, estimate: WrenchEstimate) -> ContactState:
        """Feed one estimate (a failed one leaves the state as it is)."""
        force = estimate.force_observable_n
        cov = estimate.force_observable_cov_n2
        if not estimate.converged or not np.isfinite(force).all():
            return ContactState(self.contact, float("nan"), self.cusum, self._baseline_out())
        if self.baseline is None:
            self.baseline, self.baseline_cov = force.copy(), cov.copy()
            return ContactState(False, 0.0, 0.0, self.baseline.copy())
        diff = force - self.baseline
        total = cov + self.baseline_cov
        dims = max(1, int(np.linalg.matrix_rank(total, tol=1e-12 * max(np.trace(total), 1e-30), hermitian=True)))
        d2 = float(diff @ np.linalg.pinv(total, rcond=1e-10, hermitian=True) @ diff)
        self.cusum = max(0.0, self.cusum + d2 - chi2.ppf(self.quantile, dims))
        if self.cusum > self.threshold:
            self.contact = True
        if not self.contact and self.cusum == 0.0:
            # Only an estimate that adds nothing to the CUSUM moves the baseline: a contact's
            # first estimates must not be averaged into it.
            a = self.alpha
            self.baseline = (1 - a) * self.baseline + a * force
            self.baseline_cov = (1 - a) * self.baseline_cov + a * cov
        return ContactState(self.contact, d2, self.cusum, self._baseline_out())

    def _baseline_out(self):
        return np.full(3, np.nan) if self.baseline is None else self.baseline.copy()
