"""Reach and hold a tip target under tip loads: the endoscope on any device as a Gymnasium env."""

from __future__ import annotations

import collections
import math
import os
import sys
import urllib.parse
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from twin.envs.randomization import Randomization, TipLoads
from twin.control.pretension import pretension_straight
from twin.driver import CommandRejected, Device, Fixture, open_device
from twin.driver.codec import Fault
from twin.params import Params, load_params
from twin.pcc import arc_tip_position_m

if TYPE_CHECKING:
    from twin.live import LiveDevice, LiveView

__all__ = ["ACTION_MODES", "EndoscopeReachEnv", "default_curvature_range_per_m", "default_max_length_m",
           "default_tension_range_n"]

# Env action mode → the board's control mode.
ACTION_MODES = {"tensions": "tensions", "lengths": "lengths", "pairs": "pairs"}
_FAULTS = Fault.TENSION_LIMIT | Fault.WATCHDOG
# Simulated time the fixture gives each reset step to come to rest (s): the twin's backbone
# damps out in ~0.1 s; the rig's operator fixture ignores it (Fixture.settle_s).
_RESET_SETTLE_S = 0.2
# Observation bounds: the firmware refuses length setpoints beyond ±50 mm, its duty clamp bounds a
# tension runaway at ~30 N, and a 60 mm endoscope's tip stays within 0.1 m of the clamp.
_LENGTH_BOUND_M = 0.1
_TENSION_BOUND_N = 100.0
_POSITION_BOUND_M = 0.2
# The ranges of an env made for a robot, from the robot (the thesis endoscope's values in brackets,
# the ranges this env was tuned on): the largest target bend κL (1.2 rad: κ ≤ 20 1/m on 60 mm),
# the tension actions as fractions of the board's tension limit (0.3 … 5 N of 6 N), and a full
# length action as this multiple of the tendon's length change at the largest bend (8.1 mm for
# 5.4 mm), headroom for the load and the pretension's stretch.
TARGET_BEND_RAD = 1.2
TENSION_RANGE_OF_LIMIT = (0.05, 5.0 / 6.0)
LENGTH_ACTION_MARGIN = 1.5


def default_curvature_range_per_m(params: Params) -> tuple[float, float]:
    """Target curvatures (1/m) for ``params``'s robot: 0 … :data:`TARGET_BEND_RAD` over its length."""
    return 0.0, TARGET_BEND_RAD / params.backbone.length_m


def default_tension_range_n(params: Params) -> tuple[float, float]:
    """Tension actions' range (N) for ``params``'s robot: :data:`TENSION_RANGE_OF_LIMIT` of
    ``rig.tension_limit_n``."""
    limit = params.rig.tension_limit_n
    return TENSION_RANGE_OF_LIMIT[0] * limit, TENSION_RANGE_OF_LIMIT[1] * limit


def default_max_length_m(params: Params) -> float:
    """A full length action (m) for ``params``'s robot: :data:`LENGTH_ACTION_MARGIN` × the largest
    PCC length change of a tendon at the largest target bend (r κ s, s where it is anchored)."""
    return LENGTH_ACTION_MARGIN * params.tendons.radius_m * TARGET_BEND_RAD / params.backbone.length_m * \
        max(params.tendon_ends_m())


def _has_display() -> bool:
    """Whether a window can be opened: always on macOS and Windows, on Linux with X11 or Wayland."""
    return not sys.platform.startswith("linux") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class EndoscopeReachEnv(gym.Env):
    """Bring the endoscope tip to a target and hold it there while masses hang at the tip.

    The endoscope is clamped horizontally (thesis §8.3: base +90° about world y, gravity along
    world −z) and driven through :class:`twin.driver.Device` on ``device_url``: ``sim://``, the
    twin in simulated time (default), or ``serial://…?igtl=host:port``, the rig in real time.
    One step is one 40 Hz control period: the action goes to the board, then the env waits for
    the next telemetry sample (25 ms of device time) and reads the tracker.

    Each episode starts from the pretensioned straight endoscope
    (:func:`twin.control.pretension.pretension_straight`) with the board enabled in the action's
    control mode, a tip mass from ``tip_loads``, and a target on a constant-curvature arc
    (κ uniform in ``target_curvature_per_m``, bending plane uniform in 0…360°).

    **Actions** — ``Box(-1, 1, (n_a,), float32)``, mapped to setpoints:

    ============  =====  ==============================================================  ======
    action_mode   n_a    setpoint of tendon / pair i                                     unit
    ============  =====  ==============================================================  ======
    ``tensions``  n      τ_i = τ_lo + (a_i + 1)/2 · (τ_hi − τ_lo)  (``tension_range_n``)   N
    ``lengths``   n      Δℓ_i = a_i · ``max_length_m`` from the pretensioned zero        m
    ``pairs``     n/2    d₁₃, d₂₄ = a_i · ``max_length_m``; tendon 1 → +d₁₃, 3 → −d₁₃    m
    ============  =====  ==============================================================  ======

    Positive lengths pay tendon out. With ``randomization.latency_steps`` an action reaches the
    board that many steps late.

    n is the robot's tendon count (``tendons.angles_deg``; 4 on the thesis endoscope, the indices
    below). **Observations** — ``Box(float32)`` of size 2n + 10 + n_a:

    ========  ============================================================  ========
    index     quantity                                                      unit
    ========  ============================================================  ========
    0–3       tendon lengths from the pretensioned straight zero (encoders)  m
    4–7       tendon tensions (load cells)                                  N
    8–10      tip position from the tracker, world frame, base at origin     m
              (``env.tip_slice`` for any n)
    11–14     tip orientation from the tracker, quaternion (w, x, y, z)      —
    15–17     target tip position, world frame                              m
    18–       previous action (as given, before any latency)                —
    ========  ============================================================  ========

    Bounds: lengths ±0.1 m, tensions ±100 N, positions ±0.2 m (values are clipped to them).
    A tracker frame the fusion rejects leaves the last good pose in place.

    **Reward** — per step, with e the tip-to-target distance, τ the tensions and u the motor
    duties of the sample:

        r = −e / 10 mm − w_τ · Σ τ_i / (n τ_limit) − w_u · mean(u_i²) − (fault_penalty if a fault)

    **Termination** on a latched board fault: a tension over the limit (``rig.tension_limit_n``)
    or the watchdog. **Truncation** by the registered ``max_episode_steps`` (200 = 5 s).

    ``info``: ``tip_error_m``, ``tip_mass_kg``, ``tensions_n``, ``fault`` (flags), ``time_s``
    (device clock), ``latency_steps``; with ``tip_force=True`` also the live tip force estimate
    (:class:`twin.force.stream.ForceStream`, from the sample's tensions and the tracked pose):
    ``tip_force_n`` (3,) N, world frame, the load applied at the tip (its observable part: 0 along a
    direction the pose cannot see), ``tip_force_cov_n2`` (3, 3) N², ``tip_force_observable`` (3,)
    per world axis, and ``contact`` (the contact detector's flag).

    Args:
        device_url: ``sim://[?pose=…]`` (no seed: the env seeds it) or ``serial://…?igtl=…``.
        action_mode: ``"tensions"``, ``"lengths"`` or ``"pairs"``.
        params: parameter set (default ``models/endoscope/endoscope.toml``).
        randomization: per-episode parameter, effect and latency spreads (default none).
        tip_loads: tip masses per episode (default 0/5/10 g, half the episodes change once).
        gains: ``{mode: {"kp": …, "ki": …, "kd": …, "output_limit": …}}`` set on the board at
            reset (default the firmware's).
        target_curvature_per_m: (low, high) curvature of the target arcs (1/m); default from the
            robot (:func:`default_curvature_range_per_m`: 0 … 20 1/m on the 60 mm endoscope).
        tension_range_n: (τ_lo, τ_hi) of tension actions (N); default from the robot's tension
            limit (:func:`default_tension_range_n`: 0.3 … 5 N of 6 N).
        max_length_m: length of a full length action (m); default from the robot's tendon radius
            and length (:func:`default_max_length_m`: 8.1 mm).
        pretension_n: pretension per tendon at reset (N); default ``tendons.pretension_n``.
        tension_weight, effort_weight: w_τ and w_u of the reward.
        fault_penalty: reward subtracted on the faulting step.
        live_port: serve a live browser view of the endoscope, its prediction, the target and the
            tensions (:mod:`twin.live`) on this port of 127.0.0.1 (0: a free one); ``env.live_url``
            says where once the first :meth:`reset` opened the device. Needs viser.
        tip_force: estimate the tip force every step and put it in ``info`` (~2-3 ms of CPU a
            step on the default robot); default off.
    """

    # "human" opens MuJoCo's GLFW window, and GLFW without a display ends the process: offered
    # only where there is one, so Gymnasium's check_env (which renders every mode) passes headless.
    metadata = {"render_modes": ["rgb_array", *(["human"] if _has_display() else [])], "render_fps": 40}

    def __init__(self, device_url: str = "sim://", *, action_mode: str = "tensions", params: Params | None = None,
                 randomization: Randomization | None = None, tip_loads: TipLoads | None = None,
                 gains: dict | None = None, target_curvature_per_m: tuple[float, float] | None = None,
                 tension_range_n: tuple[float, float] | None = None, max_length_m: float | None = None,
                 pretension_n: float | None = None, tension_weight: float = 0.1, effort_weight: float = 1.0,
                 fault_penalty: float = 10.0, render_mode: str | None = None, live_port: int | None = None,
                 tip_force: bool = False):
        if render_mode == "human" and not _has_display():
            raise gym.error.DependencyNotInstalled(
                'render_mode = "human": needs a display (DISPLAY and WAYLAND_DISPLAY are unset); '
                'use "rgb_array" for pictures without one')
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode = {render_mode!r}: must be None or one of "
                             f"{', '.join(self.metadata['render_modes'])}")
        if action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode = {action_mode!r}: must be one of {', '.join(ACTION_MODES)}")
        parts = urllib.parse.urlsplit(device_url)
        if parts.scheme == "sim" and "seed" in urllib.parse.parse_qs(parts.query):
            raise ValueError(f"device_url = {device_url!r}: leave the seed out; reset(seed=...) seeds the twin")
        self.params = params if params is not None else load_params()
        tension_range_n = tension_range_n or default_tension_range_n(self.params)
        target_curvature_per_m = target_curvature_per_m or default_curvature_range_per_m(self.params)
        max_length_m = default_max_length_m(self.params) if max_length_m is None else max_length_m
        n = self.params.tendons.count
        if action_mode == "pairs" and n % 2:
            raise ValueError(f"action_mode = 'pairs': the robot has {n} tendons; pairs need an even count "
                             "(tendon i and i + n/2 opposed)")
        low, high = tension_range_n
        if not 0 <= low < high <= self.params.rig.tension_limit_n:
            raise ValueError(f"tension_range_n = {tension_range_n!r}: need 0 <= low < high <= "
                             f"rig.tension_limit_n = {self.params.rig.tension_limit_n}")
        if not max_length_m > 0:
            raise ValueError(f"max_length_m = {max_length_m!r}: must be > 0")
        self.device_url = device_url
        self.action_mode = action_mode
        self.randomization = randomization or Randomization()
        self.tip_loads = tip_loads or TipLoads()
        self.gains = dict(gains or {})
        self.target_curvature_per_m = target_curvature_per_m
        self.tension_range_n = (float(low), float(high))
        self.max_length_m = float(max_length_m)
        self.pretension_n = self.params.tendons.pretension_n if pretension_n is None else float(pretension_n)
        self.tension_weight, self.effort_weight, self.fault_penalty = tension_weight, effort_weight, fault_penalty

        n_a = n // 2 if action_mode == "pairs" else n
        self.action_space: spaces.Box = spaces.Box(-1.0, 1.0, (n_a,), np.float32)
        self.tip_slice = slice(2 * n, 2 * n + 3)
        high_obs = np.concatenate([np.full(n, _LENGTH_BOUND_M), np.full(n, _TENSION_BOUND_N),
                                   np.full(3, _POSITION_BOUND_M), np.ones(4), np.full(3, _POSITION_BOUND_M),
                                   np.ones(n_a)]).astype(np.float32)
        self.observation_space: spaces.Box = spaces.Box(-high_obs, high_obs, dtype=np.float32)

        self.render_mode = render_mode
        self._view: Any = None  # the camera (rgb_array) or viewer (human) on the twin, made on first use
        self.live_port = live_port
        self._live: LiveView | None = None  # made with the first device
        self.live_url: str | None = None
        self.device: Device | LiveDevice | None = None
        self._device_params: Params | None = None
        self.tip_force = bool(tip_force)
        self.force_stream: Any = None  # the twin.force.stream.ForceStream of the device, with tip_force
        self._fused: Any = None  # the last good tracker pose
        self._neutral = self._neutral_action()

    # ------------------------------------------------------------------ gymnasium API
    @property
    def _last_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The tip's last tracked (position (m), quaternion): reset() waits for the first."""
        if self._pose is None:
            raise RuntimeError("EndoscopeReachEnv: no tracked pose before reset()")
        return self._pose

    @property
    def _fixture(self) -> Fixture:
        fixture = self._dev.fixture
        if fixture is None:
            raise ValueError(f"device_url = {self.device_url!r}: the env needs a fixture (tip masses)")
        return fixture

    @property
    def _dev(self) -> Device | LiveDevice:
        """The open device: reset() opens it."""
        if self.device is None:
            raise RuntimeError("EndoscopeReachEnv: no device before reset()")
        return self.device

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode. ``options``: ``target_m`` (3,) fixes the target, ``tip_mass_kg``
        the tip mass (no change during the episode)."""
        super().reset(seed=seed)
        options = options or {}
        rng = self.np_random
        params, latency = self.randomization.sample(self.params, rng)
        self._open(params, int(rng.integers(2**31)))
        device = self._dev
        fixture = self._fixture
        fixture.settle_s = _RESET_SETTLE_S
        for mode, gains in self.gains.items():
            device.set_gains(mode, **gains)
        self._zero_m = pretension_straight(device, params, mode=ACTION_MODES[self.action_mode],
                                           tension_n=self.pretension_n)
        mass, self._change_step, self._later_mass_kg = self.tip_loads.sample(rng)
        if "tip_mass_kg" in options:
            mass, self._change_step = float(options["tip_mass_kg"]), None
        fixture.hang_tip_mass(mass)
        # Mid-episode loads land within one step: the env's time must not jump.
        fixture.settle_s = 0.0
        self._tip_mass_kg = mass
        self.target_m = np.asarray(options["target_m"], dtype=float) if "target_m" in options else self._sample_target(rng)
        if self._live is not None:
            from twin.live import LiveDevice

            if isinstance(device, LiveDevice):
                device.target_m = self.target_m
        self._latency = latency
        self._queue = collections.deque([self._neutral] * latency)
        self._previous = self._neutral.copy()
        self._steps = 0
        self._pose: tuple[np.ndarray, np.ndarray] | None = None
        sample = device.wait_next()
        while self._pose is None:
            self._read_tracker()
            if self._pose is None:
                sample = device.wait_next()
        observation = self._observation(sample)
        if self.force_stream is not None:
            self.force_stream.reset()
            self._estimate_force(sample)
        return observation, self._info(sample, float(np.linalg.norm(self._last_pose[0] - self.target_m)))

    def step(self, action):
        action = np.clip(np.asarray(action, dtype=np.float32).reshape(self.action_space.shape), -1.0, 1.0)
        self._queue.append(action)
        applied = self._queue.popleft()
        rejected = False
        try:
            self._command(applied)
        except CommandRejected:
            # The board left ENABLED (a fault latched since the last sample): end the episode below.
            rejected = True
        self._steps += 1
        if self._steps == self._change_step:
            self._fixture.hang_tip_mass(self._later_mass_kg)
            self._tip_mass_kg = self._later_mass_kg
        sample = self._dev.wait_next()
        fresh = self._read_tracker()
        if self.force_stream is not None:
            if fresh:
                self._estimate_force(sample)
            else:  # no estimate from a stale pose: the tensions moved on; info keeps the last one
                self.force_stream.follow(self._dev.drain())
        self._previous = action
        error = math.dist(self._last_pose[0].tolist(), self.target_m.tolist())
        fault = rejected or bool(sample.fault_flags & _FAULTS) or not sample.enabled
        duty = sample.motor_commands.tolist()
        reward = (-error / 0.01
                  - self.tension_weight * sum(sample.tensions_n.tolist()) / (len(duty) * self.params.rig.tension_limit_n)
                  - self.effort_weight * sum(u * u for u in duty) / len(duty)
                  - (self.fault_penalty if fault else 0.0))
        return self._observation(sample), reward, fault, False, self._info(sample, error)

    def render(self):
        """The twin as it is now: an (H, W, 3) uint8 image (``render_mode="rgb_array"``) with the
        target (green sphere), a floor grid of 1 cm squares and 1 cm bars along world x (red) and
        y (blue); or a frame of MuJoCo's viewer (``"human"``, needs a display). Needs a ``sim://`` device."""
        if self.render_mode is None:
            return None
        if self.device is None:
            raise RuntimeError("render(): call reset() first")
        if self.device.url.split(":", 1)[0] != "sim":
            raise ValueError(f"render_mode = {self.render_mode!r}: a picture needs the twin (sim://), not "
                             f"{self._dev.url}")
        if self._view is None:
            self._view = self._dev.twin.camera() if self.render_mode == "rgb_array" else self._dev.twin.viewer()
        if self.render_mode == "rgb_array":
            # The target and a 1 cm floor grid: a recorded episode shows whether the tip reaches it, and how far.
            return self._view.render(target_m=self.target_m, floor_grid=True)
        self._view.sync()
        return None

    def close(self):
        if self._live is not None:
            self._live.close()
            self._live = None
        self._close_device()

    def _close_device(self) -> None:
        if self._view is not None:
            self._view.close()
            self._view = None
        if self.device is not None:
            self._dev.close()
            self.device = None

    # ------------------------------------------------------------------ mapping
    def setpoints(self, action) -> np.ndarray:
        """What an action asks of the board: tensions (N), lengths from zero (m) or pair offsets (m)."""
        a = np.asarray(action, dtype=float)
        if self.action_mode == "tensions":
            low, high = self.tension_range_n
            return low + (a + 1.0) / 2.0 * (high - low)
        return a * self.max_length_m

    def action_for(self, setpoints) -> np.ndarray:
        """The action that asks for ``setpoints`` (the inverse of :meth:`setpoints`), clipped to [−1, 1]."""
        s = np.asarray(setpoints, dtype=float)
        if self.action_mode == "tensions":
            low, high = self.tension_range_n
            a = 2.0 * (s - low) / (high - low) - 1.0
        else:
            a = s / self.max_length_m
        return np.clip(a, -1.0, 1.0).astype(np.float32)

    # ------------------------------------------------------------------ internals
    def _neutral_action(self) -> np.ndarray:
        if self.action_mode == "tensions":
            return self.action_for(np.full(self.params.tendons.count, self.pretension_n))
        return np.zeros(self.action_space.shape, dtype=np.float32)

    def _command(self, action) -> None:
        setpoints = self.setpoints(action)
        if self.action_mode == "tensions":
            self._dev.set_tensions(setpoints)
        elif self.action_mode == "lengths":
            self._dev.set_lengths(self._zero_m + setpoints)
        else:
            self._dev.set_pairs(setpoints)

    def _open(self, params: Params, seed: int) -> None:
        scheme = urllib.parse.urlsplit(self.device_url).scheme
        if self.device is not None and (scheme != "sim" or params == self._device_params):
            if scheme == "sim":
                # The same twin, reset: rebuilding the MuJoCo model is the slow part of a reset.
                self._dev.twin.reset(seed)
                self._dev.reconnect()
            return
        self._close_device()
        device: Device | LiveDevice = open_device(self.device_url, params=params, seed=seed if scheme == "sim" else None)
        self.device = device
        device.connect()
        if self.live_port is not None:
            from twin.live import LiveDevice, LiveView

            if self._live is None:
                self._live = LiveView(self.params, port=self.live_port, base_rotation=device.base_rotation)
                self.live_url = self._live.url
            # What the env reads of the device (telemetry, tracker, the twin after each wait) goes to the view.
            device = self.device = LiveDevice(device, self._live)
        if device.tracker is None:
            raise ValueError(f"device_url = {self.device_url!r}: the env needs a tracker (serial:// takes ?igtl=host:port)")
        self._device_params = params
        if self.tip_force:
            from twin.force.stream import ForceStream

            # The env's model (not the episode's randomized twin): what a controller on a rig would know.
            self.force_stream = ForceStream.for_device(self.device, self.params)
            if self._live is not None:
                self._live.follow(self.force_stream)

    def _sample_target(self, rng) -> np.ndarray:
        kappa = rng.uniform(*self.target_curvature_per_m)
        phi = rng.uniform(0.0, 360.0)
        return self._dev.base_rotation @ arc_tip_position_m(kappa, phi, self.params.backbone.length_m)

    def _read_tracker(self) -> bool:
        """Read a tracker frame; whether the fusion accepted it (else the last good pose stays)."""
        tracker = self._dev.tracker
        if tracker is None:
            raise RuntimeError(f"{self.device_url}: the device has no tracker")
        fused = tracker.read()
        if fused.ok and fused.pose is not None:
            self._pose = (fused.pose.position_m, fused.pose.quaternion)
            self._fused = fused.pose
        return bool(fused.ok)

    def _estimate_force(self, sample) -> None:
        """One live estimate from ``sample`` and the last good tracker pose (its encoder ticks and
        those of the samples between steps move the sliding states)."""
        self.force_stream.update(sample, self._fused.position_m, self._fused.rotation, samples=self._dev.drain())

    def _observation(self, sample) -> np.ndarray:
        return np.concatenate([
            sample.tendon_lengths_m - self._zero_m, sample.tensions_n, self._last_pose[0], self._last_pose[1],
            self.target_m, self._previous,
        ]).astype(np.float32).clip(self.observation_space.low, self.observation_space.high)

    def _info(self, sample, error_m: float) -> dict:
        return {"tip_error_m": float(error_m), "tip_mass_kg": self._tip_mass_kg,
                "tensions_n": sample.tensions_n.copy(), "fault": int(sample.fault_flags),
                "time_s": sample.time_s, "latency_steps": self._latency, **self._force_info()}

    def _force_info(self) -> dict:
        force = self.force_stream.latest if self.force_stream is not None else None
        if force is None:
            return {}
        return {"tip_force_n": force.force_observable_n.copy(), "tip_force_cov_n2": force.force_cov_n2.copy(),
                "tip_force_observable": force.observable.copy(), "contact": force.contact}
