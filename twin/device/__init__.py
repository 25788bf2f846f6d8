"""The emulated rig, above the twin: the real firmware built for the host driving the MuJoCo plant
(:class:`twin.device.board.EmulatedBoard`), served as ``sim://`` in simulated time, on a
pseudo-terminal (:class:`twin.device.pty_board.PtyBoard`, ``twin emulate``), and the twin's
OpenIGTLink server. The rig driver that talks to any of them, or to the rig, is :mod:`twin.driver`.
"""

from twin.device.sim_twin import SimTwin
from twin.driver.fixture import SimFixture

__all__ = ["SimFixture", "SimTwin"]
