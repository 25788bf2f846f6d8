"""Capstan friction of the tendons at the disc holes.

Keys: ``effects.tendon_friction_coeff`` μ per radian of wrap (0 = off) and
``effects.tendon_friction_direction`` (±1, the predictor's sliding sense at rest).

Twin: the tension decays as e^(−μθ) over the wrap angle θ from the spool to each disc while the
tendon is pulled, and grows so while it is released; the load cell, at the spool, reads the
undecayed end. So the tip bends less than the measured tension says on loading, more on
unloading: hysteresis. :class:`TendonFriction` applies it before every physics step.

Prediction: the predictor takes μ with the body (:class:`twin.effects.BodySpec`) and each
tendon's sliding direction from its encoder length (:func:`friction_direction`).

Dynamic calibration (:mod:`twin.dynamics`): μ again, fitted on log scale between 0.001 and 1
per radian through twin replays of time series, where the Dahl state sets the sliding direction.

Discrepancy: μ (log; starts at 0.02 when off; between 0.001 and 1 per radian, a braided line
in a printed hole being of order 0.1): one coefficient for all holes, fitted for both sliding
directions at rest (pulled / backed off), the better kept.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from twin.effects.base import BodySpec, Candidate, Effect, FitParameter, Key, Params

__all__ = ["EFFECT", "FRICTION_JUMP_N", "FRICTION_MAX_STEP_S", "FRICTION_TENSION_CAP_LIMITS", "FRICTION_MOTOR_TRAVEL_LAG_S", "FRICTION_TENSION_LAG_S", "FRICTION_TRAVEL_LAG_S", "PRESLIDING_M", "SlidingState", "TendonFriction", "friction_direction",
           "slide", "slide_path"]

# Tendon travel over which the friction turns from one direction to the other (m): the
# presliding (Dahl) displacement of a braided line in a printed hole, an assumption of a few
# hundredths of a millimetre, well above an encoder count (0.94 µm).
PRESLIDING_M = 2e-5
# Longest physics step (s) the friction is taken at: the twin's default 5 ms step. Shorter steps
# (2.5, 1.67, 0.83 ms) did not remove the divergences at high μ: those grow out of a limit cycle
# of the length loop with the friction, not the step (see FRICTION_TRAVEL_LAG_S).
FRICTION_MAX_STEP_S = 5e-3
# Time constant (s) of the spool tension the twin's friction forces follow. The forces are
# explicit (set before each step from the last step's tension), so a tension spike of one step
# (a tendon snapping taut) would return at once as a friction force and, with the sliding state
# flipping with the spool's chatter, grow into a divergence (seen in the validation sweep at
# μ = 0.15, κ = 26.2 1/m: 100 N within 2 ms, then NaN). A few milliseconds of lag damp that and
# change nothing at rest nor in motions slower than the board's 5 ms tick.
FRICTION_TENSION_LAG_S = 2e-3
# Time constant (s) of the spool travel that moves the sliding state while the spool is on an
# ideal source (the plant's tension and length modes: the fixture's dead weights, `twin sim`). A
# spool on an ideal tension source is a light carriage on a 200 kN/m tendon: it chatters by tens
# of µm from one 5 ms step to the next, beyond the presliding travel, and each flip of σ swings
# the friction forces by 2 T₀ sinh(μθ) (7 N at μ = 0.6 over a quarter turn), which an explicit
# step cannot follow; 20 ms of lag (4 board ticks) follows its slower motion.
FRICTION_TRAVEL_LAG_S = 20e-3
# ... and while the motor drives the spool (the board's every mode, so every rig measurement):
# none. That spool carries the rotor (2.66 kg at the tendon on the thesis rig) and does not
# chatter, and a lag there is a delay in a loop: in tension mode the rod's swing moves the
# spool through the tension loop, the spool's travel flips σ, σ swings the holes' tensions, and
# those push the rod. With 5, 20 and 60 ms of lag that loop cycled at 15, 11 and 7 Hz (the
# endoscope at μ = 0.3, κ = 26.2 1/m, φ 0 and 30, a 5 g hold in tension mode: 2-5 N peak to
# peak, the tip never at rest or the tension limit tripped); without, those rows come to rest.
FRICTION_MOTOR_TRAVEL_LAG_S = 0.0
# The highest spool tension the twin's friction follows, as a multiple of the rig's tension limit
# (``rig.tension_limit_n``). A slack tendon that a dead weight or a motor snaps taut spikes for a
# step to 100-300 N on the twin's practically inextensible line (seen at the calibration weights
# of a pretension, after a bend at κ = 26.2 1/m that the friction held 29 mm off straight); a
# rig's board trips at its limit, so no held tension reaches that. Followed in full, such a spike
# came back within a step as friction forces of e^(μθ) − 1 times it on the bent rod, and the
# twin diverged (the compensation grid at μ = 0.3, κ = 26.2 1/m: mjWARN_BADQACC 29 ms after the
# weights went on). Twice the limit leaves every tension the board can hold or trip on followed.
FRICTION_TENSION_CAP_LIMITS = 2.0
# A change of the friction's pull at a tendon's end within one physics step (N) after which the
# plant loop takes short steps (twin.sim.plant.ENGAGE_MAX_STEP_S) until it calms: the friction
# turning round on a stiff robot let go by a tripped board at 27 N (μ = 0.6) swung it by some
# 30 N in a step, which at 5 ms steps whipped the rod to MuJoCo's divergence within 50 ms and at
# 1.25 ms steps did not; on ideal tension sources (the twin's cross-check) the long and
# stiff-long robots at μ = 0.6 chattered into a divergence with 10 N and 1 N here, not with
# 0.5 N. The endoscope's sweeps at μ <= 0.3 (twin bench friction's rows) take no more short
# steps for it than without (93 at μ = 0.3; 95 with 0.2 N).
FRICTION_JUMP_N = 0.5
# Starting value of μ for a fit when it is off (0) in the parameter set: log(0) cannot start one.
_FIT_START = 0.02


def slide(state, pull_m) -> np.ndarray:
    """The Dahl sliding state after each tendon was pulled in by ``pull_m`` (m; negative: paid
    out): σ moves towards +1 while pulled and −1 while released, over :data:`PRESLIDING_M` of
    travel, and holds while the tendon stands. The twin's friction and the host's record of a
    rig's (:class:`SlidingState`) both advance it so."""
    return slide_path(state, np.asarray(pull_m, dtype=float).reshape(1, -1))


def slide_path(state, pulls_m) -> np.ndarray:
    """The Dahl sliding state after the rows of ``pulls_m`` ((T, n) m, oldest first), each as
    :func:`slide`. A plain loop over numbers: a record of a whole run is thousands of rows of a
    few tendons each, mostly standing still."""
    sigma = np.asarray(state, dtype=float).reshape(-1).tolist()
    for row in (np.asarray(pulls_m, dtype=float) / PRESLIDING_M).tolist():
        for i, step in enumerate(row):
            if step:
                value = sigma[i] + step
                sigma[i] = 1.0 if value > 1.0 else -1.0 if value < -1.0 else value
    return np.array(sigma)


class SlidingState:
    """Each tendon's friction sliding state σ (−1 … +1), followed from its encoder the way the
    twin's friction follows its spool: a static state remembers how it was reached, so a dataset
    records σ with every measurement and the prediction uses it instead of guessing a direction.

    Feed it every telemetry sample in order (:meth:`follow`); it starts at 0 (unknown), as the
    twin's friction does, and the first move of more than :data:`PRESLIDING_M` sets it. The
    travel moves σ through the friction's lag while the motors drive the spools
    (:data:`FRICTION_MOTOR_TRAVEL_LAG_S`), as in the twin.

    Example:
        >>> state = SlidingState(device.info.tendon_m_per_count)
        >>> state.follow(device.drain())
        >>> state.state
    """

    def __init__(self, tendon_m_per_count: float, tick_s: float = 5e-3,
                 travel_lag_s: float = FRICTION_MOTOR_TRAVEL_LAG_S):
        """Args:
            tendon_m_per_count: tendon length per encoder count (m; positive = paid out), the
                handshake's :attr:`twin.driver.DeviceInfo.tendon_m_per_count`.
            tick_s: the board's tick (s), the period of the counts a sample carries (the
                firmware's 5 ms IntervalTimer).
            travel_lag_s: time constant (s) of the travel that moves σ: the twin's while its
                motors drive the spools, as the board's do whenever it reports.
        """
        self.tendon_m_per_count = float(tendon_m_per_count)
        self.state: np.ndarray | None = None
        self._lagged_m: np.ndarray | None = None
        # The lag over one tick, as the twin's at 5 ms steps.
        self._blend = tick_s / (travel_lag_s + tick_s)

    def follow(self, samples, *, mean_from_s: float | None = None) -> np.ndarray | None:
        """Advance over telemetry samples (oldest first) and, within each, over the counts of
        every board tick it carries (``encoder_history_counts``, (K, N), oldest first; a sample
        without them, ``encoder_counts``, (N,)): the spool's motion between 40 Hz samples (a
        length controller's settling dither of a few µm) moves σ as the twin's friction sees it.

        Args:
            samples: telemetry samples, oldest first.
            mean_from_s: with a device time (s), :attr:`window_mean` becomes the mean σ over the
                ticks of the samples stamped from then on: what a measurement averaged over that
                window saw. A length controller's dither moves σ by ~0.08 RMS within a 0.25 s
                window (its magnitude by +0.02 on average; endoscope, μ = 0.25, 36 rows).

        Returns:
            σ per tendon (at the last tick), or None before the first sample.
        """
        rows, times = [], []
        for sample in samples:
            ticks = getattr(sample, "encoder_history_counts", None)
            block = np.atleast_2d(np.asarray(sample.encoder_counts if ticks is None else ticks, dtype=float))
            rows.append(block)
            times.append(np.full(len(block), float(getattr(sample, "time_s", np.inf))))
        self.window_mean = None
        if not rows:
            return self.state
        positions_m = np.concatenate(rows) * self.tendon_m_per_count
        if self._lagged_m is None:
            self.state, self._lagged_m = np.zeros(positions_m.shape[1]), positions_m[0].copy()
        # The spool's travel through the friction's lag, tick by tick (a plain loop: few tendons).
        lagged, moves = self._lagged_m.tolist(), []
        for row in positions_m.tolist():
            move = [(x - y) * self._blend for x, y in zip(row, lagged)]
            lagged = [y + m for y, m in zip(lagged, move)]
            moves.append(move)
        self._lagged_m = np.array(lagged)
        pulls = -np.array(moves)
        if mean_from_s is None:
            self.state = slide_path(self.state, pulls)
            return self.state
        inside = np.concatenate(times) >= mean_from_s
        self.state = slide_path(self.state, pulls[~inside])
        history = []
        for pull in pulls[inside]:
            self.state = slide(self.state, pull)
            history.append(self.state)
        self.window_mean = np.mean(history, axis=0) if history else self.state.copy()
        return self.state

    #: σ per tendon averaged over the ticks of the last :meth:`follow` from ``mean_from_s`` on
    #: (None when it was not asked for).
    window_mean: np.ndarray | None = None


class TendonFriction:
    """Capstan friction of the tendons over the disc holes, applied as body forces.

    MuJoCo's tendon carries one tension T₀ along its whole path — the spool's. With friction
    coefficient μ the tension in segment k (spool = 0) is T_k = T₀ exp(−σ μ Σ_{m≤k} θ_m), where
    θ_m is the angle the tendon turns at site m (the base hole and each disc, or each joint
    with continuous routing) and σ ∈ [−1, 1]
    the state of a Dahl model of the sliding direction: σ → +1 while the spool pulls tendon
    in, → −1 while it pays out, over :data:`PRESLIDING_M` of travel, and it holds when the
    tendon stops, so a static state remembers how it was reached. The difference between the
    friction profile and MuJoCo's uniform one is added, for a spatial tendon through the discs,
    at each site as a force along the chords (and its moment about the body's centre of mass)
    through ``xfrc_applied``, the forces including the friction on the disc so that momentum
    balances; for a fixed tendon over the joints (continuous routing) as the fixed tendon's own
    pull on each joint, −(T_k − T₀) ∂ℓ/∂ξ, through ``qfrc_applied`` (``joint_pulls`` in the
    constructor says why). T₀ is the spool's tension, at most
    ``tension_cap_n`` (:data:`FRICTION_TENSION_CAP_LIMITS`) and, on an ideal tension source, at
    most the source's setting, through a first-order lag of
    :data:`FRICTION_TENSION_LAG_S`, and σ follows the spool's travel through one of
    :data:`FRICTION_TRAVEL_LAG_S` on an ideal source, of :data:`FRICTION_MOTOR_TRAVEL_LAG_S`
    while the motor drives it. σ turns over at least :data:`PRESLIDING_M` and the stretch the
    tendon takes the friction's swing up over; on the plant's ideal tension sources (not the
    fixture's dead weights, whose board-driven runs stay as they were), which nothing holds,
    also a share (the physics step over that lag) of the spool travel the rod's compliance gives
    the swing (millimetres on the long robot bent at μ = 0.6): over less, each turn's own travel
    turned σ back further than it came and the twin chattered instead of coming to rest.

    A :class:`twin.effects.StepHook` that the plant loop (``twin/sim/native/loop.cpp``,
    ``tendon_friction``) applies itself before every physics step: :meth:`attach` hands it the
    paths, μ and the constants; this class finds the paths and reads the state back.
    """

    max_step_s = FRICTION_MAX_STEP_S

    def __init__(self, model, coeff: float, spool_dofs: np.ndarray, sites: np.ndarray, passed=None,
                 turn_beyond: float = 0.0, tension_cap_n: float = math.inf, joint_pulls=None):
        """Args:
            model: the compiled twin (``mujoco.MjModel``).
            coeff: μ per radian of wrap.
            tension_cap_n: the highest spool tension the friction follows (N; default none):
                :data:`FRICTION_TENSION_CAP_LIMITS` times the rig's tension limit in a twin.
            spool_dofs: (n,) dof index of each spool.
            sites: (n, S) site ids along each tendon's path, spool first, tip last.
            passed: (n,) how many of its S sites each tendon passes up to its anchor (default all):
                a tendon of a proximal segment ends before the tip, and the sites beyond its
                anchor carry none of its friction.
            turn_beyond: share (0 … 1) of the turn at a site whose tension loss the segment
                after it does not carry yet (the next one does): 0 where the tendon turns at the
                site itself (a disc's hole: the rest of the path beyond it is past the capstan),
                ½ where a site stands for a bend spread over half an element on either side (a
                joint's plane, continuous routing): there the tension at the joint is the one
                half-way round its turn, as in the predictor's continuous wrap. Carrying the whole
                turn's loss at the joint put the loss half an element early and made the friction's
                effect on the tip larger than the predictor's by ~1.5/N (9 % at N = 10 elements,
                5 % at N = 20, 16 % at N = 5; endoscope, μ = 0.3, κ = 26.2 1/m).
            joint_pulls: for fixed tendons over the joints (continuous routing), a pair of
                (n, S, 6) arrays, the dof index (−1: none) and the tendon's length coefficient
                ∂ℓ/∂ξ on it (:func:`_joint_pulls`), of the joints in the plane of each site. The
                friction then pulls those joints through the fixed tendon's own coefficients, with
                the tension lost up to half the joint's turn, as the predictor's moment τ(s) r × t
                at the joint: a force along the chord to the next site, which a bend of Δθ at the
                joint tilts from the plane's normal, reaches the arm r·cos Δθ only (1 % of the
                friction's effect on the endoscope at N = 10, κ = 20 1/m). And a site's turn is
                then its joint's rotation across the tendon, |φ × t|, the predictor's wrap
                ∫|u × t| ds over the joint; not the angle between the chords through the sites,
                which a twist hinge tilts by r·φ/h without bending the tendon (with G·J torsion
                and a 10 g tip that counted 4 % more wrap than the predictor on a 100 mm rod) and
                a helix turns even on a straight rod (1.8 times the predictor's friction on the
                helical robot). None: forces along the
                chords through the sites, turning at each by the angle between them (a line
                running straight between discs, as the rig's).
        """
        self.coeff = float(coeff)
        if not 0.0 <= turn_beyond <= 1.0:
            raise ValueError(f"turn_beyond = {turn_beyond!r}: must be within 0 … 1")
        self.turn_beyond = float(turn_beyond)
        self.tension_cap_n = float(tension_cap_n)
        self.joint_turns = joint_pulls is not None
        if joint_pulls is not None:
            self._joint_dofs = np.ascontiguousarray(joint_pulls[0], dtype=np.int32)
            self._joint_coefficients = np.ascontiguousarray(joint_pulls[1], dtype=np.float64)
        sites = np.array(sites)
        if passed is not None:
            # The sites beyond a tendon's anchor repeat the anchor, so that the paths stay
            # rectangular: the plant loop ends a path at its first zero-length segment.
            last = np.asarray(passed, dtype=int) - 1
            beyond = np.arange(sites.shape[1])[None, :] > last[:, None]
            sites[beyond] = np.broadcast_to(sites[np.arange(len(sites)), last][:, None], sites.shape)[beyond]
        self._sites = sites
        self._spool_dofs = np.asarray(spool_dofs)
        self._loop_sites = np.ascontiguousarray(self._sites, dtype=np.int32)
        self._loop_state = None

    @classmethod
    def in_model(cls, model, coeff: float, tendons: int, passed=None, tension_cap_n: float = math.inf) -> "TendonFriction":
        """The friction of the ``tendons`` tendons of a twin built by :mod:`twin.sim.model`,
        found by the names it gives them: spool joint and site ``spool{i}``, base hole
        ``hole{i}``, then sites ``t{i}_s1`` … towards the tip; ``passed`` (n,) the number of
        ``t{i}_s…`` sites up to each tendon's anchor (default all); ``tension_cap_n`` as in the
        constructor."""
        names = {model.site(k).name for k in range(model.nsite)}
        along = 0
        while f"t0_s{along + 1}" in names:
            along += 1
        sites = [[model.site(f"spool{i}").id, model.site(f"hole{i}").id]
                 + [model.site(f"t{i}_s{j}").id for j in range(1, along + 1)] for i in range(tendons)]
        dofs = [model.jnt_dofadr[model.joint(f"spool{i}").id] for i in range(tendons)]
        # A fixed tendon (continuous routing: it wraps the joints, its sites only trace the path)
        # bends at the joints' planes, where its sites are; a spatial one turns at its sites.
        fixed = _wraps_joints(model)
        return cls(model, coeff, np.array(dofs), np.array(sites), None if passed is None else np.asarray(passed) + 2,
                   turn_beyond=0.5 if fixed else 0.0, tension_cap_n=tension_cap_n,
                   joint_pulls=_joint_pulls(model, np.array(sites)) if fixed else None)

    def attach(self, state) -> None:
        """Have the plant loop whose state (:class:`twin.sim.native_loop.LoopState`) is ``state``
        apply this friction before every physics step. The loop reads the paths from this
        object's buffer, which lives as long as it does; its spool dofs must be the loop's."""
        if list(self._spool_dofs) != list(state.spool_dof[:len(self._spool_dofs)]):
            raise ValueError(f"spool dofs {self._spool_dofs.tolist()}: not the plant loop's spools")
        self._loop_state = state
        state.friction_sites = self._loop_sites.ctypes.data
        state.friction_sites_per_tendon = self._loop_sites.shape[1]
        state.presliding_m = PRESLIDING_M
        state.friction_lag_s = FRICTION_TENSION_LAG_S
        state.friction_travel_lag_s = FRICTION_TRAVEL_LAG_S
        state.friction_motor_travel_lag_s = FRICTION_MOTOR_TRAVEL_LAG_S
        state.friction_coeff = self.coeff
        state.friction_turn_beyond = self.turn_beyond
        state.friction_joint_turns = int(self.joint_turns)
        if self.joint_turns:
            state.friction_joint_dofs = self._joint_dofs.ctypes.data
            state.friction_joint_coefficients = self._joint_coefficients.ctypes.data
        state.friction_tension_cap_n = self.tension_cap_n
        state.friction_jump_n = FRICTION_JUMP_N

    @property
    def state(self) -> np.ndarray:
        """Each tendon's sliding state σ (−1 … +1) as the loop left it (zeros before attaching)."""
        n = len(self._spool_dofs)
        return np.zeros(n) if self._loop_state is None else np.array(self._loop_state.sliding_state[:n])

    def reset(self) -> None:
        """The loop's reset (``bl_plant_reset``) zeroes σ and the lagged tension."""

    def before_step(self, model, data, spool_tensions_n: np.ndarray) -> None:
        raise RuntimeError("tendon friction runs inside the plant loop: attach it (TendonFriction.attach)")


def friction_direction(relative_lengths_m, sense: float = 1.0, sliding_state=None) -> np.ndarray:
    """Sliding state per tendon (+1 tension lost towards the tip … −1 gained) of a static state.

    With ``sliding_state`` (the σ a dataset recorded, :class:`SlidingState`) that one, times
    ``sense``. Without (an older dataset), a guess for a state reached from the pretensioned
    straight pose: +1 for a tendon pulled in (shortened) to get there, −1 for one paid out — times
    ``sense`` (``effects.tendon_friction_direction``), −1 when a length controller settled by
    backing off past the presliding travel, which flips every tendon's last motion."""
    if sliding_state is not None and np.isfinite(sliding_state).all():
        return sense * np.clip(np.asarray(sliding_state, dtype=float), -1.0, 1.0)
    lengths = np.asarray(relative_lengths_m, dtype=float)
    return sense * np.where(lengths > 0, -1.0, 1.0)


def _wraps_joints(model) -> bool:
    """Whether the twin's tendons are fixed tendons over the joints (continuous routing), whose
    sites only trace the path, rather than spatial ones through their sites."""
    import mujoco

    return int(model.wrap_type[model.tendon_adr[model.tendon("tendon0").id]]) == int(mujoco.mjtWrap.mjWRAP_JOINT)


def _joint_pulls(model, sites: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The joints each fixed tendon pulls, by the site in whose plane they lie: (n, S, 6) dof
    indices (−1: none) and (n, S, 6) the tendon's length coefficients on them, for the paths
    ``sites`` (n, S) of :meth:`TendonFriction.in_model` (spool, hole, then ``t{i}_s{k}`` in joint
    k's plane). Station k's joints are named ``b{k}_…`` (:mod:`twin.sim.model`); a joint that
    lumps the compliance of a block of elements (a slide, a twist hinge) is pulled with its
    station's tension, the block's middle."""
    import mujoco

    n, count = sites.shape
    dofs = np.full((n, count, 6), -1, dtype=np.int32)
    coefficients = np.zeros((n, count, 6))
    for i in range(n):
        tendon = model.tendon(f"tendon{i}").id
        used = np.zeros(count, dtype=int)
        for w in range(model.tendon_adr[tendon], model.tendon_adr[tendon] + model.tendon_num[tendon]):
            if int(model.wrap_type[w]) != int(mujoco.mjtWrap.mjWRAP_JOINT):
                continue
            joint = int(model.wrap_objid[w])
            name = model.joint(joint).name
            if not (name.startswith("b") and "_" in name):
                continue  # the spool
            k = int(name[1:name.index("_")]) + 1  # path: spool, hole, then t{i}_s1 at joint 1's plane
            dofs[i, k, used[k]] = model.jnt_dofadr[joint]
            coefficients[i, k, used[k]] = model.wrap_prm[w]
            used[k] += 1
    return dofs, coefficients


def _sites_to_anchor(model, params: Params) -> np.ndarray:
    """(n,) how many of the sites ``t{i}_s1`` … each tendon's friction path runs through up to its
    anchor (:meth:`Params.tendon_ends_m`), by their arc length along the clamp's axis in the
    straight pose (``qpos0``).

    A spatial tendon ends at the site of its anchor's disc: the sites not beyond the anchor. A
    fixed one (continuous routing) pulls every joint whose plane lies before its anchor, and its
    sites stand in those planes, each on the body before the joint: the path runs on to the next
    site, on the anchor's body, as a tendon to the tip runs on to the tip, so that the segment
    across the last joint it pulls carries that joint's friction loss. Ended at the last plane,
    that joint kept the spool's tension (two-segment, μ = 0.3, κ 15 1/m: the tip 0.7 mm from the
    predictor)."""
    import mujoco

    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    names = {model.site(k).name for k in range(model.nsite)}
    along = sum(1 for j in range(1, model.nsite + 1) if f"t0_s{j}" in names)
    fixed = _wraps_joints(model)
    passed = []
    for i, end_m in enumerate(params.tendon_ends_m()):
        hole = model.site(f"hole{i}").id
        axis = data.xmat[model.site_bodyid[hole]].reshape(3, 3)[:, 2]
        s_m = [(data.site_xpos[model.site(f"t{i}_s{j}").id] - data.site_xpos[hole]) @ axis for j in range(1, along + 1)]
        if fixed:
            # The joints pulled are those of elements centred before the anchor (twin.sim.model.TendonLength).
            passed.append(min(along, int(np.count_nonzero(np.asarray(s_m) < end_m - 1e-7)) + 1))
        else:
            passed.append(int(np.count_nonzero(np.asarray(s_m) <= end_m + 1e-7)))
    return np.array(passed)


class TendonFrictionEffect(Effect):
    name = "tendon_friction"
    description = ("capstan friction at the disc holes: tension lost towards the tip while pulled, "
                   "gained while released")
    deciding_experiments = ("reapproach",)
    parameters = (Key("tendon_friction_coeff", nonnegative=True),
                  Key("tendon_friction_direction", off=1.0, choices=(1.0, -1.0)))

    def body_spec(self, params: Params, spec: BodySpec) -> BodySpec:
        return dataclasses.replace(spec, friction_coeff=params.effects.tendon_friction_coeff)

    def step_hook(self, params: Params, model) -> TendonFriction | None:
        coeff = params.effects.tendon_friction_coeff
        if not coeff > 0:
            return None
        passed = None
        if min(params.tendon_ends_m()) < params.backbone.length_m:
            passed = _sites_to_anchor(model, params)
        return TendonFriction.in_model(model, coeff, params.tendons.count, passed,
                                       tension_cap_n=FRICTION_TENSION_CAP_LIMITS * params.rig.tension_limit_n)

    def candidate(self, params: Params) -> Candidate:
        coeff = FitParameter("effects.tendon_friction_coeff", log=True, bounds=(1e-3, 1.0))
        return Candidate(self.name, (coeff,), start={coeff.label: _FIT_START},
                         variants=({"effects.tendon_friction_direction": 1.0},
                                   {"effects.tendon_friction_direction": -1.0}))

    def dynamic_candidate(self, params: Params) -> FitParameter | None:
        return FitParameter("effects.tendon_friction_coeff", log=True, scale=0.05, bounds=(1e-3, 1.0))


EFFECT = TendonFrictionEffect()
