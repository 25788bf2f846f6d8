"""``twin validate`` (the main job), ``twin stiffness`` and ``twin calibrate``: experiments on a device."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

from twin.cliargs import (UsageError, add_device_arg, add_param_args, add_pose_args, add_twin_set_arg, count,
                          new_run_folder, open_device_arg, params_from_args, robot_name, twin_params)
from twin.live import add_live_argument
from twin.params import parse_override
from twin.pcc import quick_grid, validation_grid


def register(sub: argparse._SubParsersAction) -> None:
    v = sub.add_parser(
        "validate",
        help="run the thesis validation sweep on a device, predict it, and write a report (the main job)",
        description="Runs the kappa x phi x tip-mass sweep (thesis 8.3) on a device, records the dataset, "
        "predicts every configuration with the Cosserat model from the measured tensions and known loads, "
        "and writes a Markdown report with figures into a run folder.",
    )
    _device_args(v)
    v.add_argument("--quick", action="store_true",
                   help="a 24-configuration subset of the grid (smallest, middle and largest kappa, phi 0/90/180/270, "
                        "lightest and heaviest tip mass; on the thesis grid kappa 0/13/26.2, 0 and 10 g) for a fast look")
    v.add_argument("--grid", metavar="FILE|SPEC",
                   help="the configurations to run: a CSV file with columns kappa_per_m (or bend_deg), phi_deg, "
                        "tip_mass_kg, one configuration a row; or a SPEC of axes, e.g. "
                        "'bend_deg=0,30,60;phi_deg=0,90,180,270;tip_mass_kg=0,0.01' (an axis left out keeps the "
                        "default's). Default: the thesis grid (thesis 8.3), its curvatures scaled to bend the robot "
                        "by the thesis's 0-90 deg")
    v.add_argument("--resume", metavar="RUN_DIR", help="continue an interrupted run in this folder")
    add_live_argument(v)
    v.set_defaults(func=run_validate)

    c = sub.add_parser(
        "calibrate",
        help="load-cell calibration (thesis 4.3): guided run with known masses, or --refit / --check a file",
        description="Hangs the thesis Table 2 masses over each load cell's pulley (operator prompts on the rig, "
        "automatic on the twin), fits a line per channel and saves the calibration file the host applies.",
    )
    _device_args(c)
    c.add_argument("--file", default="calibration.json", metavar="FILE",
                   help="calibration file to write (run, --refit) or read (--check); default calibration.json")
    mode = c.add_mutually_exclusive_group()
    mode.add_argument("--refit", action="store_true", help="refit the readings stored in --file, no device")
    mode.add_argument("--check", action="store_true",
                      help="hang a few known masses and check --file against them (pass/fail per channel)")
    c.add_argument("--samples", type=int, default=10, help="samples averaged per mass (default 10)")
    c.set_defaults(func=run_calibrate_cmd)

    s = sub.add_parser("stiffness", help="stiffness characterisation (thesis 8.2): fit E and G on a device",
                       description="Exits 3 when the data leave a modulus undetermined: it is named, and the "
                                   "fitted parameter file keeps that modulus's value from the parameter set.")
    _device_args(s)
    s.add_argument("--resume", metavar="RUN_DIR", help="continue an interrupted run in this folder")
    s.set_defaults(func=run_stiffness_cmd)


def _device_args(p: argparse.ArgumentParser) -> None:
    add_device_arg(p)
    p.add_argument("--out", default="runs", metavar="DIR", help="parent folder of the run folder (default runs)")
    p.add_argument("--calibration", metavar="FILE", help="load-cell calibration file (default: the parameter set's)")
    add_twin_set_arg(p)
    p.add_argument("--seed", type=count, default=None, help="sim:// noise seed")
    add_param_args(p)
    add_pose_args(p)


# The invocation of a run, in its run folder (the hidden --twin-set stays in TWIN_TRUTH).
RUN_RECORD = "run.json"
TWIN_TRUTH = "twin_truth.json"


class RunRefused(Exception):
    """A run cannot start or resume as asked (the message says why, naming each difference)."""


def _twin_warnings(args, params) -> list[str]:
    """On sim://, the warning that the twin's own cross-check against the predictor is out of
    bounds (so differences may be the twin's, not the model's); printed and put in the report."""
    if not args.device.startswith("sim://"):
        return []
    from twin.sim.crosscheck import crosscheck_status
    from twin.sim.plant import SimulationError

    try:
        warning = crosscheck_status(twin_params(args, params)).warning
    except SimulationError as exc:
        # The cross-check settles the twin in tension mode without the firmware; with strong
        # hidden effects (tendon friction on the long robots) that can diverge after the sweep
        # itself ran: the measurements stand, the missing check is said.
        warning = f"the twin's own cross-check against the predictor diverged ({exc}); its share of the differences is unknown"
    if warning:
        print(f"twin: {warning}", file=sys.stderr)
    return [warning] if warning else []


def _open(args, params):
    try:
        device = open_device_arg(args.device, params=twin_params(args, params), seed=args.seed,
                                 robot=robot_name(args))
    except UsageError as exc:  # a bad URL or option: nothing was opened
        raise RunRefused(str(exc)) from None
    device.connect()
    return device


def _calibration(args, params, device) -> dict:
    from twin.experiments.protocols import apply_calibration, nominal_calibration

    if args.calibration:
        from twin.calibration import load_calibration

        loaded = load_calibration(args.calibration)
        device.set_calibration(loaded)
        return {**loaded.to_dict(), "file": str(args.calibration)}
    cal = nominal_calibration(params)
    apply_calibration(device, cal)
    return cal


def _invocation(args, command: str) -> dict:
    """What decides the conditions of a run's measurements, as recorded in ``run.json``."""
    return {"command": command, "device": args.device, "seed": args.seed, "quick": bool(getattr(args, "quick", False)),
            "grid": getattr(args, "grid", None),
            "calibration": args.calibration, "robot": getattr(args, "robot", None), "params": args.params,
            "set": list(args.overrides)}


def _resume_command(args, command: str, folder: Path) -> str:
    """The command line that continues the run in ``folder`` under the same conditions."""
    words = ["twin", command, "--resume", str(folder), "--device", args.device]
    if args.seed is not None:
        words += ["--seed", str(args.seed)]
    if getattr(args, "quick", False):
        words.append("--quick")
    if getattr(args, "grid", None):
        words += ["--grid", args.grid]
    if args.calibration:
        words += ["--calibration", args.calibration]
    if getattr(args, "robot", None):
        words += ["--robot", args.robot]
    if args.params:
        words += ["--params", args.params]
    if getattr(args, "pose", None):
        words += ["--pose", args.pose]
    if getattr(args, "base_quat", None) is not None:
        words += ["--base-quat", ",".join(repr(float(q)) for q in args.base_quat)]
    for option, values in (("--set", args.overrides), ("--twin-set", args.twin_overrides)):
        for value in values:
            words += [option, value]
    return shlex.join(words)


def _start_run(args, command: str) -> Path:
    """Create the run folder of a new run and record its invocation in it."""
    from twin.data.dataset import write_atomic

    folder = new_run_folder(args.out, command)
    try:
        write_atomic(folder / RUN_RECORD, json.dumps(_invocation(args, command), indent=1))
        if args.twin_overrides:
            # The hidden truth stays out of the dataset folder, so analyses see only what a lab would.
            write_atomic(folder / TWIN_TRUTH, json.dumps({"twin_set": args.twin_overrides}, indent=1))
    except OSError:
        for leftover in (folder / TWIN_TRUTH, folder / RUN_RECORD):
            leftover.unlink(missing_ok=True)
        folder.rmdir()
        raise
    return folder


def _check_resume(args, command: str, experiment: str, params) -> Path:
    """The run folder of ``--resume``, once it is known to be a ``twin command`` run taken under
    the conditions of this invocation (device, seed, parameters, twin settings, grid).

    Raises:
        RunRefused: not a run folder, a damaged dataset, or conditions that differ (each named).
    """
    import warnings

    from twin.data.dataset import (METADATA, MEASUREMENTS, RUN_DATASET, DatasetError, DatasetWarning, read_dataset,
                                   read_metadata, recorded_params)
    from twin.params import ParameterError

    folder = Path(args.resume)
    where = f"--resume {folder}"
    dataset = folder / RUN_DATASET
    record_path = folder / RUN_RECORD
    if not record_path.exists() and not (dataset / METADATA).exists():
        raise RunRefused(f"{where}: not a run folder of twin {command} (it has neither {RUN_RECORD} nor "
                         f"{RUN_DATASET}/{METADATA})")
    record = None
    if record_path.exists():
        try:
            record = json.loads(record_path.read_text())
        except (OSError, ValueError) as exc:
            raise RunRefused(f"{where}: {record_path} is unreadable ({exc})") from None
        if not isinstance(record, dict):
            raise RunRefused(f"{where}: {record_path} is unreadable (not a JSON object)")
        if record.get("command") != command:
            raise RunRefused(f"{where}: a twin {record.get('command')} run, not a twin {command} run")
    differences = []

    def differ(what: str, here, there) -> None:
        if here != there:
            differences.append(f"{what} {_shown(here)} here, {_shown(there)} in the run")

    if (dataset / METADATA).exists():
        try:
            if (dataset / MEASUREMENTS).exists():
                with warnings.catch_warnings():
                    # A torn last row is for the writer to report, once, when it cuts it off.
                    warnings.simplefilter("ignore", DatasetWarning)
                    metadata = read_dataset(dataset).metadata
            else:
                metadata = read_metadata(dataset)
        except DatasetError as exc:
            raise RunRefused(f"{where}: its dataset cannot be resumed: {exc}") from None
        if metadata.get("experiment") != experiment:
            raise RunRefused(f"{where}: holds a {metadata.get('experiment')!r} dataset, not {experiment!r}")
        if record is None:
            differ("--device", args.device, metadata.get("device"))
        try:
            recorded_set = recorded_params(metadata)
        except ParameterError as exc:
            raise RunRefused(f"{where}: the run's parameter set does not load today ({exc})") from None
        if recorded_set.tendons.count != params.tendons.count:
            raise RunRefused(f"{where}: dataset {dataset} has {recorded_set.tendons.count} tendons; robot "
                             f"{robot_name(args)!r} has {params.tendons.count}")
        recorded = recorded_set.to_dict()
        changed = [(f"{section}.{key}", entry["value"], recorded.get(section, {}).get(key, {}).get("value"))
                   for section, entries in params.to_dict().items() for key, entry in entries.items()]
        changed = [c for c in changed if c[1] != c[2]]
        for key, here, there in changed[:_SHOWN_PARAMETERS]:
            differ(key, here, there)
        if len(changed) > _SHOWN_PARAMETERS:
            differences.append(f"{len(changed) - _SHOWN_PARAMETERS} more parameter(s)")
    if record is not None:
        differ("--device", args.device, record.get("device"))
        if args.device.startswith("sim://"):
            differ("--seed", args.seed, record.get("seed"))
        if command == "validate":
            differ("--quick", bool(args.quick), record.get("quick"))
            differ("--grid", args.grid, record.get("grid"))
        differ("--calibration", args.calibration, record.get("calibration"))
    truth_path = folder / TWIN_TRUTH
    try:
        twin_set = json.loads(truth_path.read_text())["twin_set"] if truth_path.exists() else []
        differ("--twin-set", _twin_set(args.twin_overrides), _twin_set(twin_set))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise RunRefused(f"{where}: {truth_path} is unreadable ({exc})") from None
    if differences:
        raise RunRefused(f"{where}: " + "; ".join(differences) + ". Resume with the run's settings, or start "
                         "a new run (without --resume): rows taken under other conditions would be mixed in")
    if record is None:
        print(f"twin {command}: warning: {where}: no {RUN_RECORD} (a run from an older twin): its --seed, --quick "
              "and --calibration could not be checked", file=sys.stderr)
    return folder


# Parameter differences a resume refusal lists one by one (another parameter file differs in many).
_SHOWN_PARAMETERS = 6


def _twin_set(overrides) -> dict:
    """--twin-set values by key, read as values (so ``[0,0]`` and ``[0, 0]`` are the same)."""
    return dict(parse_override(o) for o in overrides)


def _shown(value) -> str:
    """A setting as the resume refusal names it."""
    if isinstance(value, bool):
        return "on" if value else "off"
    if value is None or value == {}:
        return "none"
    if isinstance(value, dict):
        return " ".join(f"{k}={v!r}" for k, v in value.items())
    return str(value)


def _measured_rows(folder: Path) -> int:
    """Rows of measurements in a run folder's dataset (0 when it has none or no dataset)."""
    from twin.data.dataset import MEASUREMENTS, RUN_DATASET

    try:
        with open(folder / RUN_DATASET / MEASUREMENTS, "rb") as f:
            return max(0, sum(1 for line in f if line.strip()) - 1)
    except OSError:
        return 0


def _discard_if_empty(args, folder: Path) -> bool:
    """Remove the folder of a new run that measured nothing; True if it was removed."""
    import shutil

    if getattr(args, "resume", None) or _measured_rows(folder):
        return False
    shutil.rmtree(folder, ignore_errors=True)
    return True


def _stopped(command: str, folder: Path, args, exc: BaseException) -> None:
    """Why a run stopped, where its measurements are, and the command line that continues it; a
    new run that measured nothing leaves no folder behind."""
    from twin.data.dataset import RUN_DATASET

    why = f"{type(exc).__name__}: {exc}" if not isinstance(exc, KeyboardInterrupt) else "interrupted"
    print(f"twin {command}: stopped: {why}", file=sys.stderr)
    if _discard_if_empty(args, folder):
        print(f"twin {command}: nothing was measured; run folder {folder} removed", file=sys.stderr)
        return
    print(f"twin {command}: every complete measurement so far is in {folder / RUN_DATASET}; continue with:\n"
          f"  {_resume_command(args, command, folder)}", file=sys.stderr)


# The axes a --grid SPEC may set, and the file columns: name → (what it is, smallest value).
_GRID_AXES = {"kappa_per_m": ("curvature (1/m)", 0.0), "bend_deg": ("bend angle kappa L (deg)", 0.0),
              "phi_deg": ("bending plane (deg)", None), "tip_mass_kg": ("tip mass (kg)", 0.0)}


def grid_from_arg(text: str | None, params) -> list[tuple]:
    """The (config, κ 1/m, φ deg, tip mass kg) rows ``--grid`` names: the robot's default grid
    (:func:`twin.pcc.validation_grid`) for None, a SPEC's axes crossed, or a CSV file's rows.

    Raises:
        RunRefused: a file that cannot be read, or a key, column or value that is wrong (named).
    """
    import csv
    import math

    if text is None:
        return validation_grid(params)
    where = f"--grid {text}"
    length_m = params.backbone.length_m

    def number(key: str, word: str) -> float:
        try:
            value = float(word)
        except ValueError:
            raise RunRefused(f"{where}: {key} value {word!r} is not a number") from None
        low = _GRID_AXES[key][1]
        if not math.isfinite(value) or (low is not None and value < low):
            raise RunRefused(f"{where}: {key} = {value!r}: must be finite" + (f" and >= {low:g}" if low is not None else ""))
        return value

    def kappa(key: str, value: float) -> float:
        return value if key == "kappa_per_m" else round(math.radians(value) / length_m, 9)

    path = Path(text)
    if path.is_file():
        try:
            with open(path, newline="") as f:
                table = list(csv.DictReader(f))
        except (OSError, UnicodeDecodeError, csv.Error) as exc:
            raise RunRefused(f"{where}: cannot read it as CSV ({exc})") from None
        columns = set(table[0]) if table else set()
        unknown = sorted(columns - set(_GRID_AXES))
        curvature = [k for k in ("kappa_per_m", "bend_deg") if k in columns]
        missing = [k for k in ("phi_deg", "tip_mass_kg") if k not in columns] + ([] if curvature else ["kappa_per_m or bend_deg"])
        if not table or unknown or missing or len(curvature) > 1:
            raise RunRefused(f"{where}: needs a header row with the columns kappa_per_m (or bend_deg), phi_deg and "
                             "tip_mass_kg and a row per configuration"
                             + (f"; unknown column(s) {', '.join(unknown)}" if unknown else "")
                             + (f"; missing {', '.join(missing)}" if missing and table else "")
                             + ("; kappa_per_m and bend_deg both given" if len(curvature) > 1 else ""))
        key = curvature[0]
        return [(i, kappa(key, number(key, row[key])), number("phi_deg", row["phi_deg"]),
                 number("tip_mass_kg", row["tip_mass_kg"])) for i, row in enumerate(table)]
    if "=" not in text:
        raise RunRefused(f"{where}: neither a file nor a SPEC such as 'bend_deg=0,45,90;phi_deg=0,90;tip_mass_kg=0,0.01'")
    axes: dict[str, list[float]] = {}
    for part in filter(None, (p.strip() for p in text.split(";"))):
        key, _, values = part.partition("=")
        key = key.strip()
        if key not in _GRID_AXES:
            raise RunRefused(f"{where}: unknown axis {key!r}; the axes are {', '.join(_GRID_AXES)}")
        words = [w.strip() for w in values.split(",") if w.strip()]
        if not words:
            raise RunRefused(f"{where}: {key} has no values")
        axes[key] = [number(key, w) for w in words]
    if "kappa_per_m" in axes and "bend_deg" in axes:
        raise RunRefused(f"{where}: give the curvatures as kappa_per_m or as bend_deg, not both")
    default = validation_grid(params)
    kappas = ([kappa(k, v) for k in ("kappa_per_m", "bend_deg") if k in axes for v in axes[k]]
              or list(dict.fromkeys(row[1] for row in default)))
    phis = axes.get("phi_deg") or list(dict.fromkeys(row[2] for row in default))
    masses = axes.get("tip_mass_kg") or list(dict.fromkeys(row[3] for row in default))
    rows = [(k, p, m) for k in kappas for p in phis for m in masses]
    return [(i, *row) for i, row in enumerate(rows)]


def _run_folder(args, command: str, experiment: str, params) -> Path:
    """The run folder: ``--resume``'s once checked, else a new one."""
    # Checked before a run folder exists: a bad hidden setting should not leave one behind.
    try:
        twin_params(args, params)
    except UsageError as exc:
        raise RunRefused(str(exc)) from None
    if args.calibration:
        # Checked before a run folder exists: a typo should not cost a folder or a pretension.
        from twin.calibration import CalibrationFileError, load_calibration

        try:
            cal = load_calibration(args.calibration)
        except OSError as exc:
            raise RunRefused(f"--calibration {args.calibration}: cannot read it ({exc.strerror or exc})") from None
        except CalibrationFileError as exc:
            raise RunRefused(f"--calibration {args.calibration}: {exc}") from None
        _check_channels(args, cal, params)
    if getattr(args, "grid", None):
        grid_from_arg(args.grid, params)  # a bad --grid is refused before a run folder exists
    if getattr(args, "resume", None):
        return _check_resume(args, command, experiment, params)
    return _start_run(args, command)


def _check_channels(args, cal, params) -> None:
    """Refuse a calibration file of another channel count than the robot's tendons.

    Raises:
        RunRefused: one line naming the file, its channels and the robot's tendons.
    """
    if len(cal.channels) != params.tendons.count:
        raise RunRefused(f"--calibration {args.calibration}: {len(cal.channels)} channels; robot "
                         f"{robot_name(args)!r} has {params.tendons.count} tendons")


def _run(args, command: str, experiment: str, body) -> int:
    """The frame of a measuring command: the run folder (new, or ``--resume``'s once checked), then
    ``body(folder, params)``, which returns the exit code. A run that cannot start or resume as
    asked ends with 2; one stopped by the device, the protocol, a refused row or an I/O error (a
    full disk) ends with 4, and Ctrl-C with 130, each after one line saying why and the command
    line that continues the run."""
    from twin.data.dataset import DatasetError
    from twin.driver.errors import DeviceError
    from twin.experiments.protocols import ProtocolError
    from twin.resources import NativeBuildError
    from twin.sim.plant import SimulationError

    params = params_from_args(args)
    try:
        folder = _run_folder(args, command, experiment, params)
        try:
            return body(folder, params)
        except (RunRefused, NativeBuildError):
            # Refused, or no compiler for the twin: nothing was measured, so no folder stays.
            _discard_if_empty(args, folder)
            raise
        except (ProtocolError, DeviceError, SimulationError, DatasetError, OSError) as exc:
            # OSError: a full disk or another I/O error; the dataset writer left every complete row readable.
            _stopped(command, folder, args, exc)
            return 4
        except KeyboardInterrupt as exc:
            _stopped(command, folder, args, exc)
            return 130
        except BaseException:
            # Anything else (bad input found late, a bug): a new run that measured nothing leaves no folder.
            _discard_if_empty(args, folder)
            raise
    except RunRefused as exc:
        print(f"twin {command}: {exc}", file=sys.stderr)
        return 2


def run_validate(args: argparse.Namespace) -> int:
    return _run(args, "validate", "validation", lambda folder, params: _validate(args, folder, params))


def _validate(args, folder: Path, params) -> int:
    from twin.data.dataset import RUN_DATASET, read_dataset
    from twin.experiments.analysis import analyse_validation
    from twin.experiments.protocols import run_validation, tripped_before, unrealisable
    from twin.experiments.report import write_validation_report
    from twin.live import LiveDevice, live_view_from_args

    grid = grid_from_arg(args.grid, params)
    if args.quick:
        grid = quick_grid(grid)
    start = time.perf_counter()
    device = _open(args, params)
    view = live_view_from_args(args, params, base_rotation=device.base_rotation, command="validate")
    try:
        left_out = unrealisable(grid, params, device.base_rotation)
        known = {e["config"] for e in left_out}
        left_out += [e for e in tripped_before(folder / RUN_DATASET) if e["config"] not in known]
        print(f"twin validate: {len(grid) - len(left_out)} configurations on {args.device}, run folder {folder}",
              file=sys.stderr)
        for reason, entries in _by_reason(left_out).items():
            print(f"twin validate: {len(entries)} of the grid's {len(grid)} configurations left out: robot "
                  f"{robot_name(args)!r} {reason}: {_configurations(entries)}", file=sys.stderr)
        calibration = _calibration(args, params, device)
        run_validation(device if view is None else LiveDevice(device, view), folder / RUN_DATASET, params,
                       grid=grid, calibration=calibration, robot=robot_name(args))
        pose = device.base_rotation
    finally:
        device.close()
        if view is not None:
            view.close()
    sweep_s = time.perf_counter() - start
    dataset = read_dataset(folder / RUN_DATASET)
    left_out = dataset.metadata.get("left_out", [])  # with the configurations that tripped the limit
    if len(dataset) == 0:
        print(f"twin validate: no configuration was measured: all {len(left_out)} left out (listed in "
              f"{folder / RUN_DATASET}/metadata.json); nothing to predict", file=sys.stderr)
        return 4
    result = analyse_validation(dataset, params, progress=True)
    picture = _picture(args, params, folder, pose)
    path = write_validation_report(result, folder, picture=picture, warnings=_twin_warnings(args, params),
                                   facts={"sweep_wall_time_s": sweep_s, "device": args.device,
                                          "robot": robot_name(args)})
    s = result.summary()
    print(f"sweep {sweep_s:.1f} s wall; {s['rows']} configurations, {s['failed_predictions']} failed predictions; "
          f"prediction error median {s['median_error_mm']:.3f} mm, RMS {s['rms_error_mm']:.3f} mm, "
          f"worst {s['worst_error_mm']:.3f} mm")
    if left_out:
        print(f"left out: {len(left_out)} configurations robot {robot_name(args)!r} cannot realise or hold (listed "
              "with the reason in the report and the dataset's metadata)")
    print(f"report: {path}")
    return 0


def _by_reason(entries) -> dict:
    """Left-out configurations grouped by their reason, as the command line words it."""
    from twin.experiments.protocols import TRIPPED, UNREALISABLE

    groups: dict[str, list] = {}
    for entry in entries:
        reason = entry["reason"]
        said = ("cannot realise them, " + reason if reason == UNREALISABLE else
                "cannot hold them: " + (TRIPPED if reason.startswith(TRIPPED) else reason))
        groups.setdefault(said, []).append(entry)
    return groups


# Left-out configurations a command line names one by one (the report lists them all).
_SHOWN_CONFIGURATIONS = 8


def _configurations(entries) -> str:
    """Grid configurations as a short list: ``config (κ, φ, mass)`` each, the first few."""
    shown = ", ".join(f"{e['config']} (κ {e['kappa_cmd_per_m']:g} 1/m, φ {e['phi_cmd_deg']:g}°, "
                      f"{e['tip_mass_kg'] * 1e3:g} g)" for e in entries[:_SHOWN_CONFIGURATIONS])
    more = len(entries) - _SHOWN_CONFIGURATIONS
    return shown + (f" and {more} more" if more > 0 else "")


def _picture(args, params, folder: Path, base_rotation) -> Path | None:
    """A rendered picture of the bent twin, in the device's pose, for the report (sim only; None
    with a note when no GL)."""
    if not args.device.startswith("sim://"):
        return None
    try:
        from twin.rod.grid import pcc_tensions_n
        from twin.sim import Plant
        from twin.sim.render import render_png

        plant = Plant(params, base_rotation=base_rotation)
        # The grid's second-largest curvature (17.5 1/m on the thesis's 60 mm).
        kappa = sorted({row[1] for row in validation_grid(params)})[-2]
        plant.set_tensions(pcc_tensions_n(kappa, 30.0, params))
        plant.settle()
        path = folder / "figures" / "endoscope.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        render_png(plant, path, labelled=True, title=f"the twin at κ {kappa:g} 1/m, φ 30°, no tip mass")
        return path
    except Exception as exc:  # rendering is a nicety: report why it is missing, keep the run
        print(f"twin validate: no picture of the endoscope ({exc})", file=sys.stderr)
        return None


def run_stiffness_cmd(args: argparse.Namespace) -> int:
    return _run(args, "stiffness", "stiffness", lambda folder, params: _stiffness(args, folder, params))


def _stiffness(args, folder: Path, params) -> int:
    from twin.data.dataset import RUN_DATASET, read_dataset
    from twin.experiments.protocols import run_stiffness
    from twin.data.fitting import fit_determined
    from twin.experiments.stiffness import MODULI, PIN_SHEAR, fit_stiffness, plot_error_surface

    device = _open(args, params)
    try:
        _calibration(args, params, device)
        run_stiffness(device, folder / RUN_DATASET, params, robot=robot_name(args))
    finally:
        device.close()
    dataset = read_dataset(folder / RUN_DATASET)
    result = fit_stiffness(dataset, params)
    plot_error_surface(result, folder / "error_surface.png")
    # A modulus whose profile interval stays open is as undetermined as one the Jacobian gives up on.
    loose = set(result.fit.undetermined()) | {i for i, p in enumerate(result.profile) if not p.identifiable}
    for i, (row, interval) in enumerate(zip(result.fit.table(), result.profile)):
        note = "  NOT IDENTIFIABLE from these data" if i in loose else ""
        print(f"{row['parameter']:28s} {row['value']:.5g}  (95% profile: {interval.describe()}){note}")
    print(f"correlation E-G {result.fit.correlation[0, 1]:+.3f}; tip RMS {result.fit.rms_m * 1e3:.3f} mm")
    if any(result.profile[i].parameter == "backbone.shear_modulus_pa" for i in loose):
        print(f"twin stiffness: the sag under tip masses does not pin G; {PIN_SHEAR} would", file=sys.stderr)
    # What the data leave undetermined keeps its value in the parameter set, never a fitted one.
    fit, dropped = fit_determined(dataset, params, [p for i, p in enumerate(MODULI) if i not in loose]) \
        if loose else (result.fit, [])
    dropped += [(MODULI[i], float(result.fit.values[i]), float(result.fit.std_errors[i])) for i in sorted(loose)
                if all(d[0] != MODULI[i] for d in dropped)]
    for p, value, std in dropped:
        print(f"twin stiffness: {p.label} is not determined by these data (fit {value:.4g} ± {std:.2g}); "
              f"the parameter file keeps {params.get(p.key)!r} ({params.source(p.key) or 'no source'})",
              file=sys.stderr)
    if fit is None:
        print("twin stiffness: nothing is determined; no fitted parameter file written", file=sys.stderr)
        return 3
    fit.params.save(folder / "fitted_params.toml")
    print(f"fitted parameter file: {folder / 'fitted_params.toml'} "
          f"({', '.join(p.label for p in fit.parameters)} fitted)")
    return 3 if dropped else 0


def _print_calibration(cal) -> None:
    print(f"{'channel':>7} {'gain counts/N':>14} {'± SE':>8} {'offset counts':>14} {'± SE':>8} {'R^2':>9} "
          f"{'max resid N':>11}")
    for i, ch in enumerate(cal.channels):
        print(f"{i + 1:>7} {ch.gain_counts_per_n:14.1f} {ch.gain_se_counts_per_n:8.2f} {ch.offset_counts:14.1f} "
              f"{ch.offset_se_counts:8.2f} {ch.r_squared:9.6f} {ch.max_residual_n:11.4f}")


def run_calibrate_cmd(args: argparse.Namespace) -> int:
    from twin.calibration import Calibration, check, fit_all, load_calibration, tensions_from_masses_n
    from twin.experiments.protocols import calibrate_device

    path = Path(args.file)
    if args.refit:
        old = load_calibration(path)
        fits = fit_all(old.raw_counts, old.tensions_n)
        cal = Calibration.from_fits(fits, old.raw_counts, masses_g=old.masses_g, gravity_m_s2=old.gravity_m_s2,
                                    samples_per_mass=old.samples_per_mass, device=old.device)
        cal.save(path)
        _print_calibration(cal)
        print(f"refitted {path}")
        return 0
    params = params_from_args(args)
    try:
        device = _open(args, params)
    except RunRefused as exc:
        print(f"twin calibrate: {exc}", file=sys.stderr)
        return 2
    try:
        if args.check:
            cal = load_calibration(path)
            if len(cal.channels) != params.tendons.count:
                print(f"twin calibrate: --file {path}: {len(cal.channels)} channels; robot {robot_name(args)!r} has "
                      f"{params.tendons.count} tendons", file=sys.stderr)
                return 2
            masses = (0.0, 50.0, 150.0, 250.0)
            raw = []
            for m in masses:
                device.fixture.hang_calibration_mass(m, range(params.tendons.count))
                raw.append(sum(device.wait_next().raw_counts.astype(float) for _ in range(args.samples)) / args.samples)
            device.fixture.remove_calibration_masses()
            result = check(cal, raw, tensions_from_masses_n(masses, params.environment.gravity_m_s2))
            for i, (err, ok) in enumerate(zip(result.max_abs_error_n, result.channel_passed)):
                print(f"channel {i + 1}: largest error {err * 1e3:.1f} mN ({'pass' if ok else 'FAIL'})")
            return 0 if result.passed else 5
        cal = calibrate_device(device, params, samples_per_mass=args.samples)
    finally:
        device.close()
    cal.save(path)
    _print_calibration(cal)
    print(f"calibration written to {path}")
    return 0
