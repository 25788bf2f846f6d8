"""Whether the board's loops settle, friction or not (``twin bench hold``).

Two figures on a ``sim://`` device, the firmware's loops on the twin: length mode bending the
robot to a configuration of the compensation grid, and then tension mode holding the tensions
it measures there with a tip mass hung (the start of a compensation trial). Friction in the disc
holes (``effects.tendon_friction_coeff``) is what used to make the tension loop cycle: the
figures are meant to be taken with it on, e.g.
``twin bench hold --set effects.tendon_friction_coeff=0.3``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from twin.control.gains import tension_gains_for
from twin.driver.errors import DeviceError
from twin.control.pretension import pretension_straight
from twin.effects.tendon_friction import PRESLIDING_M
from twin.params import Params, load_params
from twin.pcc import tendon_length_changes_m

__all__ = ["HOLD_KAPPA_PER_M", "HOLD_PHI_DEG", "HOLD_MASS_KG", "CommandedHold", "hold_commanded", "hold_figures"]

# The configuration and load of the measurement: a mid bend of the compensation grid
# (twin.pcc.GRID_KAPPA_PER_M) with the smallest tip mass of the compensation trial, where the
# tension loop was seen to cycle at μ = 0.1.
HOLD_KAPPA_PER_M = 8.7
HOLD_PHI_DEG = 0.0
HOLD_MASS_KG = 0.005

# The window (s) whose means the held tension is judged on: the tension loop's own bandwidth is
# ~4 Hz (ki × stall force, 23 /s), the tendon rod's swing modes 1-10 Hz, while what the loop
# passes of the load cells' white noise rings at the 25-40 Hz presliding resonance of a stuck
# tendon (stiff-long at μ = 0.3: 73 % of the true tension's variance in 25-40 Hz); 0.1 s means
# keep everything up to the rod's modes and average that out.
MEAN_WINDOW_S = 0.1
# The window (s) over which a held spool counts as still: five periods of the loop's ~4 Hz crossover
# (ki × stall force, 23 /s), long enough that a ring of the loop would not pass for a stop.
STILL_WINDOW_S = 0.5


def hold_figures(params: Params | None = None, *, kappa_per_m: float = HOLD_KAPPA_PER_M,
                 phi_deg: float = HOLD_PHI_DEG, mass_kg: float = HOLD_MASS_KG, length_timeout_s: float = 15.0,
                 tension_settle_s: float = 3.0, measure_s: float = 2.0, tension_gains: dict | None = None,
                 seed: int = 0) -> dict:
    """Settling of length and tension mode on a ``sim://`` twin of ``params``.

    Length mode: from the pretensioned straight robot, the lengths of the constant-curvature bend
    (``kappa_per_m``, ``phi_deg``); the device time until every tendon is within an encoder count
    of its target (looked at every 0.25 s, at most ``length_timeout_s``) and each tendon's
    distance from its target then (encoder counts): where it stuck, if it did. Tension mode: the tip
    mass hung (1 s to swing out in length mode), then tension mode holding the tensions measured
    at the switch; after ``tension_settle_s``, over ``measure_s``: the twin's true tension at
    every board tick, and the load cells' at every telemetry sample.

    The held tension is judged on the true tension's :data:`MEAN_WINDOW_S` means: the cells'
    noise is not the loop's (stiff-long's 5 kg cells, 25 mN RMS, span ~0.13 N over a second on
    their own), and what the loop passes of it into the tendon rings at the 25-40 Hz presliding
    resonance of a tendon friction holds, which those means average out. Beside it, each stated:
    the true tension's own peak to peak, the cells' (noise included: ~0.03 N on 1 kg cells
    without friction) and that of the cells' means over the same window, what a rig would see.

    Args:
        params: the twin's parameter set (default ``models/endoscope/endoscope.toml``).
        tension_gains: the board's tension gains; default :func:`twin.control.gains.tension_gains_for` the
            robot (the gains ``twin compensate`` runs on).
        seed: the twin's sensor-noise seed.

    Returns:
        ``length_error_counts`` (largest of ``length_errors_counts``, one per channel, absolute),
        ``length_settle_s``,
        ``tension_ptp_n`` (N: largest of ``tension_ptps_n``, each channel's peak to peak of
        its true tension's 0.1 s means), ``tension_offset_n`` (largest absolute of
        ``tension_offsets_n``, each channel's load-cell mean less its setpoint, N),
        ``tension_true_ptp_n`` (N: the true tension's peak to peak, every tick),
        ``tension_cell_ptp_n`` (N: the cells', every telemetry sample), ``tension_cell_mean_ptp_n``
        (N: the cells' 0.1 s means') and ``tension_ring_rms_n`` (N: the largest channel's RMS
        beyond the load cells' stated noise, ``sensors.loadcell_noise_n``, as a variance
        difference: what the loop adds to the noise).
    """
    from twin.driver import open_device

    params = params if params is not None else load_params()
    with open_device("sim://", params=params, seed=seed) as device:
        device.set_gains("tensions", **(tension_gains or tension_gains_for(params)))
        zero = pretension_straight(device, params, mode="lengths")
        device.set_lengths(zero + tendon_length_changes_m(kappa_per_m, phi_deg, params))
        start_s = device.time_s
        while True:
            device.wait(0.25)
            sample = device.latest()
            # Rounded: a length one count off reads 1.000002 counts off (float32 lengths).
            length_errors = np.round(np.abs(sample.tendon_lengths_m - sample.targets) / device.info.tendon_m_per_count, 2)
            if length_errors.max() <= 1.0 or device.time_s - start_s >= length_timeout_s:
                break
        length_s = device.time_s - start_s

        _hang_tip_mass(device, mass_kg)
        device.set_mode("tensions")
        device.wait(tension_settle_s)
        device.drain()
        tick_s = device.twin.tick_s
        true_n, _ = _tick_samples(device, measure_s)
        samples = device.drain()
        targets = samples[-1].targets
        tensions = np.array([s.tensions_n for s in samples])
        ptps = np.ptp(tensions, axis=0)
        offsets = tensions.mean(axis=0) - targets
        # What the loop adds to the cells' own noise (their stated RMS, sensors.loadcell_noise_n):
        # on 5 kg cells (25 mN RMS) the noise alone spans ~0.13 N over a second of samples.
        rings = np.sqrt(np.maximum(tensions.var(axis=0) - params.sensors.loadcell_noise_n ** 2, 0.0))
        true_ptps = np.ptp(true_n, axis=0)
        true_mean_ptps = np.ptp(_window_means(true_n, round(MEAN_WINDOW_S / tick_s)), axis=0)
        cell_mean_ptps = np.ptp(_window_means(tensions, round(MEAN_WINDOW_S * params.rig.telemetry_rate_hz)), axis=0)
    return {
        "length_error_counts": float(length_errors.max()),
        "length_settle_s": round(float(length_s), 2),
        "tension_ptp_n": float(true_mean_ptps.max()),
        "tension_offset_n": float(np.abs(offsets).max()),
        "tension_true_ptp_n": float(true_ptps.max()),
        "tension_cell_ptp_n": float(ptps.max()),
        "tension_cell_mean_ptp_n": float(cell_mean_ptps.max()),
        "tension_ring_rms_n": float(rings.max()),
        "length_errors_counts": [round(float(e), 1) for e in length_errors],
        "tension_ptps_n": [round(float(p), 4) for p in true_mean_ptps],
        "tension_offsets_n": [round(float(o), 4) for o in offsets],
    }


def _window_means(x: np.ndarray, window: int) -> np.ndarray:
    """Means of ``x`` (samples × channels) over consecutive windows of ``window`` samples (a
    partial last window left out)."""
    window = max(1, window)
    n = len(x) // window * window
    return x[:n].reshape(-1, window, x.shape[1]).mean(axis=1)


@dataclasses.dataclass(frozen=True)
class CommandedHold:
    """What :func:`hold_commanded` measured.

    Attributes:
        true_n: the twin's true tensions at every board tick (ticks × channels, N).
        setpoints_n: the tensions commanded (N).
        switch_n: the load cells' tensions at the switch to tension mode (N).
        tick_s: the board's tick (s).
        fault_flags: the board's fault flags at the end (0: none).
        settled_s: the time from the end of the ramp to the measurement (s).
        spool_ptp_m: each spool's peak to peak travel over the measurement (m).
    """

    true_n: np.ndarray
    setpoints_n: np.ndarray
    switch_n: np.ndarray
    tick_s: float
    fault_flags: int
    settled_s: float
    spool_ptp_m: np.ndarray

    def figures(self) -> dict:
        """Per channel: ``ptp_n`` (the true tension's peak to peak, every tick), ``mean_ptp_n`` (that
        of its :data:`MEAN_WINDOW_S` means) and ``offset_n`` (its mean less the setpoint), N."""
        means = _window_means(self.true_n, round(MEAN_WINDOW_S / self.tick_s))
        return {"ptp_n": np.ptp(self.true_n, axis=0), "mean_ptp_n": np.ptp(means, axis=0),
                "offset_n": self.true_n.mean(axis=0) - self.setpoints_n}


def hold_commanded(params: Params, tensions_n: np.ndarray | Callable[[np.ndarray], np.ndarray], *,
                   kappa_per_m: float, phi_deg: float, mass_kg: float, twin_params: Params | None = None,
                   robot: str | None = None, settle_s: float = 2.0, still_timeout_s: float = 0.0,
                   measure_s: float = 2.0, seed: int = 1) -> CommandedHold:
    """Tension mode holding commanded tensions in a bent pose, as a compensation trial's command does.

    On a ``sim://`` twin of ``twin_params`` (default ``params``), the board on ``params``'s tension
    gains (:func:`twin.control.gains.tension_gains_for`): the pretensioned straight robot bent in
    length mode to the constant-curvature lengths of (``kappa_per_m``, ``phi_deg``) for 3 s,
    ``mass_kg`` hung for 1 s, then tension mode, and after 0.5 s its setpoints ramped to
    ``tensions_n`` over a second (a smoothstep, as a compensation ramps); after ``settle_s``, and
    then until every spool has moved less than the friction's presliding travel over
    :data:`STILL_WINDOW_S` (at most ``still_timeout_s`` more), the true tensions at every board
    tick over ``measure_s``.

    Args:
        tensions_n: the commanded tensions (N), or a function of the load cells' tensions at the
            switch (N) giving them; negatives are held at 0.
        robot: the robot's name, for the board's channel-count message.
    """
    from twin.driver import open_device

    with open_device(f"sim://?seed={seed}", params=twin_params or params, robot=robot) as device:
        device.set_gains("tensions", **tension_gains_for(params))
        zero = pretension_straight(device, params, mode="lengths")
        device.set_lengths(zero + tendon_length_changes_m(kappa_per_m, phi_deg, params))
        device.wait(3.0)
        _hang_tip_mass(device, mass_kg)
        device.set_mode("tensions")
        device.wait(0.5)
        start = np.asarray(device.latest().tensions_n, dtype=float)
        end = np.maximum(np.asarray(tensions_n(start) if callable(tensions_n) else tensions_n, dtype=float), 0.0)
        for k in range(1, 41):  # a smoothstep over a second, as a compensation ramps
            x = k / 40
            device.set_tensions(np.maximum(start + (end - start) * x * x * (3.0 - 2.0 * x), 0.0))
            device.wait_next(timeout_s=1.0)
        device.wait(settle_s)
        # A command that bends the rod on is held by a duty clamp's pull less the back-EMF of its
        # winding: it slides there at a few mm/s, which is no ring; the hold is measured once every
        # spool has stopped (moved less than the friction's presliding travel over a window).
        settled_s = settle_s
        spool = device.twin.spool_positions_m()
        while settled_s < settle_s + still_timeout_s:
            device.wait(STILL_WINDOW_S)
            settled_s += STILL_WINDOW_S
            now = device.twin.spool_positions_m()
            if np.abs(now - spool).max() < PRESLIDING_M:
                break
            spool = now
        true_n, spools_m = _tick_samples(device, measure_s)
        return CommandedHold(true_n, end, start, device.twin.tick_s, int(device.latest().fault_flags), settled_s,
                             np.ptp(spools_m, axis=0))


def _hang_tip_mass(device, mass_kg: float) -> None:
    """Hang ``mass_kg`` (kg) on the tip through the device's fixture and give it 1 s to swing out."""
    if device.fixture is None:
        raise DeviceError(f"{device.url}: hanging a tip mass needs the device's fixture; it has none")
    device.fixture.hang_tip_mass(mass_kg)
    device.wait(1.0)


def _tick_samples(device, measure_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The twin's true tensions (N) and spool positions (m) at every board tick (ticks × channels)
    over ``measure_s`` (s): what the tendons hold, without the cells' noise, sampled fast enough
    for the 25-40 Hz presliding resonance."""
    tick_s = device.twin.tick_s
    true, spools = [], []
    for _ in range(round(measure_s / tick_s)):
        device.wait(tick_s)
        true.append(device.twin.true_tensions_n())
        spools.append(device.twin.spool_positions_m())
    return np.array(true), np.array(spools)
