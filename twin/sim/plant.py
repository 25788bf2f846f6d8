"""The plant: the twin of the endoscope and rig, stepped in simulated time.

:class:`Plant` is what the device layer's ``sim://`` backend wraps. Time only advances in
:meth:`Plant.step` (and :meth:`Plant.step_until`, :meth:`Plant.settle`), by whole physics steps of
``sim.timestep_s``; nothing happens between calls. The spools are driven in one of four modes:

``pwm``      the rig: PWM duty in [−1, 1] per motor into the DC-motor model (:mod:`twin.sim.motor`);
             duty 0 brakes (H-bridge outputs shorted), positive duty pays tendon out.
``coast``    H-bridge outputs open: the spools turn freely (the firmware's safe stop).
``tension``  ideal tension sources on the spools (N), for ``twin sim --tensions`` and tension
             control studies.
``length``   ideal spool positions: relative tendon lengths (m, positive = paid out), for
             ``twin sim --lengths``.

In ``pwm`` and ``coast`` the motors' rotor inertia loads the spools; the ideal modes drive a
light carriage. Sensors are sampled at their rates (load cells ``rig.loadcell_rate_hz``, tracker
``rig.tracker_rate_hz``) and held; encoders are read on demand. Noise comes from one generator
seeded at construction, so a run is reproducible from its seed.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import time

import mujoco
import numpy as np

from twin import effects
from twin.checks import finite_vector
from twin.effects.tendon_friction import TendonFriction
from twin.params import Params, load_params
from twin.sim.model import (ACTUATOR_GROUPS, SPOOL_TRAVEL_M, Layout, TendonLength, build_model,
                             tendon_stiffness_n_per_m)
from twin.sim.motor import MotorConstants
from twin.sim.native_loop import Mode, PlantLoop, Reason
from twin.sim.sensors import HX711_RANGE_COUNTS, LoadCellSample, NoiseStream, TrackerSample, probe_layout

__all__ = ["DriveMode", "ENGAGE_MAX_STEP_S", "HOLDER_AT_ONCE_M", "HOLDER_STAGE_M", "HOLDER_STAGE_S", "Plant", "SettleResult", "SimulationError"]


class DriveMode(enum.StrEnum):
    """How the spools are driven (:attr:`Plant.mode`): the loop's :class:`twin.sim.native_loop.Mode`
    by name, valued as the reports spell it."""

    PWM = "pwm"
    COAST = "coast"
    TENSION = "tension"
    LENGTH = "length"


# The loop's mode numbers → DriveMode; a KeyError here when the two enums part ways.
_DRIVE_MODES = tuple(DriveMode[mode.name] for mode in Mode)


# Taking up a slack tendon: the discrete integrator linearises the tendon's dead-band spring where
# a step starts, so a tendon that goes from slack to taut within one step is springless for that
# step and engages with a spike that grows with the step and with the speed it closes at
# (twin/sim/model.py, INEXTENSIBLE_COMPLIANCE_M_PER_N): about stiffness × step × closing speed.
# With steps of 1.25 ms a spool pulling in a slack line stays within the rig's 6 N tension limit;
# with 2.5 ms it tripped the emulated board now and then. So the loop takes a stretch of steps
# as shorter ones of at most ENGAGE_MAX_STEP_S when a tendon carrying less than ENGAGE_MARGIN_N
# (or slack) could close over it fast enough for a full step's spike to exceed ENGAGE_SPIKE_N.
# Taut tendons, and slack ones resting at the slack edge — the perpendicular pair while one
# motor bends the rod — run at the full sim.timestep_s.
ENGAGE_MAX_STEP_S = 1.25e-3
ENGAGE_MARGIN_N = 0.5
ENGAGE_SPIKE_N = 0.1
# The most the reference holder's welds close at once (m of their position error, at anchors
# that lie a metre off each disc, so that a disc's tilt counts with its offset: Plant.engage_holder),
# the stages it closes a larger error in, and the time (s) each stage is given
# (twin.device.sim_fixture.SimFixture). A rod within HOLDER_AT_ONCE_M is clamped at once as before:
# every frictionless sweep of the zoo (at most 4.6 mm, the long robot's sag), the endoscope at
# μ = 0.15 (10 mm), the helical robot at μ = 0.6 (up to 33 mm, which it survives). One farther
# off, a robot that drooped with slack tendons and that friction then holds so (217-268 mm on
# long and helical at μ = 0.6; clamped at once from 268 mm the helical robot diverged within a
# step, and so it did closing from 280 mm in stages of 20 mm), closes in stages of
# HOLDER_STAGE_M, each given four times the welds' 10 ms time constant (twin.sim.model, holder
# solref).
HOLDER_AT_ONCE_M = 20e-3
HOLDER_STAGE_M = 5e-3
HOLDER_STAGE_S = 0.04


class SimulationError(RuntimeError):
    """The simulation diverged or was asked something it cannot do; the message says which."""


@dataclasses.dataclass(frozen=True)
class SettleResult:
    """Outcome of :meth:`Plant.settle`.

    Attributes:
        settled: True when the motion fell below the tolerance before the timeout.
        sim_time_s: simulated time spent settling (s).
        wall_time_s: wall-clock time spent (s).
        last_change_m: largest tip or spool displacement over the last window (m).
    """

    settled: bool
    sim_time_s: float
    wall_time_s: float
    last_change_m: float


class Plant:
    """The simulated rig.

    Args:
        params: parameter set (default ``models/endoscope/endoscope.toml``).
        base_rotation: nominal clamp orientation (3×3, body → world); default the parameter
            set's ``rig.base_quat``.
        seed: seed of the sensor-noise generator.
        elements: override of ``sim.elements``.
        tendon_sites: override of ``sim.tendon_routing``; see :class:`twin.sim.model.Layout`.

    Attributes:
        loop: the :class:`twin.sim.native_loop.PlantLoop` that steps, drives and samples this
            plant; the emulated board ticks through it too.

    Raises:
        twin.sim.native_loop.NativeLoopError: the plant loop cannot be built (no g++).
    """

    def __init__(self, params: Params | None = None, *, base_rotation=None, seed: int = 0,
                 elements: int | None = None, tendon_sites: str | None = None):
        self.params = params if params is not None else load_params()
        self.base_rotation = np.asarray(self.params.rig.base_rotation if base_rotation is None else base_rotation,
                                        dtype=float)
        self.model = build_model(self.params, base_rotation=self.base_rotation, elements=elements,
                                 tendon_sites=tendon_sites)
        self.data = mujoco.MjData(self.model)
        self.layout = Layout.from_params(self.params, elements=elements, tendon_sites=tendon_sites)
        m, n, p = self.model, self.params.tendons.count, self.params
        self.tendon_count = n
        self.loop = PlantLoop(m, self.data, n)
        motor = MotorConstants.from_rig(p.rig)
        spool_joints = [m.joint(f"spool{i}").id for i in range(n)]
        self._spool_q = m.jnt_qposadr[spool_joints]
        self._tip_site = m.site("tip").id
        self._tip_load = m.body("tip_load").id
        self._holder = np.array([m.equality(f"holder{j}").id for j in range(1, p.discs.count + 1)])
        self._holder_straight = m.eq_data[self._holder, :10].copy()
        self._path_sites = np.array([[m.site(f"hole{i}").id] + [m.site(f"t{i}_s{j + 1}").id for j in range(
            self.layout.site_s_m.size)] for i in range(n)])
        taut_length_m = m.tendon_lengthspring[:, 1].copy()
        self._tendon_stiffness = tendon_stiffness_n_per_m(p)
        self._dt = m.opt.timestep
        self._hooks = effects.step_hooks(p, m)
        # Effects that act every step may need steps shorter than sim.timestep_s to stay stable.
        longest_s = min([hook.max_step_s for hook in self._hooks], default=math.inf)
        base_substeps = max(1, math.ceil(self._dt / longest_s - 1e-9)) if math.isfinite(longest_s) else 1
        gain, offset_n = effects.loadcell_response(p)
        probes_m, axes = probe_layout(p)
        s = self.loop.state
        s.step_s = self._dt
        s.engage_stretch_m = ENGAGE_MARGIN_N / self._tendon_stiffness
        # Closing speed (m/s) at which a full step's engagement spike reaches ENGAGE_SPIKE_N.
        s.engage_speed_m_s = ENGAGE_SPIKE_N / (self._tendon_stiffness * self._dt)
        s.supply_voltage_v = motor.supply_voltage_v
        s.stall_force_n = motor.stall_force_n
        s.reflected_mass_kg = motor.reflected_mass_kg
        s.tendon_stiffness_n_per_m = self._tendon_stiffness
        s.loadcell_gain_counts_per_n = p.sensors.loadcell_gain_counts_per_n
        s.loadcell_noise_n = p.sensors.loadcell_noise_n
        s.loadcell_min_counts, s.loadcell_max_counts = HX711_RANGE_COUNTS
        s.loadcell_rate_hz = p.rig.loadcell_rate_hz
        s.tracker_noise_m = p.sensors.tracker_noise_m
        s.tracker_noise_rad = p.sensors.tracker_noise_rad
        s.tracker_rate_hz = p.rig.tracker_rate_hz
        s.m_per_count = p.rig.tendon_m_per_count
        s.slack_length_m[:n] = taut_length_m.tolist()
        s.taut_length_m[:n] = taut_length_m.tolist()
        # The slack edges as the loop moves them (a view, not a copy).
        self._slack_length_m = np.ctypeslib.as_array(s.slack_length_m)[:n]
        if self.layout.routing == "continuous":
            # The loop reads these buffers every step: they live as long as the plant.
            geometry = TendonLength.from_params(p, self.layout).geometric_stiffness(m)
            self._geometry, self._geometry_index = geometry.loop_arrays()
            s.geometry = self._geometry.ctypes.data
            s.geometry_index = self._geometry_index.ctypes.data
            s.stiffened_joints = geometry.joints.shape[0]
            s.coupled_pairs = geometry.pairs.shape[0]
            # The backbone's damping (twin.sim.model) follows the tendons' stiffening too.
            s.damping_per_stiffness_s = p.sim.damping_time_s * effects.plant_dynamics(p).damping_scale
        s.loadcell_offset_counts[:n] = [float(x) for x in p.sensors.loadcell_offset_counts]
        s.loadcell_gain[:n] = np.asarray(gain, dtype=float).tolist()
        s.loadcell_offset_n[:n] = np.asarray(offset_n, dtype=float).tolist()
        s.probe_position_m[:] = probes_m.ravel().tolist()
        s.probe_axis[:] = axes.ravel().tolist()
        s.tip_site = self._tip_site
        s.base_substeps = base_substeps
        s.engage_substeps = max(base_substeps, math.ceil(self._dt / ENGAGE_MAX_STEP_S - 1e-9))
        s.current_substeps = base_substeps
        s.ctrl_pwm, s.ctrl_tension, s.ctrl_length = (m.actuator(f"{block}0").id for block in ("motor", "tension", "length"))
        s.group_pwm, s.group_tension, s.group_length = (ACTUATOR_GROUPS[mode] for mode in ("pwm", "tension", "length"))
        s.spool_qpos[:n] = [int(q) for q in self._spool_q]
        s.spool_dof[:n] = [int(m.jnt_dofadr[j]) for j in spool_joints]
        self._set_dynamics(effects.plant_dynamics(p), spool_joints)
        m.opt.timestep = self._dt / base_substeps
        # Tendon friction runs inside the loop; other hooks are called back into Python.
        for hook in self._hooks:
            if isinstance(hook, TendonFriction):
                hook.attach(s)
        self._python_hooks = [hook for hook in self._hooks if not isinstance(hook, TendonFriction)]
        if self._python_hooks:
            self.loop.set_hook(self._before_step)
        self.reset(seed)

    # ----------------------------------------------------------------------------- state
    def reset(self, seed: int | None = None) -> None:
        """Back to t = 0: straight, at rest, tendons just taut (0.2 mN), no tip mass, holder released,
        motors braked (``pwm`` with duty 0), sample counters at zero."""
        if seed is not None:
            self._seed = seed
        mujoco.mj_resetData(self.model, self.data)
        self.loop.set_noise(NoiseStream(np.random.default_rng(self._seed)))
        for hook in self._hooks:
            hook.reset()
        self._tip_mass_kg = 0.0
        self.model.body_mass[self._tip_load] = 0.0
        self.data.eq_active[self._holder] = False
        self.loop.reset()
        self.clear_peak_tensions()
        self._loadcell: LoadCellSample | None = None
        self._tracker_frame: TrackerSample | None = None
        self._warnings_seen = self.data.warning.number.copy()
        self.loop.state.diverged_at_s = -1.0

    @property
    def time_s(self) -> float:
        """Simulation time (s)."""
        return float(self.data.time)

    @property
    def timestep_s(self) -> float:
        """The physics step ``sim.timestep_s`` (s)."""
        return float(self._dt)

    @property
    def mode(self) -> DriveMode:
        """How the spools are driven now."""
        return _DRIVE_MODES[self.loop.state.mode]

    @property
    def short_steps(self) -> int:
        """Physics steps of ``sim.timestep_s`` taken as shorter ones to take up a slack tendon
        (:data:`ENGAGE_MAX_STEP_S`), since construction."""
        return int(self.loop.state.short_steps)

    # ----------------------------------------------------------------------------- drive
    def set_motor_pwm(self, duty) -> None:
        """Drive the motors with PWM duties in [−1, 1] (clipped); positive pays tendon out."""
        self.loop.set_drive(Mode.PWM, self._vector("duty", duty).tolist())

    def coast(self) -> None:
        """Open the H-bridges: no drive, no braking."""
        self.loop.set_drive(Mode.COAST)

    def set_tensions(self, tensions_n) -> None:
        """Pull each tendon with an ideal tension source (N, >= 0)."""
        t = self._vector("tensions_n", tensions_n)
        if np.any(t < 0):
            raise ValueError(f"tensions_n = {t.tolist()}: tendons can only pull (all must be >= 0)")
        self.loop.set_drive(Mode.TENSION, t.tolist())

    def set_tendon_lengths(self, lengths_m) -> None:
        """Hold each spool at a relative tendon length (m from the straight, just-taut length;
        positive = paid out)."""
        d = self._vector("lengths_m", lengths_m)
        if np.any(np.abs(d) > SPOOL_TRAVEL_M):
            raise ValueError(f"lengths_m = {d.tolist()}: beyond the spool travel of ±{SPOOL_TRAVEL_M} m")
        self.loop.set_drive(Mode.LENGTH, d.tolist())

    def set_tip_mass_kg(self, mass_kg: float) -> None:
        """Hang a mass at the tip (kg, nominal; 0 removes it). What it truly weighs is the
        effects' (:func:`twin.effects.true_tip_mass_kg`)."""
        if not (math.isfinite(mass_kg) and mass_kg >= 0):
            raise ValueError(f"mass_kg = {mass_kg!r}: must be finite and >= 0")
        self._tip_mass_kg = float(mass_kg)
        self.loop.state.jump = 1
        self.model.body_mass[self._tip_load] = effects.true_tip_mass_kg(self.params, mass_kg)

    @property
    def tip_mass_kg(self) -> float:
        """The nominal hung mass (kg)."""
        return self._tip_mass_kg

    def set_tip_load(self, force_n=(0.0, 0.0, 0.0), moment_nm=(0.0, 0.0, 0.0)) -> None:
        """Apply a force (N) and a moment (N·m), both in the world frame, at the tip, where a
        hung mass hangs: a sideways push, a contact, a probe's cable. Zeros remove it; it adds
        to a hung mass's weight."""
        wrench = np.concatenate([finite_vector("force_n", force_n, 3), finite_vector("moment_nm", moment_nm, 3)])
        self.loop.state.jump = 1
        self.data.xfrc_applied[self._tip_load] = wrench

    @property
    def tip_load(self) -> tuple[np.ndarray, np.ndarray]:
        """The applied tip force (N) and moment (N·m), world frame (:meth:`set_tip_load`; a reset
        clears it with the rest of the state)."""
        wrench = self.data.xfrc_applied[self._tip_load]
        return wrench[:3].copy(), wrench[3:].copy()

    @property
    def sliding_state(self) -> np.ndarray | None:
        """Ground truth: the tendon friction's sliding state σ per tendon (+1 pulled … −1
        released, :class:`twin.effects.SlidingState`), or None when the twin has no friction."""
        for hook in self._hooks:
            if isinstance(hook, TendonFriction):
                return hook.state.copy()
        return None

    def engage_holder(self) -> int:
        """Clamp the reference holder around the discs: they are pulled back to and held in the
        straight pose (weld constraints), as while pretensioning.

        The holder's channel closes around round discs: it straightens the rod but leaves each
        disc turned about the backbone as it is when it closes (the weld's reference takes the
        disc's twist relative to the clamp). Pulling the twist out too would snap a helically
        routed robot, whose pretension alone twists the tip by 17°, against its tendons within
        a step (MuJoCo diverged six steps after the holder closed).

        A rod that drooped while its tendons were slack and that tendon friction then holds so
        (268 mm of weld error on the helical robot at μ = 0.6) is not snapped straight within a
        step either: that drove the spools' tensions to hundreds of newtons and MuJoCo diverged
        within four steps, with or without the friction. The holder then closes in stages of
        :data:`HOLDER_STAGE_M` of weld error each (:meth:`close_holder`), the way a hand closes
        it; a rod within :data:`HOLDER_AT_ONCE_M` is clamped straight at once.

        Returns:
            the number of stages the holder closes in (1: it is closed now).
        """
        m, d = self.model, self.data
        mujoco.mj_kinematics(m, d)
        relative, conjugate, anchor = np.empty(4), np.empty(4), np.empty(3)
        start, target = np.empty((len(self._holder), 7)), np.empty((len(self._holder), 7))
        for row, (eq, straight) in enumerate(zip(self._holder, self._holder_straight)):
            disc, clamp = m.eq_obj1id[eq], m.eq_obj2id[eq]
            # The clamp's orientation in the disc's frame; its twist part about the backbone (z).
            mujoco.mju_negQuat(conjugate, d.xquat[disc])
            mujoco.mju_mulQuat(relative, conjugate, d.xquat[clamp])
            twist = np.array([relative[0], 0.0, 0.0, relative[3]])
            twist /= max(np.linalg.norm(twist), 1e-12)
            # The weld's anchor (eq_data[0:3], disc frame) lies at eq_data[3:6] in the clamp's
            # frame: at the straight disc's position, turned by the disc's twist.
            mujoco.mju_rotVecQuat(anchor, straight[0:3], twist)
            target[row, :3] = straight[3:6] - straight[0:3] + anchor
            target[row, 3:] = twist
            # The reference that holds the disc where it is: the point eq_data[3:6] of the disc's
            # frame on the clamp's eq_data[0:3].
            here = d.xmat[clamp].reshape(3, 3) @ straight[0:3] + d.xpos[clamp] - d.xpos[disc]
            start[row, :3] = d.xmat[disc].reshape(3, 3).T @ here
            start[row, 3:] = relative
        # The welds' position error at their anchors, which the holder is to close.
        travel_m = float(np.max(np.linalg.norm(target[:, :3] - start[:, :3], axis=1)))
        self._holder_path = (start, target)
        self._holder_stages = 1 if travel_m <= HOLDER_AT_ONCE_M else math.ceil(travel_m / HOLDER_STAGE_M - 1e-9)
        self._holder_stage = 0
        self.close_holder()
        self.data.eq_active[self._holder] = True
        return self._holder_stages

    def close_holder(self) -> bool:
        """Close the engaged holder by one more of its stages (:meth:`engage_holder`): the welds
        hold each disc that share of the way from where it was when the holder engaged to
        straight. Returns True once it is fully closed."""
        start, target = self._holder_path
        self._holder_stage = min(self._holder_stage + 1, self._holder_stages)
        share = self._holder_stage / self._holder_stages
        turn, quat = np.empty(3), np.empty(4)
        for eq, a, b in zip(self._holder, start, target):
            if share >= 1.0:
                self.model.eq_data[eq, 3:10] = b
                continue
            # Position straight along, orientation along the shortest turn.
            mujoco.mju_subQuat(turn, b[3:], a[3:])
            quat[:] = a[3:]
            mujoco.mju_quatIntegrate(quat, turn, share)
            self.model.eq_data[eq, 3:6] = a[:3] + share * (b[:3] - a[:3])
            self.model.eq_data[eq, 6:10] = quat
        self.loop.state.jump = 1
        return self._holder_stage == self._holder_stages

    def release_holder(self) -> None:
        """Open the reference holder: the discs are free again."""
        self.data.eq_active[self._holder] = False
        self.loop.state.jump = 1

    @property
    def holder_engaged(self) -> bool:
        return bool(self.data.eq_active[self._holder[0]])

    # ----------------------------------------------------------------------------- time
    def step(self, duration_s: float) -> None:
        """Advance by ``duration_s`` rounded to whole steps (at least one when positive).

        Raises:
            SimulationError: the simulation diverged (MuJoCo warned of bad accelerations).
        """
        if not (math.isfinite(duration_s) and duration_s >= 0):
            raise ValueError(f"duration_s = {duration_s!r}: must be finite and >= 0")
        steps = max(1, round(duration_s / self._dt)) if duration_s > 0 else 0
        if steps and self.loop.run(steps) == Reason.WARNING:
            self.raise_warnings()

    def step_until(self, time_s: float) -> None:
        """Advance to simulation time ``time_s`` (to the first step at or after it)."""
        self.step(max(0.0, time_s - self.time_s))

    def settle(self, tol_m: float = 1e-6, timeout_s: float = 3.0, window_s: float = 0.02) -> SettleResult:
        """Step until neither the tip nor any spool moved more than ``tol_m`` over each of two
        consecutive windows.

        One window is not enough: a rod carrying a tip mass swings slowly (4 Hz with 10 g), and
        a window that straddles a turning point sees almost no change. Two in a row cannot both
        do so. With the backbone's damping time of ``sim.damping_time_s`` the state left to go is
        then about tol_m · damping_time_s / window_s.

        Returns:
            :class:`SettleResult`; ``settled`` is False when ``timeout_s`` of simulated time ran
            out first — the caller must not take that state as static.
        """
        start_sim, start_wall = self.time_s, time.perf_counter()
        change, quiet = math.inf, 0
        while self.time_s - start_sim < timeout_s:
            before = np.concatenate([self.tip_pose()[0], self.data.qpos[self._spool_q]])
            self.step(window_s)
            after = np.concatenate([self.tip_pose()[0], self.data.qpos[self._spool_q]])
            change = float(np.max(np.abs(after - before)))
            quiet = quiet + 1 if change < tol_m else 0
            if quiet == 2:
                return SettleResult(True, self.time_s - start_sim, time.perf_counter() - start_wall, change)
        return SettleResult(False, self.time_s - start_sim, time.perf_counter() - start_wall, change)

    def raise_warnings(self) -> None:
        """Raise :class:`SimulationError` for the MuJoCo warnings since the last check, if any;
        the loop returns :data:`twin.sim.native_loop.Reason.WARNING` when there are."""
        counts = self.data.warning.number.copy()
        new = {mujoco.mjtWarning(i).name: int(c) for i, c in enumerate(counts - self._warnings_seen) if c > 0}
        self._warnings_seen = counts
        # MuJoCo resets the data when a step diverges: the loop kept the time it happened at.
        diverged_s, self.loop.state.diverged_at_s = self.loop.state.diverged_at_s, -1.0
        if new:
            at_s = diverged_s if diverged_s >= 0 else self.time_s
            raise SimulationError(f"MuJoCo warned at t = {at_s:.4f} s: {new}")

    # ----------------------------------------------------------------------------- sensors
    def encoder_counts(self) -> np.ndarray:
        """(n,) int64 quadrature counts of the motor encoders (0 at reset, up = paid out)."""
        return np.array(self.loop.encoder_counts(), dtype=np.int64)

    def loadcell_sample(self) -> LoadCellSample:
        """The latest load-cell sample (raw HX711 counts), held between samples."""
        s = self.loop.state
        if self._loadcell is None or self._loadcell.index != s.loadcell_index:
            self._loadcell = LoadCellSample(np.array(s.raw_counts[:self.tendon_count], dtype=np.int64),
                                            s.loadcell_index, s.loadcell_time_s)
        return self._loadcell

    def loadcell_raw_counts(self) -> np.ndarray:
        """(n,) int64 raw counts of :meth:`loadcell_sample`."""
        return self.loadcell_sample().raw_counts

    def tracker_probes(self) -> TrackerSample:
        """The latest EM tracker frame (two 5-DOF probes), held between frames."""
        s = self.loop.state
        if self._tracker_frame is None or self._tracker_frame.index != s.tracker_index:
            self._tracker_frame = TrackerSample(np.array(s.tracker_positions_m[:]).reshape(2, 3),
                                                np.array(s.tracker_axes[:]).reshape(2, 3), s.tracker_index,
                                                s.tracker_time_s)
        return self._tracker_frame

    # ----------------------------------------------------------------------------- ground truth
    def true_tensions_n(self) -> np.ndarray:
        """(n,) tension at the spool end of each tendon (N): what a perfect load cell reads."""
        return np.maximum(self.data.ten_length - self._slack_length_m, 0.0) * self._tendon_stiffness

    def peak_tensions_n(self) -> np.ndarray:
        """(n,) the largest tension each tendon carried at any physics step since the last
        :meth:`clear_peak_tensions` (or reset) (N): what a safety limit must bound."""
        return np.array(self.loop.state.peak_tension_n[:self.tendon_count])

    def clear_peak_tensions(self) -> None:
        """Start :meth:`peak_tensions_n` afresh from the current tensions."""
        self.loop.state.peak_tension_n[:self.tendon_count] = self.true_tensions_n().tolist()

    def tip_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Tip position (3,) m and rotation (3, 3) in the world frame, base at the origin."""
        return self.data.site_xpos[self._tip_site].copy(), self.data.site_xmat[self._tip_site].reshape(3, 3).copy()

    def spool_positions_m(self) -> np.ndarray:
        """(n,) tendon paid out at each spool (m): the relative tendon lengths."""
        return self.data.qpos[self._spool_q].copy()

    def tendon_path_lengths_m(self) -> np.ndarray:
        """(n,) each tendon's path from the base hole to the tip disc (m), as the predictor's
        ``tendon_lengths_m``."""
        p = self.data.site_xpos[self._path_sites]
        return np.linalg.norm(np.diff(p, axis=1), axis=2).sum(axis=1)

    def backbone_positions_m(self) -> np.ndarray:
        """(N + 2, 3) the base, each station and the tip (m)."""
        ids = [self.model.body(f"b{k}").id for k in range(1, self.layout.elements + 1)]
        return np.vstack([self.data.xpos[self.model.body("clamp").id], self.data.xpos[ids],
                          self.data.site_xpos[self._tip_site]])

    def warnings(self) -> dict[str, int]:
        """MuJoCo warnings raised since the model was built, by name (only non-zero ones)."""
        return {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(self.data.warning)
                if w.number}

    # ----------------------------------------------------------------------------- internals
    def _vector(self, name: str, value) -> np.ndarray:
        return finite_vector(name, value, self.tendon_count)

    def _set_dynamics(self, dynamics: effects.PlantDynamics, spool_joints) -> None:
        """The rig's dynamic imperfections (:class:`twin.effects.PlantDynamics`): the loop's in its
        state, friction and damping as the joints' own; each left untouched when off."""
        m, s = self.model, self.loop.state
        s.latency_s = dynamics.actuation_latency_s
        s.loadcell_lag_s = dynamics.loadcell_lag_s
        s.backlash_m = dynamics.spool_backlash_m
        if dynamics.motor_friction_n > 0:
            m.dof_frictionloss[m.jnt_dofadr[spool_joints]] = dynamics.motor_friction_n
        if dynamics.damping_scale != 1.0:
            backbone = [j for j in range(m.njnt) if m.joint(j).name.startswith("b")]
            dofs = m.jnt_dofadr[backbone]
            m.dof_damping[dofs] = m.dof_damping[dofs] * dynamics.damping_scale

    def _before_step(self) -> None:
        tensions = self.true_tensions_n()
        for hook in self._python_hooks:
            hook.before_step(self.model, self.data, tensions)
