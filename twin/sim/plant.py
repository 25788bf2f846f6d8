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
import math
import time

import mujoco
import numpy as np

from twin.params import Params, load_params
from twin.pose import HORIZONTAL
from twin.sim import native_loop
from twin.sim.effects import FRICTION_MAX_STEP_S, TendonFriction
from twin.sim.model import ACTUATOR_GROUPS, SPOOL_TRAVEL_M, Layout, build_model, tendon_stiffness_n_per_m
from twin.sim.motor import MotorConstants, duty_to_voltage_v, encoder_counts
from twin.sim.sensors import LoadCells, LoadCellSample, NoiseStream, Tracker, TrackerSample

__all__ = ["ENGAGE_MAX_STEP_S", "MODES", "Plant", "SettleResult", "SimulationError"]

MODES = ("pwm", "coast", "tension", "length")
_ACTUATOR_BLOCK = {"pwm": 0, "tension": 1, "length": 2}


# Taking up a slack tendon: the discrete integrator linearises the tendon's dead-band spring where
# a step starts, so a tendon that goes from slack to taut within one step is springless for that
# step and engages with a spike that grows with the step and with the speed it closes at
# (twin/sim/model.py, INEXTENSIBLE_COMPLIANCE_M_PER_N): about stiffness × step × closing speed.
# With steps of 1.25 ms a spool pulling in a slack line stays within the rig's 6 N tension limit;
# with 2.5 ms it tripped the emulated board now and then. So the plant takes a stretch of steps
# as shorter ones of at most ENGAGE_MAX_STEP_S when a tendon carrying less than ENGAGE_MARGIN_N
# (or slack) could close over it fast enough for a full step's spike to exceed ENGAGE_SPIKE_N
# (:meth:`Plant._engage_risk`). Taut tendons, and slack ones resting at the slack edge — the
# perpendicular pair while one motor bends the rod — run at the full sim.timestep_s.
ENGAGE_MAX_STEP_S = 1.25e-3
ENGAGE_MARGIN_N = 0.5
ENGAGE_SPIKE_N = 0.1


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
        params: parameter set (default ``models/endoscope.toml``).
        base_rotation: nominal clamp orientation (3×3, body → world); horizontal by default.
        seed: seed of the sensor-noise generator.
        elements: override of ``sim.elements``.
        tendon_sites: override of ``sim.tendon_routing``; see :class:`twin.sim.model.Layout`.
        native: step in native code (:mod:`twin.sim.native_loop`; same numbers, several times
            less overhead) where it can: four tendons, no tendon friction, g++ at hand.

    Attributes:
        short_steps: physics steps of ``sim.timestep_s`` taken as shorter ones to take up a
            slack tendon (:data:`ENGAGE_MAX_STEP_S`), since construction.
    """

    def __init__(self, params: Params | None = None, *, base_rotation=HORIZONTAL, seed: int = 0,
                 elements: int | None = None, tendon_sites: str | None = None, native: bool = True):
        self.params = params if params is not None else load_params()
        self.base_rotation = np.asarray(base_rotation, dtype=float)
        self.model = build_model(self.params, base_rotation=self.base_rotation, elements=elements,
                                 tendon_sites=tendon_sites)
        self.data = mujoco.MjData(self.model)
        self.layout = Layout.from_params(self.params, elements=elements, tendon_sites=tendon_sites)
        m, n = self.model, self.params.tendons.count
        self.tendon_count = n
        self._motor = MotorConstants.from_rig(self.params.rig)
        self._spool_joints = np.array([m.joint(f"spool{i}").id for i in range(n)])
        self._spool_q = m.jnt_qposadr[self._spool_joints]
        self._spool_v = m.jnt_dofadr[self._spool_joints]
        self._tip_site = m.site("tip").id
        self._tip_load = m.body("tip_load").id
        self._holder = np.array([m.equality(f"holder{j}").id for j in range(1, self.params.discs.count + 1)])
        self._path_sites = np.array([[m.site(f"hole{i}").id] + [m.site(f"t{i}_s{j + 1}").id for j in range(
            self.layout.site_s_m.size)] for i in range(n)])
        spool_sites = np.array([[m.site(f"spool{i}").id] for i in range(n)])
        self._slack_length_m = m.tendon_lengthspring[:, 1].copy()
        self._slack_length_list = self._slack_length_m.tolist()
        self._tendon_stiffness = tendon_stiffness_n_per_m(self.params)
        friction = self.params.effects.tendon_friction_coeff
        self._friction = (TendonFriction(m, friction, self._spool_v, np.hstack([spool_sites, self._path_sites]))
                          if friction > 0 else None)
        self._dt = m.opt.timestep
        # Friction is updated between physics steps from the spool's last move; beyond
        # FRICTION_MAX_STEP_S that explicit update chatters against the stiff tendon, so the
        # plant then takes each step as several shorter ones.
        self._substeps = math.ceil(self._dt / FRICTION_MAX_STEP_S - 1e-9) if self._friction is not None else 1
        # A tendon near or past slack is taken up with steps of at most ENGAGE_MAX_STEP_S.
        self._engage_substeps = max(self._substeps, math.ceil(self._dt / ENGAGE_MAX_STEP_S - 1e-9))
        self._engage_stretch_m = ENGAGE_MARGIN_N / self._tendon_stiffness
        # Closing speed (m/s) at which a full step's engagement spike reaches ENGAGE_SPIKE_N.
        self._engage_speed_m_s = ENGAGE_SPIKE_N / (self._tendon_stiffness * self._dt)
        # The sparse tendon Jacobian (mjData.ten_J): each row's entries and their columns, for ten_J · qacc.
        self._ten_j_cols_list = m.ten_J_colind[:m.ten_J_rownnz.sum()].tolist()
        self._ten_j_rows_list = [range(a, a + k) for a, k in zip(m.ten_J_rowadr.tolist(), m.ten_J_rownnz.tolist())]
        self.short_steps = 0
        m.opt.timestep = self._dt / self._substeps
        self._current_substeps = self._substeps
        self.reset(seed)
        # Friction is updated from Python between steps: that plant steps in Python.
        usable = native and self._friction is None and n == native_loop.CHANNELS
        self._native = native_loop.PlantLoop(self) if usable and native_loop.available() else None

    # ----------------------------------------------------------------------------- state
    def reset(self, seed: int | None = None) -> None:
        """Back to t = 0: straight, at rest, tendons just taut (0.2 mN), no tip mass, holder released,
        motors braked (``pwm`` with duty 0), sample counters at zero."""
        if seed is not None:
            self._seed = seed
        mujoco.mj_resetData(self.model, self.data)
        self._noise = NoiseStream(np.random.default_rng(self._seed))
        self._loadcells = LoadCells(self.params, self._noise)
        self._tracker = Tracker(self.params, self._noise)
        if self._friction is not None:
            self._friction.reset()
        self._tip_mass_kg = 0.0
        self._jump = True
        self._pwm_v = np.zeros(self.tendon_count)
        self._jump_accel_m_s2 = 0.0
        self.model.body_mass[self._tip_load] = 0.0
        self.data.eq_active[self._holder] = False
        self._mode = None
        self._set_mode("pwm")
        mujoco.mj_forward(self.model, self.data)
        self._loadcell = self._sample_loadcells(0)
        self._tracker_frame = self._sample_tracker(0)
        self._warnings_seen = self._warning_counts()

    @property
    def time_s(self) -> float:
        """Simulation time (s)."""
        return float(self.data.time)

    @property
    def timestep_s(self) -> float:
        return float(self._dt)

    @property
    def mode(self) -> str:
        """The drive mode: one of :data:`MODES`."""
        return self._mode

    # ----------------------------------------------------------------------------- drive
    def set_motor_pwm(self, duty) -> None:
        """Drive the motors with PWM duties in [−1, 1] (clipped); positive pays tendon out."""
        self._set_mode("pwm")
        volts = duty_to_voltage_v(self._vector("duty", duty), self._motor.supply_voltage_v)
        # The spools' acceleration steps with the drive: bound it for the engagement check.
        step_n = self._motor.stall_force_n / self._motor.supply_voltage_v * float(abs(volts - self._pwm_v).max())
        self._jump_accel_m_s2 += step_n / self._motor.reflected_mass_kg
        self._pwm_v = volts
        self._ctrl("pwm")[:] = volts

    def coast(self) -> None:
        """Open the H-bridges: no drive, no braking."""
        self._set_mode("coast")

    def set_tensions(self, tensions_n) -> None:
        """Pull each tendon with an ideal tension source (N, >= 0)."""
        t = self._vector("tensions_n", tensions_n)
        if np.any(t < 0):
            raise ValueError(f"tensions_n = {t.tolist()}: tendons can only pull (all must be >= 0)")
        self._set_mode("tension")
        self._ctrl("tension")[:] = t
        self._jump = True

    def set_tendon_lengths(self, lengths_m) -> None:
        """Hold each spool at a relative tendon length (m from the straight, just-taut length;
        positive = paid out)."""
        d = self._vector("lengths_m", lengths_m)
        if np.any(np.abs(d) > SPOOL_TRAVEL_M):
            raise ValueError(f"lengths_m = {d.tolist()}: beyond the spool travel of ±{SPOOL_TRAVEL_M} m")
        self._set_mode("length")
        self._ctrl("length")[:] = d
        self._jump = True

    def set_tip_mass_kg(self, mass_kg: float) -> None:
        """Hang a mass at the tip (kg, nominal; 0 removes it). The weight is off by
        ``effects.tip_load_error_fraction``."""
        if not (math.isfinite(mass_kg) and mass_kg >= 0):
            raise ValueError(f"mass_kg = {mass_kg!r}: must be finite and >= 0")
        self._tip_mass_kg = float(mass_kg)
        self._jump = True
        self.model.body_mass[self._tip_load] = mass_kg * (1.0 + self.params.effects.tip_load_error_fraction)

    @property
    def tip_mass_kg(self) -> float:
        """The nominal hung mass (kg)."""
        return self._tip_mass_kg

    def engage_holder(self) -> None:
        """Clamp the reference holder around the discs: they are pulled back to and held in the
        straight pose (weld constraints), as while pretensioning."""
        self.data.eq_active[self._holder] = True
        self._jump = True

    def release_holder(self) -> None:
        self.data.eq_active[self._holder] = False
        self._jump = True

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
        remaining = max(1, round(duration_s / self._dt)) if duration_s > 0 else 0
        if remaining and self._native is not None:
            self._native.run(remaining)
            return
        model, data = self.model, self.data
        while remaining > 0:
            chunk = min(remaining, self._steps_until(min(self._next_loadcell_s, self._next_tracker_s)))
            substeps = self._substeps
            if self._engage_substeps > substeps and self._engage_risk(chunk * self._dt):
                substeps = self._engage_substeps
                self.short_steps += chunk
            self._jump, self._jump_accel_m_s2 = False, 0.0
            if substeps != self._current_substeps:
                model.opt.timestep = self._dt / substeps
                self._current_substeps = substeps
            if self._friction is None:
                mujoco.mj_step(model, data, chunk * substeps)
            else:
                for _ in range(chunk * substeps):
                    self._friction.apply(self.model, self.data, self.true_tensions_n())
                    mujoco.mj_step(self.model, self.data)
            remaining -= chunk
            self._end_chunk()

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

    # ----------------------------------------------------------------------------- sensors
    def encoder_counts(self) -> np.ndarray:
        """(n,) int64 quadrature counts of the motor encoders (0 at reset, up = paid out)."""
        return encoder_counts(self.data.qpos[self._spool_q], self.params.rig)

    def loadcell_sample(self) -> LoadCellSample:
        """The latest load-cell sample (raw HX711 counts), held between 80 Hz samples."""
        return self._loadcell

    def loadcell_raw_counts(self) -> np.ndarray:
        """(n,) int64 raw counts of :meth:`loadcell_sample`."""
        return self._loadcell.raw_counts

    def tracker_probes(self) -> TrackerSample:
        """The latest EM tracker frame (two 5-DOF probes), held between 40 Hz frames."""
        return self._tracker_frame

    # ----------------------------------------------------------------------------- ground truth
    def true_tensions_n(self) -> np.ndarray:
        """(n,) tension at the spool end of each tendon (N): what a perfect load cell reads."""
        k = self._tendon_stiffness
        return np.array([max(length - slack, 0.0) * k for length, slack in
                         zip(self.data.ten_length.tolist(), self._slack_length_list)])

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
        v = np.asarray(value, dtype=float).reshape(-1)
        if v.shape != (self.tendon_count,) or not np.isfinite(v).all():
            raise ValueError(f"{name} = {value!r}: expected {self.tendon_count} finite numbers")
        return v

    def _ctrl(self, mode: str) -> np.ndarray:
        n = self.tendon_count
        block = _ACTUATOR_BLOCK[mode]
        return self.data.ctrl[block * n:(block + 1) * n]

    def _set_mode(self, mode: str) -> None:
        if self._mode == mode:
            return
        self._mode = mode
        enabled = ACTUATOR_GROUPS.get(mode)
        self.model.opt.disableactuator = sum(1 << g for g in ACTUATOR_GROUPS.values() if g != enabled)
        self.data.ctrl[:] = 0.0
        self._jump = True
        self._pwm_v = np.zeros(self.tendon_count)
        if mode == "length":
            # Start the servo where the spools are, so that switching modes does not jerk them.
            self._ctrl("length")[:] = self.data.qpos[self._spool_q]
        motor = mode in ("pwm", "coast")
        self.model.dof_armature[self._spool_v] = self._motor.reflected_mass_kg if motor else 0.0

    def _engage_risk(self, span_s: float) -> bool:
        """Could a tendon that is slack or carries less than ENGAGE_MARGIN_N engage within the
        next ``span_s`` with a full step's spike over ENGAGE_SPIKE_N?

        The closing speed is bounded from the last step: the tendon's speed, plus its
        acceleration (``ten_J`` · ``qacc``, the last step's velocity change per second) and the
        spools' acceleration step from a new PWM drive, over the span and the one step the
        kinematics lag behind. After a jump the plant cannot bound (a mode switch, a new ideal
        tension or length, the tip mass, the holder) any tendon near slack counts.
        """
        # Plain floats: on four tendons they are several times faster than numpy's calls.
        d = self.data
        margin = self._engage_stretch_m
        stretch = [length - slack for length, slack in zip(d.ten_length.tolist(), self._slack_length_list)]
        near = [i for i, e in enumerate(stretch) if e < margin]
        if not near:
            return False
        if self._jump:
            return True
        span = span_s + self._dt
        # Summed in order in plain floats: twin/sim/native/loop.cpp does the same sums
        # in the same order, so both take the same steps.
        ten_j, qacc, speed = d.ten_J.tolist(), d.qacc.tolist(), d.ten_velocity.tolist()
        cols, extra = self._ten_j_cols_list, self._jump_accel_m_s2
        for i in near:
            acc = 0.0
            for k in self._ten_j_rows_list[i]:
                acc += ten_j[k] * qacc[cols[k]]
            a = max(acc, 0.0) + extra
            v = max(speed[i], 0.0)
            if v + a * span > self._engage_speed_m_s and stretch[i] + (v + 0.5 * a * span) * span > 0.0:
                return True
        return False

    def _end_chunk(self) -> None:
        """After a chunk of physics steps (here, or natively in twin.device.board_loop): raise on
        a MuJoCo warning, then take the samples that have come due."""
        self._check_warnings()
        self._take_due_samples()

    def _take_due_samples(self) -> None:
        """Sample the load cells and the tracker if their time has come."""
        now_s = self.data.time
        if now_s >= self._next_loadcell_s - 1e-9:
            self._loadcell = self._sample_loadcells(self._loadcell.index + 1)
        if now_s >= self._next_tracker_s - 1e-9:
            self._tracker_frame = self._sample_tracker(self._tracker_frame.index + 1)

    def _steps_until(self, t_s: float) -> int:
        return max(1, math.ceil((t_s - self.data.time) / self._dt - 1e-9))

    def _sample_loadcells(self, index: int) -> LoadCellSample:
        sample = LoadCellSample(self._loadcells.read(self.true_tensions_n()), index, self.time_s)
        self._next_loadcell_s = (index + 1) / self.params.rig.loadcell_rate_hz
        return sample

    def _sample_tracker(self, index: int) -> TrackerSample:
        positions, axes = self._tracker.read(*self.tip_pose())
        self._next_tracker_s = (index + 1) / self.params.rig.tracker_rate_hz
        return TrackerSample(positions, axes, index, self.time_s)

    def _warning_counts(self) -> np.ndarray:
        # The vector view: building it from the per-warning structs costs 60 µs, a step's worth.
        counts = self.data.warning.number.copy()
        self._warnings_seen_bytes = counts.tobytes()
        return counts

    def _check_warnings(self) -> None:
        counts = self.data.warning.number
        # Comparing the bytes is the cheapest test (1 µs against 7 for a numpy comparison).
        if counts.tobytes() != self._warnings_seen_bytes:
            new = {mujoco.mjtWarning(i).name: int(c) for i, c in enumerate(counts - self._warnings_seen) if c > 0}
            self._warnings_seen = self._warning_counts()
            if new:
                raise SimulationError(f"MuJoCo warned at t = {self.time_s:.4f} s: {new}")
