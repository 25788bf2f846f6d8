"""The live shadow: a calibrated twin in lockstep beside a device, which sees the two diverge and
names why (:class:`ShadowDevice`, :class:`Monitor`)."""

from twin.shadow.device import ShadowDevice
from twin.shadow.monitor import KINDS, Divergence, FrameValues, Monitor

__all__ = ["KINDS", "Divergence", "FrameValues", "Monitor", "ShadowDevice"]
