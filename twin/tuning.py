"""Controller tuning against the env, worked as an example: the board's tension PID, then a
model-based tip-tracking controller on top of it.

1. **Tension PID** (the firmware's tension mode; gains per :meth:`twin.driver.Device.set_gains`).
   A rollout asks for a fixed sequence of tension steps on an antagonistic pair and hangs a tip
   mass half-way; the cost is the RMS tension tracking error (N), plus a penalty if the board
   faults. Nelder–Mead on (log kp, log ki, log duty clamp) from the firmware's defaults.
2. **Tip tracking** (:class:`TipTrackingController`): feedforward tensions from the predictor for the known
   tip load (:func:`twin.control.compensation.compensate_tensions`), then an integral correction
   through the predictor's Jacobian, τ ← τ + g·J⁺(p* − p), and swing damping, −k_v·J⁺ṗ. The
   cost is the mean tip error (mm) over episodes with random targets and loads on twins that
   differ from the model as a rig does (``Randomization.typical()``); Nelder–Mead tunes g, k_v
   and the tension PID's integral gain ki together, from the feedforward alone. ki is tuned
   again here because the step rollout rewards a slow integral (its largest steps are partly
   out of reach, and a fast integral winds up on them) while the tracker needs the tensions it
   asks for: on stage 1's ki of ~0.03–0.05 the tuned tracker missed by 1.9–2.2 mm, with ki
   tuned alongside by 0.6–0.7 mm. Episodes are independent and seed themselves, so they run
   in parallel processes (``workers``) or on a Ray cluster (``cluster``) with the same result
   (:func:`twin.scaleout.map_ordered`).

``python -m twin.tuning`` (or ``twin tune``) runs both and prints the metrics before and
after. The tuning drives the env, so it sits above both :mod:`envs` and :mod:`twin.control`; the
controllers take its result from :mod:`twin.control.gains`.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import Sequence

import numpy as np

from twin.cliargs import add_param_args, params_from_args
from twin.control.gains import DEFAULT_TENSION_GAINS, TUNED_TENSION_GAINS
from twin.params import Params, load_params
from twin.rod.grid import GRAVITY_TIP_FORCE_N
from twin.scaleout import Executor, connect, map_ordered

# The env (gymnasium, MuJoCo), SciPy and the predictor's kernels are imported where they are
# used: `twin tune --help` builds this module's parser without loading them.

__all__ = ["TipTrackingController", "TuningResult", "tension_cost", "tension_steps_n", "tracking_cost", "tune_tension_gains", "tune_tracking_gains",
           "main", "register"]

# Cost of a rollout the board faulted in (N RMS or mm): above any error a working loop has.
_FAULT_COST = 10.0
# Tension steps of the PID rollout on an antagonistic pair (a, b), as factors on the pretension,
# every other tendon held at it; 0.5 s each. On the thesis endoscope (1.35 N) they are steps of
# 1.35 N … 3.5 N on tendons 1 and 3.
_PAIR_STEPS = ((1.0, 1.0), (1.85, 0.74), (0.74, 1.85), (2.59, 0.44), (1.0, 1.0), (0.44, 2.22))
_STEPS_PER_SETPOINT = 20


def tension_steps_n(params: Params, tension_range_n: tuple[float, float] | None = None) -> np.ndarray:
    """The PID rollout's setpoints (steps, tendons) (N) for ``params``'s robot: :data:`_PAIR_STEPS`
    on its antagonistic pair (:func:`twin.control.cocontraction.antagonistic_pair`), within
    ``tension_range_n`` (default the env's for the robot)."""
    from twin.envs.reach import default_tension_range_n
    from twin.control.cocontraction import antagonistic_pair

    a, b = antagonistic_pair(params)
    low, high = tension_range_n or default_tension_range_n(params)
    pretension = params.tendons.pretension_n
    steps = np.full((len(_PAIR_STEPS), params.tendons.count), pretension)
    steps[:, a], steps[:, b] = np.array(_PAIR_STEPS).T * pretension
    return np.clip(steps, low, high)


@dataclasses.dataclass(frozen=True)
class TuningResult:
    """Before and after of one tuning: the parameters and the cost (lower is better)."""

    name: str
    before: dict
    after: dict
    cost_before: float
    cost_after: float
    unit: str
    evaluations: int

    def line(self) -> str:
        return (f"{self.name}: {self.cost_before:.4g} → {self.cost_after:.4g} {self.unit} "
                f"({self.evaluations} rollouts); {self.before} → {self.after}")


def tension_cost(gains: dict, *, params: Params | None = None, seed: int = 0) -> float:
    """RMS tension tracking error (N) of the tension-step rollout with these board gains.

    The first 5 samples after each step are left out: no loop follows a step in 25 ms, and the
    metric should reward settling, not the size of the steps.
    """
    from twin.envs.randomization import TipLoads
    from twin.envs.reach import EndoscopeReachEnv
    env = EndoscopeReachEnv(params=params, gains={"tensions": gains}, tip_loads=TipLoads.none())
    try:
        env.reset(seed=seed)
        errors = []
        steps = tension_steps_n(env.params, env.tension_range_n)
        for k, setpoint in enumerate(steps):
            if k == len(steps) // 2:
                env.device.fixture.hang_tip_mass(0.010)
            action = env.action_for(setpoint)
            for i in range(_STEPS_PER_SETPOINT):
                _, _, faulted, _, info = env.step(action)
                if faulted:
                    return _FAULT_COST
                if i >= 5:
                    errors.append(info["tensions_n"] - np.asarray(setpoint))
        return float(np.sqrt(np.mean(np.square(errors))))
    finally:
        env.close()


def tune_tension_gains(*, params: Params | None = None, start: dict | None = None, evaluations: int = 30,
                       seed: int = 0) -> TuningResult:
    """Nelder–Mead on (log kp, log ki, log output_limit) of the tension PID, kd = 0."""
    from scipy.optimize import minimize
    start = dict(start or DEFAULT_TENSION_GAINS)
    x0 = np.log([start["kp"], start["ki"], start["output_limit"]])

    def gains_of(x):
        return {"kp": float(np.exp(x[0])), "ki": float(np.exp(x[1])), "kd": 0.0,
                "output_limit": float(min(1.0, np.exp(x[2])))}

    cost_before = tension_cost(gains_of(x0), params=params, seed=seed)
    fit = minimize(lambda x: tension_cost(gains_of(x), params=params, seed=seed), x0, method="Nelder-Mead",
                   # Steps of e^-1.7 (÷5.5): the firmware's defaults sit on a plateau of faulting
                   # rollouts, and a simplex that does not reach past it never leaves it.
                   options={"maxfev": evaluations, "initial_simplex": x0 + np.vstack([np.zeros(3), -1.7 * np.eye(3)])})
    return TuningResult("tension PID", gains_of(x0), gains_of(fit.x), cost_before, float(fit.fun), "N RMS",
                        int(fit.nfev) + 1)


class TipTrackingController:
    """Feedforward, Jacobian integral control and swing damping of the tip, on tension actions.

    At reset the predictor's tensions for the target under the known tip load are the
    feedforward. Each step then moves the tensions by ``gain`` · J⁺ (p* − p) (integral action,
    J = ∂p/∂τ at the current tensions: one predictor solve and Jacobian per step, warm-started)
    and, on top of that, subtracts ``velocity_gain_s`` · J⁺ v, v the tip velocity from the last two
    tracker readings (damping, not accumulated). J⁺ is damped by ``damping`` (m/N) so that a
    near-singular J cannot command a jump.

    The damping is what lets the integral work on the twin: in tension mode the loaded tip is a
    lightly damped pendulum (about 1.7 Hz, damping ratio ~0.06), and an integral acting on the
    swinging reading feeds the swing (``twin tune``).

    Args:
        params: the predictor's parameter set.
        gain: integral gain per step (0 = feedforward only).
        velocity_gain_s: swing damping (s): tension change per unit of J⁺ v (0 = none).
        period_s: time between two :meth:`update` calls (s): the env's 40 Hz step.
        damping: Tikhonov damping of the pseudo-inverse (m/N).
        floor_n, limit_n: tension bounds (N); default the robot's: the lower end of the env's
            tension range raised to 1 N where it allows (taut tendons), and its upper end
            (:func:`twin.envs.reach.default_tension_range_n`: 1 N and 5 N on the thesis endoscope).
        base_rotation: the clamp orientation (3×3) of the robot it controls; default the
            parameter set's ``rig.base_quat`` (give the device's :attr:`~twin.driver.Device.base_rotation`).
    """

    def __init__(self, params: Params, *, gain: float = 0.05, velocity_gain_s: float = 0.0,
                 period_s: float = 0.025, damping: float = 2e-3, floor_n: float | None = None,
                 limit_n: float | None = None, base_rotation=None):
        from twin.envs.reach import default_tension_range_n
        from twin.rod import Predictor, RodModel
        if not (gain >= 0 and velocity_gain_s >= 0 and period_s > 0):
            raise ValueError(f"gain = {gain!r}, velocity_gain_s = {velocity_gain_s!r}, period_s = {period_s!r}: "
                             "gains must be >= 0 and the period > 0")
        self.model = RodModel.from_params(params)
        self.base_rotation = params.rig.base_rotation if base_rotation is None else np.asarray(base_rotation, float)
        self.gravity_m_s2 = params.environment.gravity_m_s2
        self.gain, self.velocity_gain_s, self.period_s = gain, velocity_gain_s, period_s
        low, high = default_tension_range_n(params)
        floor_n = min(1.0, 0.5 * (low + high)) if floor_n is None else floor_n
        limit_n = high if limit_n is None else limit_n
        self.damping, self.floor_n, self.limit_n = damping, floor_n, limit_n
        self.tensions_n = np.zeros(self.model.tendon_count)
        self._predictor = Predictor(self.model)
        self._pinv: np.ndarray | None = None
        self._previous_tip_m: np.ndarray | None = None

    def reset(self, target_m, tip_mass_kg: float) -> np.ndarray:
        """Feedforward tensions (N) for ``target_m`` under ``tip_mass_kg``."""
        from twin.control.compensation import compensate_tensions
        force = GRAVITY_TIP_FORCE_N(tip_mass_kg, self.gravity_m_s2)
        plan = compensate_tensions(self.model, target_m, tip_force_n=force, base_rotation=self.base_rotation,
                                   floor_n=self.floor_n, limit_n=self.limit_n)
        self.target_m, self.force_n = np.asarray(target_m, dtype=float), force
        self.tensions_n = plan.tensions_n
        self._predictor.reset()
        self._pinv, self._previous_tip_m = None, None
        return self.tensions_n.copy()

    def update(self, tip_m) -> np.ndarray:
        """Next tensions (N) from the measured tip position (m)."""
        from twin.rod import tip_jacobian
        tip = np.asarray(tip_m, dtype=float)
        if self.gain > 0 or (self.velocity_gain_s > 0 and self._pinv is None):
            # The integral needs J where the tensions are now; the damping alone makes do with J
            # at the feedforward.
            sol = self._predictor.solve(self.tensions_n, tip_force_n=self.force_n, base_rotation=self.base_rotation)
            j = tip_jacobian(self.model, sol).position_wrt_tension
            self._pinv = j.T @ np.linalg.inv(j @ j.T + self.damping ** 2 * np.eye(3))
        if self.gain > 0:
            self.tensions_n = np.clip(self.tensions_n + self.gain * (self._pinv @ (self.target_m - tip)),
                                      self.floor_n, self.limit_n)
        out = self.tensions_n
        if self.velocity_gain_s > 0 and self._previous_tip_m is not None:
            velocity = (tip - self._previous_tip_m) / self.period_s
            out = np.clip(out - self.velocity_gain_s * (self._pinv @ velocity), self.floor_n, self.limit_n)
        self._previous_tip_m = tip
        return out.copy()


# Tracking episodes run on twins that differ from the controller's model as a rig would
# (Randomization.typical(): stiffness, weight, load-cell errors, tracker noise, 0-2 steps of
# latency), with the tip load hung from the start; long enough (4 s) for the swing to matter.
TRACKING_STEPS = 160


def _tracking_episode(args) -> float:
    from twin.envs.randomization import Randomization, TipLoads
    from twin.envs.reach import EndoscopeReachEnv
    gains, params, seed, steps, tension_gains = args
    env = EndoscopeReachEnv(params=params, gains={"tensions": tension_gains},
                            tip_loads=TipLoads(change_probability=0.0), randomization=Randomization.typical())
    try:
        observation, info = env.reset(seed=seed)
        controller = TipTrackingController(params if params is not None else load_params(), **gains,
                                           base_rotation=env.device.base_rotation)
        action = env.action_for(controller.reset(env.target_m, info["tip_mass_kg"]))
        errors = []
        for _ in range(steps):
            observation, _, faulted, _, info = env.step(action)
            if faulted:
                return _FAULT_COST
            errors.append(info["tip_error_m"] * 1e3)
            action = env.action_for(controller.update(observation[env.tip_slice]))
        # The second half: how well the target is held once reached.
        return float(np.mean(errors[steps // 2:]))
    finally:
        env.close()


def tracking_cost(gains: dict, *, params: Params | None = None, seeds: Sequence[int] = (0, 1, 2),
                  steps: int = TRACKING_STEPS, tension_gains: dict | None = None, workers: int = 1,
                  cluster: str | None = None, executor: Executor | None = None) -> float:
    """Mean tip error (mm) over the second half of episodes with the :class:`TipTrackingController` gains
    ``gains`` (``gain``, ``velocity_gain_s``), one episode per seed in ``seeds``, run by ``executor``
    or else by :func:`twin.scaleout.map_ordered` (``workers`` local processes, or the Ray ``cluster``)."""
    jobs = [(gains, params, seed, steps, tension_gains or TUNED_TENSION_GAINS) for seed in seeds]
    if executor is not None:
        return float(np.mean(executor.map(_tracking_episode, jobs)))
    return float(np.mean(map_ordered(_tracking_episode, jobs, workers=workers, cluster=cluster)))


def tune_tracking_gains(*, params: Params | None = None, start: dict | None = None, evaluations: int = 20,
                        tension_gains: dict | None = None, **options) -> TuningResult:
    """Nelder–Mead on (log gain, log velocity_gain_s) of :class:`TipTrackingController` and the log of the
    tension PID's ``ki`` (the rest of ``tension_gains`` held), from ``start``; the baseline is
    feedforward alone (both tracker gains 0) on ``tension_gains``, and is returned as ``after``
    when nothing found beats it. ``options`` go to :func:`tracking_cost`; its ``workers`` and
    ``cluster`` serve every evaluation from one :class:`twin.scaleout.Executor`.

    Returns:
        A :class:`TuningResult` whose parameters are ``gain``, ``velocity_gain_s`` and
        ``tension_ki``.
    """
    from scipy.optimize import minimize
    tension_gains = dict(tension_gains or TUNED_TENSION_GAINS)
    start = {"gain": 0.01, "velocity_gain_s": 0.05, "tension_ki": tension_gains["ki"], **(start or {})}
    baseline = {"gain": 0.0, "velocity_gain_s": 0.0, "tension_ki": tension_gains["ki"]}

    def values_of(x):
        return {"gain": float(np.exp(x[0])), "velocity_gain_s": float(np.exp(x[1])), "tension_ki": float(np.exp(x[2]))}

    x0 = np.log([start["gain"], start["velocity_gain_s"], start["tension_ki"]])
    with Executor(options.pop("workers", 1), options.pop("cluster", None)) as executor:
        def cost(values: dict) -> float:
            return tracking_cost({"gain": values["gain"], "velocity_gain_s": values["velocity_gain_s"]},
                                 params=params, tension_gains=dict(tension_gains, ki=values["tension_ki"]),
                                 executor=executor, **options)

        cost_before = cost(baseline)
        fit = minimize(lambda x: cost(values_of(x)), x0, method="Nelder-Mead",
                       # Steps of e (×2.7) so that a few evaluations span the useful decade of each gain.
                       options={"maxfev": evaluations, "initial_simplex": x0 + np.vstack([np.zeros(3), np.eye(3)])})
    best = (values_of(fit.x), float(fit.fun)) if fit.fun < cost_before else (baseline, cost_before)
    return TuningResult("tip tracking (integral gain, swing damping, tension ki)", baseline, best[0], cost_before,
                        best[1], "mm", int(fit.nfev) + 1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m twin.tuning", description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="few rollouts (a minute): the worked example")
    parser.add_argument("--workers", type=int, default=2, help="processes for the tracking episodes")
    parser.add_argument("--cluster", default=None, metavar="ADDRESS",
                        help="run the tracking episodes on the Ray cluster whose head is at ADDRESS (HOST:PORT, "
                             "'auto' for the one running here, 'local' for a new one of --workers CPUs); "
                             "needs pip install 'twin[cluster]'")


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``twin tune`` to the ``twin`` command's subparsers."""
    p = sub.add_parser("tune", help="tune the tension PID, then the tip tracker's gains with the tension integral, "
                                    "on env rollouts")
    add_arguments(p)
    add_param_args(p)
    p.set_defaults(func=lambda args: run(args, params_from_args(args)))


def run(args: argparse.Namespace, params: Params | None = None) -> int:
    quick = args.quick
    if args.cluster is not None:
        # A cluster that is not there is said before the minutes of the PID stage, not after.
        connect(args.cluster, args.workers)
    pid = tune_tension_gains(params=params, evaluations=12 if quick else 40)
    print(pid.line())
    tracking = tune_tracking_gains(params=params, tension_gains=pid.after, evaluations=12 if quick else 35,
                                   seeds=(0, 1) if quick else (0, 1, 2, 3), workers=args.workers,
                                   cluster=args.cluster)
    print(tracking.line())
    return 0


if __name__ == "__main__":
    sys.exit(main())
