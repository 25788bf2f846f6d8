"""``twin validate`` (the main job), ``twin stiffness`` and ``twin calibrate``: experiments on a device."""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path

from twin.cliargs import add_param_args, params_from_args
from twin.params import parse_override
from twin.pcc import validation_grid
from twin.pose import HORIZONTAL


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
                   help="a 24-configuration subset (kappa 0/13/26.2, phi 0/90/180/270, 0 and 10 g) for a fast look")
    v.add_argument("--resume", metavar="RUN_DIR", help="continue an interrupted run in this folder")
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

    s = sub.add_parser("stiffness", help="stiffness characterisation (thesis 8.2): fit E and G on a device")
    _device_args(s)
    s.set_defaults(func=run_stiffness_cmd)


def _device_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default="sim://", metavar="URL", help="sim:// (default) or serial:///dev/ttyACM0")
    p.add_argument("--out", default="runs", metavar="DIR", help="parent folder of the run folder (default runs)")
    p.add_argument("--calibration", metavar="FILE", help="load-cell calibration file (default: the parameter set's)")
    p.add_argument("--twin-set", dest="twin_overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="sim:// only: change the simulated rig but not the model (a hidden effect), repeatable")
    p.add_argument("--seed", type=int, default=None, help="sim:// noise seed")
    add_param_args(p)


def _open(args, params):
    from twin.device import open_device

    twin_params = params
    if args.twin_overrides:
        if not args.device.startswith("sim://"):
            raise SystemExit("twin: --twin-set applies to sim:// only")
        twin_params = params.replace(dict(parse_override(o) for o in args.twin_overrides), source="twin-set (hidden)")
    device = open_device(args.device, params=twin_params, seed=args.seed)
    device.connect()
    return device


def _calibration(args, params, device) -> dict:
    from twin.experiments.protocols import nominal_calibration

    if args.calibration:
        from twin.calibration import load_calibration

        cal = load_calibration(args.calibration)
        device.set_calibration(cal)
        return {**cal.to_dict(), "file": str(args.calibration)}
    cal = nominal_calibration(params)
    device.set_calibration(gain_counts_per_n=cal["gain_counts_per_n"], offset_counts=cal["offset_counts"])
    return cal


def _run_folder(args, name: str) -> Path:
    if getattr(args, "resume", None):
        return Path(args.resume)
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    folder = Path(args.out) / f"{name}-{stamp}"
    folder.mkdir(parents=True, exist_ok=False)
    return folder


def run_validate(args: argparse.Namespace) -> int:
    from twin.experiments.analysis import analyse_validation
    from twin.data.dataset import RUN_DATASET, read_dataset
    from twin.device.errors import DeviceError
    from twin.experiments.protocols import ProtocolError, run_validation
    from twin.experiments.report import write_validation_report
    from twin.sim.plant import SimulationError

    params = params_from_args(args)
    folder = _run_folder(args, "validate")
    grid = validation_grid()
    if args.quick:
        grid = [g for g in grid if g[1] in (0.0, 13.0, 26.2) and g[2] in (0.0, 90.0, 180.0, 270.0) and g[3] != 0.005]
    if args.twin_overrides:
        # The hidden truth stays out of the dataset folder, so analyses see only what a lab would.
        (folder / "twin_truth.json").write_text(json.dumps({"twin_set": args.twin_overrides}, indent=1))
    print(f"twin validate: {len(grid)} configurations on {args.device}, run folder {folder}", file=sys.stderr)
    start = time.perf_counter()
    device = _open(args, params)
    try:
        calibration = _calibration(args, params, device)
        run_validation(device, folder / RUN_DATASET, params, grid=grid, calibration=calibration)
    except (ProtocolError, DeviceError, SimulationError) as exc:
        print(f"twin validate: stopped: {type(exc).__name__}: {exc}. Every measurement so far is in "
              f"{folder / RUN_DATASET}; continue with --resume {folder}", file=sys.stderr)
        return 4
    finally:
        device.close()
    sweep_s = time.perf_counter() - start
    dataset = read_dataset(folder / RUN_DATASET)
    result = analyse_validation(dataset, params, progress=True)
    picture = _picture(args, params, folder)
    path = write_validation_report(result, folder, picture=picture,
                                   facts={"sweep_wall_time_s": sweep_s, "device": args.device})
    s = result.summary()
    print(f"sweep {sweep_s:.1f} s wall; {s['rows']} configurations, {s['failed_predictions']} failed predictions; "
          f"prediction error median {s['median_error_mm']:.3f} mm, RMS {s['rms_error_mm']:.3f} mm, "
          f"worst {s['worst_error_mm']:.3f} mm")
    print(f"report: {path}")
    return 0


def _picture(args, params, folder: Path) -> Path | None:
    """A rendered picture of the bent twin for the report (sim only; None with a note when no GL)."""
    if not args.device.startswith("sim://"):
        return None
    try:
        from twin.rod.grid import pcc_tensions_n
        from twin.sim import Plant
        from twin.sim.render import render_png

        plant = Plant(params, base_rotation=HORIZONTAL)
        plant.set_tensions(pcc_tensions_n(17.5, 30.0, params))
        plant.settle()
        path = folder / "figures" / "endoscope.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        render_png(plant, path)
        return path
    except Exception as exc:  # rendering is a nicety: report why it is missing, keep the run
        print(f"twin validate: no picture of the endoscope ({exc})", file=sys.stderr)
        return None


def run_stiffness_cmd(args: argparse.Namespace) -> int:
    from twin.data.dataset import RUN_DATASET, read_dataset
    from twin.experiments.protocols import run_stiffness
    from twin.experiments.stiffness import fit_stiffness, plot_error_surface

    params = params_from_args(args)
    folder = _run_folder(args, "stiffness")
    device = _open(args, params)
    try:
        _calibration(args, params, device)
        run_stiffness(device, folder / RUN_DATASET, params)
    finally:
        device.close()
    result = fit_stiffness(read_dataset(folder / RUN_DATASET), params)
    plot_error_surface(result, folder / "error_surface.png")
    result.fit.params.save(folder / "fitted_params.toml")
    for row in result.fit.table():
        print(f"{row['parameter']:28s} {row['value']:.5g}  ± {row['std_error']:.2g}  "
              f"(95%: {row['ci95_low']:.4g} … {row['ci95_high']:.4g})")
    print(f"correlation E-G {result.fit.correlation[0, 1]:+.3f}; tip RMS {result.fit.rms_m * 1e3:.3f} mm")
    print(f"fitted parameter file: {folder / 'fitted_params.toml'}")
    return 0


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
    device = _open(args, params)
    try:
        if args.check:
            cal = load_calibration(path)
            masses = (0.0, 50.0, 150.0, 250.0)
            raw = []
            for m in masses:
                device.fixture.hang_calibration_mass(m, range(4))
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
