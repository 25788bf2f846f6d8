"""The thesis's experimental procedures, run on any device (the twin by default, the rig by URL).

Each protocol only talks to :class:`twin.driver.Device` (commands, telemetry, ``device.fixture``
for the hands-on steps, ``device.tracker`` for the tip) and writes a dataset row by row, so an
interrupted run keeps what it measured and resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import Sequence

import numpy as np
from tqdm import tqdm

from twin.calibration import Calibration, run_calibration
from twin.data.dataset import DatasetWriter
from twin.effects import SlidingState
from twin.params import Params
from twin.pcc import tendon_length_changes_m, validation_grid
from twin.pose import matrix_to_quat
from twin.rod.grid import holding_tensions_n, pcc_realisable

__all__ = ["ProtocolError", "NotAtRestError", "Measurement", "measure", "wait_for_rest", "pretension", "run_validation",
           "run_stiffness", "calibrate_device", "nominal_calibration", "apply_calibration", "unrealisable", "tripped_before",
           "HOLDABLE_FRACTION", "TRIPPED"]


class ProtocolError(RuntimeError):
    """A procedure could not go on (no tracker, a faulted board, a tip that does not settle)."""


class NotAtRestError(ProtocolError):
    """:func:`wait_for_rest` timed out: the device is still moving, the board did not fault."""


@dataclasses.dataclass(frozen=True)
class Measurement:
    """One static measurement: means over a short window.

    Attributes:
        tensions_n, lengths_m: (N,) calibrated tensions (N) and relative lengths (m) from telemetry,
            one per tendon.
        raw_counts: (N,) mean HX711 counts.
        tip_position_m: (3,) fused tracker position, base frame (m).
        tip_quaternion: (4,) (w, x, y, z) of the mean tracker rotation.
        time_s: device time at the end of the window (s).
        frames: tracker frames averaged (rejected frames are left out).
        tip_sem_m: (3,) standard error of ``tip_position_m`` per axis (m): the frames' scatter
            over √frames (NaN from a single frame), the noise the row's tip carries.
    """

    tensions_n: np.ndarray
    lengths_m: np.ndarray
    raw_counts: np.ndarray
    tip_position_m: np.ndarray
    tip_quaternion: np.ndarray
    time_s: float
    frames: int
    tip_sem_m: np.ndarray = dataclasses.field(default_factory=lambda: np.full(3, np.nan))


def _check_state(telemetry) -> None:
    if telemetry.fault_flags:
        raise ProtocolError(f"the board reports fault {telemetry.fault_flags!r} (state {telemetry.state!r}); "
                            "clear the cause and re-enable")


def measure(device, *, duration_s: float = 0.25) -> Measurement:
    """Average telemetry and tracker frames over ``duration_s`` of device time."""
    if device.tracker is None:
        raise ProtocolError("this device has no tracker (serial:// needs ?igtl=host:port)")
    samples, positions, rotations = [], [], []
    end = device.time_s + duration_s
    while device.time_s < end:
        sample = device.wait_next(timeout_s=1.0)
        _check_state(sample)
        samples.append(sample)
        fused = device.tracker.read()
        if fused.ok:
            positions.append(fused.pose.position_m)
            rotations.append(fused.pose.rotation)
    if not positions:
        raise ProtocolError(f"no valid tracker frame in {duration_s} s (last: {device.tracker.read().reason})")
    mean_rot = np.mean(rotations, axis=0)
    u, _, vt = np.linalg.svd(mean_rot)
    rotation = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return Measurement(
        tensions_n=np.mean([s.tensions_n for s in samples], axis=0),
        lengths_m=np.mean([s.tendon_lengths_m for s in samples], axis=0),
        raw_counts=np.mean([s.raw_counts for s in samples], axis=0),
        tip_position_m=np.mean(positions, axis=0),
        tip_quaternion=matrix_to_quat(rotation),
        time_s=samples[-1].time_s,
        frames=len(positions),
        tip_sem_m=(np.std(positions, axis=0, ddof=1) / np.sqrt(len(positions)) if len(positions) > 1
                   else np.full(3, np.nan)),
    )


# The tension tolerance of wait_for_rest in HX711 counts: 0.01 N on the thesis's 1 kg cells
# (45,000 counts/N), twice their ~5 mN noise. The amplifier's noise is in counts, so cells of
# another sensitivity get the tolerance this many counts make (0.05 N on 5 kg cells).
REST_TOLERANCE_COUNTS = 450.0


# The sample-to-sample scatter of a tendon's tension (in tension tolerances) above which
# wait_for_rest takes it for a dither, not the load cells' noise: four times that noise (the
# tolerance is twice it), which an estimate from a few samples does not reach by chance.
REST_DITHER_TOLERANCES = 2.0


def _dithered_tolerance_n(window, previous, tolerance_n: float) -> np.ndarray:
    """The change of each tendon's window-mean tension that :func:`wait_for_rest` allows between
    the ``previous`` window and this one (lists of (N,) samples, N): ``tolerance_n``, or two
    standard errors of the difference of the two means where the tensions dither (their
    sample-to-sample scatter, the root mean square of successive differences over √2, which a
    slow swing hardly raises, is over :data:`REST_DITHER_TOLERANCES` tolerances)."""
    if previous is None or len(window) < 2 or len(previous) < 2:
        return np.full(np.shape(window[0]), tolerance_n)
    steps = np.concatenate([np.diff(np.asarray(previous, dtype=float), axis=0),
                            np.diff(np.asarray(window, dtype=float), axis=0)])
    scatter_n = np.sqrt(np.mean(steps ** 2, axis=0) / 2.0)
    standard_error_n = scatter_n * np.sqrt(1.0 / len(window) + 1.0 / len(previous))
    return np.where(scatter_n > REST_DITHER_TOLERANCES * tolerance_n,
                    np.maximum(tolerance_n, 2.0 * standard_error_n), tolerance_n)


def wait_for_rest(device, *, tension_tolerance_n: float | None = None, tip_tolerance_m: float = 3e-4,
                  window_s: float = 0.1, timeout_s: float = 4.0) -> float:
    """Wait until the endoscope is at rest: the ``window_s`` means of the tensions and of the
    tracked tip change by less than the tolerances (set above the sensors' noise on window means:
    load cells ~5 mN on the thesis's 1 kg cells, tracker ~0.2 mm per sample) from each window to
    the next, twice in a row. ``tension_tolerance_n`` defaults to :data:`REST_TOLERANCE_COUNTS`
    at the device's rated load-cell sensitivity (0.01 N on the thesis's cells).

    Once is not enough: in tension mode the loaded endoscope swings slowly (~1.7 Hz, damping
    ratio ~0.1), and two windows around a turning point of the swing have nearly the same mean.
    Three windows span half its period, so they cannot all sit at one.

    A length loop holding tendons through strong friction never stills its tensions: it dithers
    by an encoder count, each dither turns the friction round, and the tensions swing by some
    0.1 N from sample to sample for good (endoscope-soft-g at μ = 0.6: ±0.15 N about a steady
    mean, the tip still within 0.1 mm), so two window means differ by more than the tolerance
    by chance alone. Where the tensions' sample-to-sample scatter is over
    :data:`REST_DITHER_TOLERANCES` tolerances, the means may also differ by up to two standard
    errors of that scatter: the tensions are then at rest about a dither, as on a rig.

    Returns the device time it took (s). Raises :class:`ProtocolError` after ``timeout_s``.
    """
    if tension_tolerance_n is None:
        tension_tolerance_n = REST_TOLERANCE_COUNTS / getattr(device, "loadcell_gain_counts_per_n", 45000.0)
    start = device.time_s
    last, quiet, previous = None, 0, None
    while device.time_s - start < timeout_s:
        end = device.time_s + window_s
        tensions, tips = [], []
        while device.time_s < end:
            sample = device.wait_next(timeout_s=1.0)
            _check_state(sample)
            tensions.append(sample.tensions_n)
            if device.tracker is not None:
                fused = device.tracker.read()
                if fused.ok:
                    tips.append(fused.pose.position_m)
        now = (np.mean(tensions, axis=0), np.mean(tips, axis=0) if tips else None)
        allowed_n = _dithered_tolerance_n(tensions, previous, tension_tolerance_n)
        if last is not None and np.all(np.abs(now[0] - last[0]) < allowed_n) and (
                now[1] is None or last[1] is None or np.linalg.norm(now[1] - last[1]) < tip_tolerance_m):
            quiet += 1
            if quiet == 2:
                return device.time_s - start
        else:
            quiet = 0
        last, previous = now, tensions
    raise NotAtRestError(f"the robot did not come to rest within {timeout_s} s (tensions to "
                        f"{tension_tolerance_n:.3g} N, tip to {tip_tolerance_m * 1e3:.2f} mm)")


def nominal_calibration(params: Params) -> dict:
    """The load-cell calibration the parameter set states (what the twin's HX711s are built with):
    ``{"gain_counts_per_n": [...], "offset_counts": [...], "source": "nominal"}``."""
    s = params.sensors
    return {"gain_counts_per_n": [s.loadcell_gain_counts_per_n] * params.tendons.count,
            "offset_counts": list(s.loadcell_offset_counts), "source": "nominal (sensors.* of the parameter set)"}


def apply_calibration(device, calibration: dict) -> None:
    """Give ``device`` a recorded load-cell calibration (:func:`nominal_calibration`'s form, as a
    dataset's metadata keeps it: ``gain_counts_per_n`` and ``offset_counts``)."""
    device.set_calibration(gain_counts_per_n=calibration["gain_counts_per_n"], offset_counts=calibration["offset_counts"])


def pretension(device, params: Params, *, mode: str = "lengths", tension_n: float | None = None,
               settle_s: float = 0.0, tare_lengths: bool = False) -> None:
    """Pretension every tendon of the endoscope held straight in the reference holder, and hand
    the tendons to the board in ``mode``.

    The thesis wound the tendons by hand until the load cells read 1.2–1.5 N (§8.3); here the same
    is done by hanging a dead weight of ``tension_n``/g over each tendon's load-cell pulley (the
    fixture: the operator on the rig, ideal weights on the twin), after which the board, enabled
    in ``mode``, holds the tendons and the weights come off. Call it on a disabled board. Leaves
    the holder engaged.

    Args:
        device: a connected :class:`twin.driver.Device` with a fixture.
        params: the parameter set (gravity; the default pretension ``tendons.pretension_n``).
        mode: the mode the board is enabled in.
        tension_n: pretension per tendon (N).
        settle_s: device time to let the weights settle in the closed holder (s).
        tare_lengths: zero the encoders' lengths in the pretensioned straight pose first.
    """
    tension = params.tendons.pretension_n if tension_n is None else float(tension_n)
    # Equal dead weights first: they pull a bent endoscope (from the previous configuration) back
    # to nearly straight, so the holder closes on a straight endoscope, not snaps a bent one.
    device.fixture.hang_calibration_mass(tension / params.environment.gravity_m_s2 * 1e3, range(params.tendons.count))
    device.fixture.engage_holder()
    if settle_s > 0:
        device.wait(settle_s)
    if tare_lengths:
        device.tare(loadcells=False, lengths=True)
    device.set_mode(mode)
    device.enable()
    device.fixture.remove_calibration_masses()


# Why a configuration of the grid is left out: the wording of the report and the metadata.
UNREALISABLE = ("the tendon layout cannot bend towards its plane (no two neighbouring tendons less than 180° apart "
                "bracket it)")


# The share of the tension limit the grid's pulls may need: the motors pull with at most 0.9 of
# it (firmware/PROTOCOL.md, "Tension bound"). The estimate (twin.rod.grid.holding_tensions_n,
# without the pretension, which the antagonists pay out) is within about 20 % of the tensions the
# twin's sweeps measure, mostly above (three-tendon at κ 26.2 1/m, φ 150°, 10 g: 4.68 N for
# 3.85 N measured; stiff-long at 10.48 1/m: 23.8 N for 20.5 N); one that trips the limit all
# the same is left out when the run is resumed (tripped_before).
HOLDABLE_FRACTION = 0.9


def beyond_limit_reason(limit_n: float) -> str:
    """Why a configuration of the grid is left out for the tension limit ``limit_n``."""
    return (f"holding it needs a pull over {HOLDABLE_FRACTION:g} of the {limit_n:g} N tension limit "
            "(rig.tension_limit_n), which the motors do not reach")


def unrealisable(grid: Sequence[tuple], params: Params, base_rotation=None) -> list[dict]:
    """The configurations of ``grid`` the robot cannot realise, each as ``{"config",
    "kappa_cmd_per_m", "phi_cmd_deg", "tip_mass_kg", "reason"}``: a bent one whose plane no pair
    of neighbouring tendons can pull towards (:func:`twin.rod.grid.pcc_realisable`), and one whose
    estimated holding pull (:func:`twin.rod.grid.holding_tensions_n`, in the clamp pose
    ``base_rotation``, default ``rig.base_rotation``) is over :data:`HOLDABLE_FRACTION` of
    ``rig.tension_limit_n``: run, it would trip the limit. A straight one (κ = 0) needs no pull
    to bend; under a tip mass it may need one to hold."""
    out = []
    limit = params.rig.tension_limit_n
    for config, kappa, phi, mass in grid:
        if kappa != 0 and not pcc_realisable(phi, params):
            reason = UNREALISABLE
        else:
            try:
                pull = float(np.max(holding_tensions_n(kappa, phi, mass, params, base_rotation, pretension_n=0.0)))
            except ValueError:
                reason = UNREALISABLE
            else:
                if pull <= HOLDABLE_FRACTION * limit:
                    continue
                reason = beyond_limit_reason(limit)
        out.append({"config": int(config), "kappa_cmd_per_m": float(kappa), "phi_cmd_deg": float(phi),
                    "tip_mass_kg": float(mass), "reason": reason})
    return out


# Why a configuration is left out after it tripped the limit once (the reason's first words).
TRIPPED = "tripped the tension limit when run"


def tripped_before(folder: str | Path) -> list[dict]:
    """The configurations of the dataset in ``folder`` that an earlier attempt tripped the
    tension limit in (its metadata's ``left_out`` entries whose reason says so); none for a new one."""
    from twin.data.dataset import METADATA, read_metadata

    if not (Path(folder) / METADATA).exists():
        return []
    return [dict(e) for e in read_metadata(folder).get("left_out", []) if str(e.get("reason", "")).startswith(TRIPPED)]


def _tension_trip(device) -> int:
    """The board's fault flags if the tension limit tripped (0 otherwise, or when it is gone)."""
    from twin.driver import codec

    try:
        flags = int(device.latest().fault_flags)
    except Exception:  # the board went away: nothing to say about the limit
        return 0
    return flags if flags & codec.Fault.TENSION_LIMIT else 0


def _record_trip(folder: str | Path, entry: dict) -> None:
    """Add ``entry`` to the dataset's ``left_out``, so that a resumed run does not run it again."""
    import json

    from twin.data.dataset import METADATA, read_metadata, write_atomic

    meta = read_metadata(folder)
    meta["left_out"] = [e for e in meta.get("left_out", []) if e.get("config") != entry["config"]] + [entry]
    write_atomic(Path(folder) / METADATA, json.dumps(meta, indent=1))


def run_validation(device, folder: str | Path, params: Params, *, grid: Sequence[tuple] | None = None,
                   pretension_n: float | None = None, progress: bool = True, settle_timeout_s: float = 10.0,
                   calibration: dict | None = None, robot: str | None = None, experiment: str = "validation",
                   overshoot: float = 0.0, min_overshoot_m: float = 0.0) -> Path:
    """The thesis's validation sweep (§8.3) on ``device``, written to a dataset in ``folder``.

    For each (κ, φ): hold straight, pretension to 1.2–1.5 N, release, drive the PCC tendon-length
    setpoints, then hang each tip mass while the lengths are held; record tensions, lengths and the
    tracked tip after the tip settles. Configurations already in ``folder`` are skipped (resume).

    Args:
        device: a connected :class:`twin.driver.Device` with a fixture and a tracker.
        folder: the dataset folder.
        params: the model's parameter set (recorded in the metadata; its PCC geometry sets the lengths).
        grid: (config, κ 1/m, φ deg, tip mass kg) rows (default the 216 of thesis §8.3, its
            curvatures scaled to the robot's length: :func:`twin.pcc.validation_grid`).
        pretension_n: default ``tendons.pretension_n``.
        settle_timeout_s: longest wait for the endoscope to come to rest in a configuration
            (device s). On the twin the slowest robot of the zoo, two-segment, whose six length
            loops share the load by pulling against each other, comes to rest within 5.9 s over the
            whole grid (the endoscope within 1.8 s; measured, seed 2): 10 s leaves the rig room.
        calibration: the load-cell calibration the device applies, recorded in the metadata.
        robot: the robot's name, recorded in the metadata.
        experiment: the rows' ``experiment``; another than the dataset's own appends them to it
            (the discrepancy workflow's deciding experiments, :mod:`twin.discrepancy.decide`).
        overshoot: approach each configuration from the other side: every tendon first goes past
            its setpoint by this fraction of its move (at least ``min_overshoot_m``), then back,
            so its friction's sliding state flips (0: straight there).

    Every row records each tendon's friction sliding state, followed from the encoders over the
    whole run (:class:`twin.effects.SlidingState`): a static state remembers how it was reached.
    The state recorded is its mean over the measurement's window, as the averaged tip saw it.

    The setpoints realise (κ, φ) for any tendon layout: each tendon shortens by r κ s cos(φ − α)
    over its anchored length s (:func:`twin.pcc.tendon_length_changes_m`). The configurations
    the layout cannot realise (:func:`unrealisable`) are not run: the metadata's ``left_out``
    lists them with the reason. The dataset records the device's pose
    (:attr:`twin.driver.Device.base_rotation`), the one the twin runs in or the rig is mounted in.
    """
    rows = list(grid or validation_grid(params))
    left_out = unrealisable(rows, params, device.base_rotation)
    # Configurations an earlier attempt at this run tripped the limit in: run again they would
    # trip it again, so a resumed run leaves them out too.
    known = {entry["config"] for entry in left_out}
    left_out += [e for e in tripped_before(folder) if e["config"] not in known]
    skipped = {entry["config"] for entry in left_out}
    pre = params.tendons.pretension_n if pretension_n is None else pretension_n
    groups: dict[tuple[float, float], list[tuple[int, float]]] = {}
    for config, kappa, phi, mass in rows:
        if config not in skipped:
            groups.setdefault((kappa, phi), []).append((config, mass))
    with DatasetWriter(folder, experiment=experiment, device=device.url, params=params,
                       base_rotation=device.base_rotation, calibration=calibration, robot=robot,
                       left_out=left_out, append=experiment != "validation") as writer:
        done = writer.completed()
        sliding = SlidingState(device.info.tendon_m_per_count)
        sliding.follow(device.drain())
        todo = [(k, v) for k, v in groups.items() if not all(c in done for c, _ in v)]
        # The bar closes (ends its line) also when a stop raises, so the reason prints below it.
        with tqdm(total=sum(len(v) for _, v in todo), desc="validation sweep", unit="config",
                  disable=not progress) as bar:
            for (kappa, phi), configs in todo:
                current, bending = None, False
                try:
                    device.disable()
                    pretension(device, params, tension_n=pre, settle_s=0.3)
                    device.wait(0.05)
                    _check_state(device.latest())
                    bending = True
                    # The relative lengths of the pretensioned straight endoscope: the zero of the PCC setpoints.
                    zero = device.latest().tendon_lengths_m.copy()
                    device.fixture.release_holder()
                    target = zero + tendon_length_changes_m(kappa, phi, params)
                    if overshoot > 0:
                        move = target - zero
                        device.set_lengths(target + np.sign(move) * np.maximum(np.abs(move) * overshoot, min_overshoot_m))
                        wait_for_rest(device, timeout_s=settle_timeout_s)
                    device.set_lengths(target)
                    for config, mass in sorted(configs, key=lambda c: c[1]):
                        current = (config, mass)
                        device.fixture.hang_tip_mass(mass)
                        wait_for_rest(device, timeout_s=settle_timeout_s)
                        window_s = device.time_s
                        m = measure(device) if config not in done else None
                        # σ as the averaged tip saw it: its mean over the measurement's window.
                        sliding.follow(device.drain(), mean_from_s=window_s)
                        state = sliding.window_mean if sliding.window_mean is not None else sliding.state
                        if m is not None:
                            writer.write(_row(config, kappa, phi, mass, m, zero, sliding=state))
                        bar.update(1)
                    device.fixture.hang_tip_mass(0.0)
                    device.disable()
                except Exception:
                    # A trip in the pretension is every configuration's (a limit under it): the run stops.
                    flags = _tension_trip(device) if bending else 0
                    if not flags:
                        raise
                    # The configuration being set up (the lightest load first) or loaded trips the
                    # limit whenever it is run: it is left out, named, and the sweep goes on.
                    config, mass = current or min(configs, key=lambda c: c[1])
                    _record_trip(folder, {"config": int(config), "kappa_cmd_per_m": float(kappa),
                                          "phi_cmd_deg": float(phi), "tip_mass_kg": float(mass),
                                          "reason": f"{TRIPPED} (fault flags {flags:#x})"})
                    bar.write(f"validation sweep: configuration {config} (κ {kappa:g} 1/m, φ {phi:g}°, "
                              f"{mass * 1e3:g} g) {TRIPPED}; left out, going on", file=sys.stderr)
                    device.disable()
                    device.fixture.hang_tip_mass(0.0)
                    # The group's heavier loads need more than the one that tripped: left out too.
                    for other, other_mass in configs:
                        if other_mass > mass and other not in done:
                            _record_trip(folder, {"config": int(other), "kappa_cmd_per_m": float(kappa),
                                                  "phi_cmd_deg": float(phi), "tip_mass_kg": float(other_mass),
                                                  "reason": f"{TRIPPED} with a lighter tip mass (configuration {config})"})
                    bar.update(sum(1 for c, m in configs if m >= mass))
    return Path(folder)


def _row(config, kappa, phi, mass, m: Measurement, zero_lengths, repeat: int = 0, sliding=None) -> dict:
    row = {"config": config, "repeat": repeat, "kappa_cmd_per_m": kappa, "phi_cmd_deg": phi, "tip_mass_kg": mass,
           "tip_x_m": m.tip_position_m[0], "tip_y_m": m.tip_position_m[1], "tip_z_m": m.tip_position_m[2],
           "tip_qw": m.tip_quaternion[0], "tip_qx": m.tip_quaternion[1], "tip_qy": m.tip_quaternion[2],
           "tip_qz": m.tip_quaternion[3], "time_s": m.time_s, "tip_frames": m.frames,
           "tip_sem_x_m": m.tip_sem_m[0], "tip_sem_y_m": m.tip_sem_m[1], "tip_sem_z_m": m.tip_sem_m[2]}
    for i in range(len(m.tensions_n)):
        row[f"tension_{i + 1}_n"] = m.tensions_n[i]
        row[f"length_{i + 1}_m"] = m.lengths_m[i] - zero_lengths[i]
        if sliding is not None:
            row[f"slide_{i + 1}"] = sliding[i]
    return row


def run_stiffness(device, folder: str | Path, params: Params, *, masses_kg=(0.0, 0.005, 0.010), repeats: int = 2,
                  progress: bool = True, robot: str | None = None) -> Path:
    """Stiffness characterisation (thesis §8.2): tendons uncoupled (slack), tip masses each ``repeats``
    times; the dataset records the device's pose (:attr:`twin.driver.Device.base_rotation`) and
    ``robot``, the robot's name."""
    with DatasetWriter(folder, experiment="stiffness", device=device.url, params=params,
                       base_rotation=device.base_rotation, robot=robot) as writer:
        done = writer.completed()
        device.disable()  # motors coast: the tendons go slack, the endoscope hangs under its loads
        device.fixture.release_holder()
        zero = device.latest().tendon_lengths_m.copy()
        configs = [(r * len(masses_kg) + i, r, m) for r in range(repeats) for i, m in enumerate(masses_kg)]
        for config, repeat, mass in tqdm(configs, desc="stiffness", unit="load", disable=not progress):
            device.fixture.hang_tip_mass(mass)
            wait_for_rest(device)
            if config not in done:
                writer.write(_row(config, 0.0, 0.0, mass, measure(device), zero, repeat=repeat))
        device.fixture.hang_tip_mass(0.0)
    return Path(folder)


def calibrate_device(device, params: Params, *, samples_per_mass: int = 10, progress: bool = True) -> Calibration:
    """The thesis's load-cell calibration (§4.3) as a guided run: Table 2 masses over the pulley of
    each of the robot's load cells (one per tendon), weighed with the parameter set's gravity."""
    device.disable()

    def read_raw():
        return device.wait_next(timeout_s=1.0).raw_counts.astype(float)

    run = run_calibration(read_raw, device.fixture.hang_calibration_mass, samples_per_mass=samples_per_mass,
                          channels=params.tendons.count, gravity_m_s2=params.environment.gravity_m_s2,
                          device=device.url)
    device.fixture.remove_calibration_masses()
    return run.calibration

