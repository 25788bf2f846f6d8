"""Model-based load compensation: tendon tensions that keep the tip on target under known loads.

The Cosserat predictor gives the tip position p(τ, F) for tensions τ and a tip force F, and its
Jacobian ∂p/∂τ (:func:`twin.rod.tip_jacobian`). Holding the tip at p* under a known load is then
a bounded nonlinear least-squares problem in the tensions,

    min_τ  ‖(p(τ, F) − p*) / s‖² + λ² ‖τ − τ_ref‖²     subject to  τ_floor ≤ τ ≤ τ_max,

solved by SciPy's trust-region reflective Gauss–Newton with the predictor's Jacobian. Four
tensions for three coordinates leave one direction free (all tendons pulling together barely
moves the tip); the small pull λ towards τ_ref — the tensions in use before the load — picks
the change with the least co-contraction. The floor keeps every tendon taut (a slack tendon
stops being controlled) and the ceiling stays under the board's tension limit.

:func:`hold_tensions` is the form the rig uses: the target is where the tip *is* (known by the
tensions it was put there with), so a model error common to the loaded and unloaded shapes
cancels and only the load's effect is compensated.

:func:`correct_tensions` closes the loop once the tip can be measured: the tracker's miss at the
applied tensions, against the predictor's own miss there, is the model's error; it is taken as
locally constant and the predictor re-aimed by it (one bounded solve per correction).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import least_squares

from twin.checks import finite_vector
from twin.rod import RodModel, solve, solve_batch, tip_jacobian

__all__ = ["Compensation", "compensate_tensions", "correct_tensions", "hold_tensions", "unloaded_tips",
           "response_gain", "MIN_RESPONSE_GAIN", "GAIN_RESOLVE_SIGMAS"]

# Position residuals are scaled to mm so that they and the tension pull (per N) are of one size.
_POSITION_SCALE_M = 1e-3

# The smallest share of a predicted tip move :func:`response_gain` reports: a correction re-aims
# by at most twice the model error, so a device that makes any share γ in (0, 1] of each move
# still ends every step closer (the miss left is |1 − γ/g| of it, under 1 for g >= 0.5). The
# two-segment robot under a hidden tendon friction of 0.3 made 0.14-0.42 of each predicted move
# (eight corrections at κ 17.5 φ 180 and κ 26.2 φ 270, ``sim://?seed=0``), more of a big move
# than of a small one, so a small move's share taken for a big one's overshoots: a lower floor
# would let it overshoot by more than the miss.
MIN_RESPONSE_GAIN = 0.5
# How many noise levels a predicted move must span for its measured share to be estimated, and a
# miss for a correction to be taken over that share: within a few standard errors of the
# tracker's means a move says nothing about the share, and a miss taken over it would double
# the noise the next step chases. 4: chosen, twice the two standard errors the compensation
# trial tells two misses apart by.
GAIN_RESOLVE_SIGMAS = 4.0


@dataclasses.dataclass(frozen=True)
class Compensation:
    """Tensions that hold the tip on target under a load, and how well the model says they do.

    Attributes:
        tensions_n: (nt,) tendon tensions (N), within the bounds.
        target_m: (3,) the target tip position, world frame (m).
        predicted_tip_m: (3,) the predictor's tip under the load at ``tensions_n`` (m).
        residual_m: |predicted_tip_m − target_m| (m).
        reached: True when the residual is within the tolerance; False when the bounds (or the
            model) left the target out of reach — the tensions are then the nearest the bounds allow.
        at_bounds: (nt,) bool, tendons held at the floor or the ceiling.
        evaluations: predictor solves spent.
        status: SciPy's termination message.
    """

    tensions_n: np.ndarray
    target_m: np.ndarray
    predicted_tip_m: np.ndarray
    residual_m: float
    reached: bool
    at_bounds: np.ndarray
    evaluations: int
    status: str


def compensate_tensions(model: RodModel, target_m, *, tip_force_n=None, tip_moment_nm=None, base_rotation=None,
                        reference_tensions_n=None, floor_n: float = 0.3, limit_n: float = 5.0,
                        regularisation: float = 0.03, tolerance_m: float = 1e-4,
                        friction_direction=None) -> Compensation:
    """Tendon tensions that put the predicted tip at ``target_m`` under the given tip load.

    Args:
        model: the predictor's rod.
        target_m: (3,) target tip position, world frame (m).
        tip_force_n, tip_moment_nm: (3,) known external tip force (N) and moment (N·m), world frame.
        base_rotation: clamp orientation (3×3, body → world); default identity.
        reference_tensions_n: (nt,) tensions the solution is pulled towards and started from
            (N); default the floor plus half a newton.
        floor_n: lowest tension of any tendon (N): keeps all tendons taut.
        limit_n: highest tension (N): keep it under the board's tension limit.
        regularisation: λ, weight of ‖τ − τ_ref‖ (per N) against the tip error (per mm).
        tolerance_m: residual up to which the target counts as reached (m).
        friction_direction: (nt,) each tendon's friction sliding state σ (+1 pulled … −1 paid
            out, :class:`twin.effects.SlidingState`) for a model with tendon friction; default +1.

    Returns:
        The :class:`Compensation`.

    Raises:
        ValueError: bounds not 0 <= floor < limit, or a malformed vector (names the value).
        ConvergenceError: the predictor fails at the starting tensions.
    """
    if not 0 <= floor_n < limit_n:
        raise ValueError(f"floor_n = {floor_n!r}, limit_n = {limit_n!r}: need 0 <= floor_n < limit_n")
    nt = model.tendon_count
    target = finite_vector("target_m", target_m, 3)
    reference = np.full(nt, floor_n + 0.5) if reference_tensions_n is None else finite_vector(
        "reference_tensions_n", reference_tensions_n, nt)
    loads = dict(tip_force_n=tip_force_n, tip_moment_nm=tip_moment_nm, base_rotation=base_rotation,
                 friction_direction=friction_direction)
    # The last converged base moment and shooting Jacobian: every solve after the first starts
    # warm, with Broyden updates of that Jacobian instead of finite differences.
    guess: list[np.ndarray | None] = [None, None]

    def shape(tensions):
        sol = solve(model, tensions, guess_nm=guess[0], guess_jacobian=guess[1], **loads)
        guess[:] = [sol.base_moment_nm, sol.shooting_jacobian]
        return sol

    cache: dict[bytes, tuple] = {}

    def evaluate(tensions):
        key = tensions.tobytes()
        if key not in cache:
            sol = shape(tensions)
            cache.clear()
            cache[key] = (sol, tip_jacobian(model, sol).position_wrt_tension)
        return cache[key]

    def residual(tensions):
        sol, _ = evaluate(tensions)
        return np.concatenate([(sol.tip_position_m - target) / _POSITION_SCALE_M,
                               regularisation * (tensions - reference)])

    def jacobian(tensions):
        _, d_tip = evaluate(tensions)
        return np.vstack([d_tip / _POSITION_SCALE_M, regularisation * np.eye(nt)])

    start = np.clip(reference, floor_n, limit_n)
    fit = least_squares(residual, start, jac=jacobian, bounds=(floor_n, limit_n), method="trf",
                        xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=50)
    tensions = np.clip(fit.x, floor_n, limit_n)
    tip = shape(tensions).tip_position_m
    error = float(np.linalg.norm(tip - target))
    margin = 1e-6 * (limit_n - floor_n)
    return Compensation(
        tensions_n=tensions, target_m=target, predicted_tip_m=tip, residual_m=error,
        reached=error <= tolerance_m,
        at_bounds=(tensions <= floor_n + margin) | (tensions >= limit_n - margin),
        evaluations=int(fit.nfev), status=str(fit.message),
    )


def hold_tensions(model: RodModel, unloaded_tensions_n, tip_force_n, *, tip_moment_nm=None, base_rotation=None,
                  floor_n: float = 0.3, limit_n: float = 5.0, unloaded_friction_direction=None, target_m=None,
                  **options) -> Compensation:
    """Tensions within the bounds that keep the tip where ``unloaded_tensions_n`` held it, under a tip load.

    The target is the predictor's own unloaded tip at ``unloaded_tensions_n``, so a model error
    shared by both shapes cancels: what is compensated is the load, and the move of any tendon
    that was below the floor (slack) up to it.

    Args:
        model: the predictor's rod.
        unloaded_tensions_n: (nt,) tensions (N, >= 0) that held the tip on target without the
            load, e.g. measured on the device in length mode.
        tip_force_n, tip_moment_nm: (3,) the known tip load, world frame (N, N·m); zero gives
            the tensions that hold the target within the bounds without a load.
        base_rotation: clamp orientation (3×3, body → world).
        floor_n, limit_n: tension bounds (N).
        unloaded_friction_direction: (nt,) the sliding state σ the unloaded tensions were
            measured in (a friction model's static shape depends on how it was reached); default +1.
        target_m: (3,) that unloaded tip (world frame, m), if the caller has solved it already
            (:func:`unloaded_tips`: one batch for the target and the sags of several loads);
            None solves it here.
        **options: passed to :func:`compensate_tensions` (``regularisation``, ``tolerance_m``,
            ``friction_direction``: the state the tensions will be held in).
    """
    unloaded = np.asarray(unloaded_tensions_n, dtype=float)
    if target_m is None:
        target = solve(model, np.maximum(unloaded, 0.0), base_rotation=base_rotation,
                       friction_direction=unloaded_friction_direction).tip_position_m
    else:
        target = np.asarray(target_m, dtype=float)
    return compensate_tensions(model, target, tip_force_n=tip_force_n, tip_moment_nm=tip_moment_nm,
                               base_rotation=base_rotation, reference_tensions_n=np.clip(unloaded, floor_n, limit_n),
                               floor_n=floor_n, limit_n=limit_n, **options)


def unloaded_tips(model: RodModel, unloaded_tensions_n, tip_forces_n, *, base_rotation=None,
                  unloaded_friction_direction=None) -> tuple[np.ndarray, np.ndarray]:
    """The target :func:`hold_tensions` aims at, and how far each load moves the tip at the
    unloaded tensions (every tendon pulled): independent solves of one rod, in one
    :func:`twin.rod.solve_batch`.

    Args:
        model: the predictor's rod.
        unloaded_tensions_n: (nt,) tensions (N) that held the tip on target without a load.
        tip_forces_n: (k, 3) the loads (N, world frame).
        base_rotation: clamp orientation (3×3, body → world).
        unloaded_friction_direction: (nt,) the sliding state the unloaded tensions were measured
            in (the target's); default +1.

    Returns:
        (target (3,) m, sags (k,) m: |loaded tip − unloaded tip| at the unloaded tensions).

    Raises:
        ConvergenceError: a case has no solution.
    """
    tensions = np.maximum(np.asarray(unloaded_tensions_n, dtype=float), 0.0)
    forces = np.asarray(tip_forces_n, dtype=float).reshape(-1, 3)
    nt = model.tendon_count
    # The target's own case only where its sliding state is not the sags' (+1).
    own = unloaded_friction_direction is not None
    sigma = np.ones((len(forces) + 1 + own, nt))
    if own:
        sigma[0] = unloaded_friction_direction
    cases = np.vstack([np.zeros((1 + own, 3)), forces])
    sols = solve_batch(model, np.broadcast_to(tensions, (len(cases), nt)), tip_force_n=cases,
                       base_rotation=base_rotation, friction_direction=sigma)
    free = sols[own].tip_position_m
    sags = np.array([np.linalg.norm(sol.tip_position_m - free) for sol in sols[1 + own:]])
    return sols[0].tip_position_m, sags


def response_gain(predicted_move_m, measured_move_m, noise_m: float) -> float | None:
    """The share of a predicted tip move the device made, along the predicted move: the
    projection of ``measured_move_m`` on ``predicted_move_m`` over its length, within
    [:data:`MIN_RESPONSE_GAIN`, 1]; None when the predicted move is within ``GAIN_RESOLVE_SIGMAS``
    times ``noise_m`` (the measured move's standard error, m), too small to tell.

    Args:
        predicted_move_m: (3,) the predictor's tip move between two commands (m).
        measured_move_m: (3,) the tracker's tip move between the same two commands (m).
        noise_m: standard error of the measured move (m).
    """
    predicted = finite_vector("predicted_move_m", predicted_move_m, 3)
    measured = finite_vector("measured_move_m", measured_move_m, 3)
    size = float(np.linalg.norm(predicted))
    if not size > GAIN_RESOLVE_SIGMAS * noise_m:
        return None
    return float(np.clip(measured @ predicted / size**2, MIN_RESPONSE_GAIN, 1.0))


def correct_tensions(model: RodModel, applied: Compensation, goal_m, measured_miss_m, *, tip_force_n=None,
                     tip_moment_nm=None, base_rotation=None, floor_n: float = 0.3, limit_n: float = 5.0,
                     regularisation: float = 1.0, friction_direction=None, response_gain: float = 1.0,
                     **options) -> Compensation:
    """One closed-loop correction: re-aim the predictor by the model error the tracker reveals.

    With ``applied.tensions_n`` on the device and the load hung, the tracker puts the tip at
    ``measured_miss_m`` from the measured target; the predictor put it at
    ``applied.predicted_tip_m − goal_m``. Their difference ê is the model's error at these tensions
    (plus what the device adds: tension tracking, sensor offsets). Taken as locally constant, the
    tensions that bring the real tip to the target are those that bring the predicted one to
    ``goal_m − ê``: the same bounded least squares as :func:`compensate_tensions`, started from and
    pulled towards the applied tensions, so a correction changes only what the error asks for.
    A miss the predictor already expected (a target out of reach within the bounds) gives ê = 0
    and no change: nothing winds up against the bounds.

    Args:
        model: the predictor's rod.
        applied: the :class:`Compensation` whose tensions are on the device (its ``predicted_tip_m``
            is the predictor's loaded tip at them, world frame, m).
        goal_m: (3,) the target in the predictor's frame (m): for :func:`hold_tensions`, its
            ``target_m`` (the predictor's unloaded tip), not a re-aimed one.
        measured_miss_m: (3,) measured loaded tip minus measured target, world frame (m), e.g.
            tracker means over a second with the tip at rest.
        tip_force_n, tip_moment_nm, base_rotation: the known load and the clamp orientation, as
            for :func:`compensate_tensions`.
        floor_n, limit_n: tension bounds (N).
        regularisation: λ, weight of the change from the applied tensions (mm of tip error per N).
            The tip Jacobian has two bending directions of ~20 mm/N and one of ~0.05 mm/N, all
            four tendons pulling together (the tip moves along the backbone only by its axial
            compression); 1 mm/N passes the first two whole and holds the third, so the noise of
            a measured miss (~0.02 mm) cannot command newtons of co-contraction. The feed-forward's
            0.03 lets the predictor use that direction, which it knows.
        friction_direction: (nt,) the sliding state σ measured with the miss
            (:class:`twin.effects.SlidingState`). A model with friction then re-predicts its tip at
            the applied tensions in that state, so a tendon the loop flipped is no model error,
            and re-aims in it. Default: the applied plan's prediction as it stands.
        response_gain: the share of a predicted tip move the device makes (0–1], e.g. as
            :func:`response_gain` measured it on the last correction: the unexpected part of the
            miss is taken over it. A tendon friction the model lacks holds part of each tension
            change back from the tip, so a full step falls short by much the same share again.
        **options: passed to :func:`compensate_tensions` (``tolerance_m``).

    Returns:
        The corrected :class:`Compensation`; its ``target_m`` is the re-aimed point and its
        ``residual_m`` the predictor's miss of it.
    """
    goal, miss = finite_vector("goal_m", goal_m, 3), finite_vector("measured_miss_m", measured_miss_m, 3)
    if not 0.0 < response_gain <= 1.0:
        raise ValueError(f"response_gain = {response_gain!r}: need 0 < response_gain <= 1")
    predicted = applied.predicted_tip_m if friction_direction is None else solve(
        model, applied.tensions_n, tip_force_n=tip_force_n, tip_moment_nm=tip_moment_nm, base_rotation=base_rotation,
        friction_direction=friction_direction).tip_position_m
    # The applied tensions' own expected miss of what they aimed at (out of reach within the
    # bounds) is no model error; only the rest is scaled by the device's response.
    expected = applied.predicted_tip_m - applied.target_m
    model_error = (goal + expected + (miss - expected) / response_gain) - predicted
    return compensate_tensions(model, goal - model_error, tip_force_n=tip_force_n, tip_moment_nm=tip_moment_nm,
                               base_rotation=base_rotation, reference_tensions_n=applied.tensions_n,
                               floor_n=floor_n, limit_n=limit_n, regularisation=regularisation,
                               friction_direction=friction_direction, **options)
