"""Gymnasium environments of the endoscope, registered in one place.

Import this package before :func:`gymnasium.make`::

    import gymnasium as gym
    import twin.envs  # registers the ids below

    env = gym.make("twin/EndoscopeReach-v0")                        # twin, tension actions
    env = gym.make("twin/EndoscopeReach-v0", action_mode="pairs")   # coupled length pairs
    env = gym.make("twin/EndoscopeReach-v0", device_url="serial:///dev/ttyACM0?igtl=127.0.0.1:18944")
    env = gym.make("twin.envs:twin/EndoscopeReach-v0")              # Gymnasium imports the module itself

The folder ``envs/`` of the checkout installs as ``twin.envs`` (a package-dir mapping in
``pyproject.toml``), so nothing named ``envs`` lands in site-packages.

Ids (``max_episode_steps`` 200 = 5 s at 40 Hz):

``twin/EndoscopeReach-v0``
    :class:`twin.envs.reach.EndoscopeReachEnv` with its defaults: nominal parameters, tip loads.
``twin/EndoscopeReachRandomized-v0``
    The same with :meth:`twin.envs.randomization.Randomization.typical` spreads each episode.
"""

from gymnasium.envs.registration import register

from twin.envs.randomization import Randomization, TipLoads
from twin.envs.reach import ACTION_MODES, EndoscopeReachEnv

__all__ = ["ACTION_MODES", "EndoscopeReachEnv", "Randomization", "TipLoads"]

register(id="twin/EndoscopeReach-v0", entry_point="twin.envs.reach:EndoscopeReachEnv", max_episode_steps=200)
register(id="twin/EndoscopeReachRandomized-v0", entry_point="twin.envs.reach:EndoscopeReachEnv", max_episode_steps=200,
         kwargs={"randomization": Randomization.typical()})
