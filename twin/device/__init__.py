"""The emulated rig, above the twin: the real firmware built for the host driving the MuJoCo plant
(:class:`twin.device.board.EmulatedBoard`), served as ``sim://`` in simulated time
(:mod:`twin.device.sim_url`), on a pseudo-terminal or a TCP port in wall-clock time
(:class:`twin.device.pty_board.PtyBoard`, ``twin emulate``), with the twin's fixture, tracker and
OpenIGTLink server. The rig driver that talks to any of them, or to the rig, is :mod:`twin.driver`.
"""

from typing import TYPE_CHECKING

from twin.lazy import lazy_exports

if TYPE_CHECKING:
    from twin.device.sim_fixture import SimFixture
    from twin.device.sim_twin import SimTwin

# name → the module that defines it, imported when the name is first used (the twin loads MuJoCo)
_EXPORTS = {"SimFixture": "twin.device.sim_fixture", "SimTwin": "twin.device.sim_twin"}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["SimFixture", "SimTwin"]
