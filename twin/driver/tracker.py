"""The EM tracker as a device sees it: fused 6-DOF tip poses from two 5-DOF probes.

On ``sim://`` the probes are the twin's (``Plant.tracker_probes``, 40 Hz,
timestamped in simulated time); on ``serial://`` they come from the rig's OpenIGTLink server
(:class:`twin.driver.igtl_source.OpenIGTLinkSource`) when the URL names one (``?igtl=host:port``,
with the ``igtl_…`` and ``cap_…`` keys of :mod:`twin.driver.url`).
Either way :meth:`TipTracker.read` fuses the newest frame with :func:`twin.tracking.fuse_frame`.
"""

from __future__ import annotations

from typing import Callable, Protocol

from twin.tracking import CapCalibration, FusionResult, FusionSettings, ProbeFrame, fuse_frame

__all__ = ["TipTracker"]


class ProbeSource(Protocol):
    def read(self) -> ProbeFrame: ...


class TipTracker:
    """Fused tip poses from a probe source, opened on first use.

    Args:
        open_source: makes the source (it may start a client thread, hence lazily).
        calibration: where the probes sit in the tip cap.
        settings: fusion noise levels and rejection thresholds.
    """

    def __init__(
        self,
        open_source: Callable[[], ProbeSource],
        *,
        calibration: CapCalibration = CapCalibration(),
        settings: FusionSettings = FusionSettings(),
    ):
        self._open_source = open_source
        self._source: ProbeSource | None = None
        self.calibration = calibration
        self.settings = settings

    def read_frame(self) -> ProbeFrame:
        """The newest raw probe frame (world frame, source clock)."""
        if self._source is None:
            self._source = self._open_source()
        return self._source.read()

    def read(self) -> FusionResult:
        """The newest frame, fused; ``result.pose`` is None (and ``result.reason`` says why)
        when the frame is rejected, e.g. a probe out of the field or a stale sample."""
        return fuse_frame(self.read_frame(), self.calibration, self.settings)

    def close(self) -> None:
        """Stop the source's client, if it has one; the next read opens it again."""
        source, self._source = self._source, None
        close = getattr(source, "close", None)
        if close is not None:
            close()
