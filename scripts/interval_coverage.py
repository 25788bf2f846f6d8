"""Coverage of the fitted values' 95 % intervals on hidden cases made by the twin.

Each case hides one effect of the library, at a size drawn (seeded) from a range, in the MuJoCo
twin only, sweeps a sixth of the thesis grid on it through the device interface (the real
firmware, load-cell and tracker noise on; the grid's smallest, middle and largest curvature,
every other plane, no and the heaviest tip mass: 36 configurations) and fits that effect's own
candidate (:mod:`twin.discrepancy.candidates`) to every row with
:func:`twin.data.fitting.fit_parameters`. A parameter is covered when the truth lies within the
interval. The twin is not the predictor: what their model forms differ by (reports/crosscheck)
is in every case's fit, which statistical intervals leave out.

Two intervals are measured: the statistical one (± 1.96 standard errors from σ²(JᵀJ)⁻¹) and the
one the discrepancy workflow reports (:func:`twin.discrepancy.uncertainty.honest_uncertainty`:
± 1.96 √(se² + split scatter² + model form² + model-form shift²), the scatter over ``--splits``
halves of the configurations, the model-form term at the workflow's default level, the shift
what the twin's own difference from the predictor at the sweep's configurations moves the value by).

Usage: python scripts/interval_coverage.py [N] [--seed S] [--splits K] [--robot NAME] [--effects E,...]
                                          [--every-plane]
  N cases (default 12), case sizes and twin noise seeded from S (default 0), K halves (default 4),
  the robot of models/ (default endoscope), the effects to hide in turn (default all of RANGES);
  --every-plane sweeps every plane of the three curvatures (72 configurations): more than the
  model-form term counts as independent (:data:`twin.discrepancy.uncertainty.PATTERNS`), so the
  cap on them is measured too (the honest interval's coverage without it is printed beside).
  The honest interval's coverage without the model-form shift is printed too.
Prints one row per case (truth, fit ± standard error, split scatter, model-form term, error in
standard errors and in the honest uncertainty's, model-form shift; a sweep the twin cannot bring
to rest is said and not counted) and the coverage per effect and overall of both intervals;
exits 1 when the honest interval's coverage is below 90 % or no case was measured.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from twin.data.dataset import read_dataset
from twin.data.fitting import fit_parameters
from twin.driver import open_device
from twin.discrepancy.candidates import candidate_library
from twin.discrepancy.noise import configuration_keys
from twin.discrepancy.uncertainty import LEVEL_SIGMA, PATTERNS, honest_uncertainty, model_form_reference
from twin.discrepancy.workflow import MODEL_FORM_M
from twin.experiments.protocols import ProtocolError, nominal_calibration, run_validation
from twin.pcc import validation_grid
from twin.robots import load_robot
from twin.sim.plant import SimulationError

# Effect → (key, the hidden value drawn from a uniform range per entry, as a fraction of the
# robot's nominal value where marked "rel"). Sizes: the hidden cases (weight 7.5 g of
# the endoscope's 6 g, tilt 1.2°, tracker 0.8 mm, friction μ 0.1 and 0.3) and around them.
RANGES = {
    "weight": ("backbone.mass_kg", "rel", [(1.1, 1.4)]),
    "base_tilt": ("effects.base_tilt_deg", "abs", [(-1.5, 1.5), (-1.5, 1.5)]),
    "tracker_offset": ("effects.tracker_offset_m", "abs", [(-0.0015, 0.0015)] * 3),
    "tendon_friction": ("effects.tendon_friction_coeff", "abs", [(0.05, 0.3)]),
}
GOAL = 0.90


def coverage_grid(params, every_plane: bool = False):
    """A sixth of the robot's thesis grid: its smallest, middle and largest curvature, every
    other plane (0, 60, … 300°; with ``every_plane`` all of them, a third), no and the heaviest
    tip mass."""
    grid = validation_grid(params)
    kappas = sorted({g[1] for g in grid})
    chosen = {kappas[0], kappas[len(kappas) // 2], kappas[-1]}
    heaviest = max(g[3] for g in grid)
    step = 30 if every_plane else 60
    return [g for g in grid if g[1] in chosen and g[2] % step == 0 and g[3] in (0.0, heaviest)]


def sweep(folder: Path, model, hidden: dict, seed: int, every_plane: bool = False):
    """The coverage grid swept on the twin of ``model`` with ``hidden`` set (only there)."""
    truth = model.replace(hidden, source="hidden")
    with open_device(f"sim://?seed={seed}", params=truth) as device:
        cal = nominal_calibration(model)
        device.set_calibration(gain_counts_per_n=cal["gain_counts_per_n"], offset_counts=cal["offset_counts"])
        run_validation(device, folder, model, grid=coverage_grid(model, every_plane), progress=False)
    return read_dataset(folder)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="?", type=int, default=12)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--splits", type=int, default=4)
    parser.add_argument("--robot", default="endoscope")
    parser.add_argument("--effects", default=",".join(sorted(RANGES)))
    parser.add_argument("--every-plane", action="store_true")
    args = parser.parse_args(argv)
    if args.cases < 1:
        print(f"interval_coverage: N {args.cases}: must be >= 1", file=sys.stderr)
        return 2
    if args.splits < 2:
        print(f"interval_coverage: --splits {args.splits}: must be >= 2", file=sys.stderr)
        return 2
    names = [n.strip() for n in args.effects.split(",") if n.strip()]
    unknown = [n for n in names if n not in RANGES]
    if unknown or not names:
        print(f"interval_coverage: --effects {args.effects!r}: expected some of {', '.join(sorted(RANGES))}",
              file=sys.stderr)
        return 2
    try:
        model = load_robot(args.robot)
    except Exception as exc:  # an unknown robot or a bad file: one line
        print(f"interval_coverage: --robot {args.robot!r}: {exc}", file=sys.stderr)
        return 2
    from twin.discrepancy.residuals import find_discrepancy

    rng = np.random.default_rng(args.seed)
    library = candidate_library(model)
    covered: dict[str, list[bool]] = {n: [] for n in names}
    honest: dict[str, list[bool]] = {n: [] for n in names}
    uncapped: list[bool] = []  # the honest interval with every configuration counted independent
    unshifted: list[bool] = []  # the honest interval without the model-form shift
    failed: list[int] = []
    cpu_start = time.process_time()
    print(f"robot {args.robot}, seed {args.seed}, {args.splits} halves")
    print()
    print("| case | effect | truth | fit ± standard error | split scatter | model form | error (se) | covered "
          "| error (u) | honest covers | model-form shift |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for case in tqdm(range(args.cases), desc="hidden cases", unit="case", file=sys.stderr):
        effect = names[case % len(names)]
        key, kind, ranges = RANGES[effect]
        truth = [float(rng.uniform(lo, hi)) for lo, hi in ranges]
        if kind == "rel":
            truth = [t * float(model.get(key)) for t in truth]
        hidden = {key: truth[0] if len(ranges) == 1 else truth}
        with tempfile.TemporaryDirectory() as folder:
            try:
                data = sweep(Path(folder) / "sweep", model, hidden, seed=args.seed * 1000 + case,
                             every_plane=args.every_plane)
            except (ProtocolError, SimulationError) as exc:
                # The twin that cannot bring this case to rest measures nothing: said, not counted.
                failed.append(case)
                print(f"| {case} | {effect} | {', '.join(f'{t:.5g}' for t in truth)} | sweep failed: "
                      f"{str(exc).splitlines()[0][:120]} | | | | | | | |", flush=True)
                continue
        candidate = library[effect]
        parameters = list(candidate.parameters)
        # From where the workflow starts the candidate (friction, off in the model: at 0.02).
        fit = fit_parameters(data, model, parameters, x0=candidate.x0(model), max_evaluations=25)
        # As the workflow: the structure the fitted model leaves, judged at the data's noise.
        before = find_discrepancy(data, model)
        after = find_discrepancy(data, fit.params, noise=before.noise)
        left = after.structure.structured_rms_m if after.structure.beyond_noise else 0.0
        uncertainty = honest_uncertainty(data, fit, model_form_m=MODEL_FORM_M, structured_rms_m=left,
                                         splits=args.splits, reference_errors_m=model_form_reference(data, model))
        configurations = len(np.unique(configuration_keys(data)))
        for p, u in zip(parameters, uncertainty):
            if p.key != key:  # a parameter the candidate fits along (the truth leaves it nominal)
                continue
            true = truth[p.index] if p.index is not None else truth[0]
            z = (u.value - true) / u.std_error if u.std_error > 0 else float("inf")
            z_honest = (u.value - true) / u.total if u.total > 0 else float("inf")
            covered[effect].append(abs(z) <= LEVEL_SIGMA)
            honest[effect].append(abs(z_honest) <= LEVEL_SIGMA)
            form = u.model_form * np.sqrt(min(configurations, PATTERNS) / configurations)
            scatter = u.split_scatter if np.isfinite(u.split_scatter) else 0.0
            shift = u.model_form_shift if np.isfinite(u.model_form_shift) else 0.0
            uncapped.append(abs(u.value - true) <= LEVEL_SIGMA * np.sqrt(u.std_error**2 + scatter**2 + form**2
                                                                         + shift**2))
            unshifted.append(abs(u.value - true) <= LEVEL_SIGMA * np.sqrt(u.total**2 - shift**2))
            print(f"| {case} | {effect} | {true:.5g} | {u.value:.5g} ± {u.std_error:.2g} | {u.split_scatter:.2g} | "
                  f"{u.model_form:.2g} | {z:+.1f} | {'yes' if covered[effect][-1] else 'no'} | {z_honest:+.1f} | "
                  f"{'yes' if honest[effect][-1] else 'no'} | {u.model_form_shift:+.2g} |", flush=True)
    print()
    for n in names:
        if covered[n]:
            print(f"{n}: {sum(covered[n])} of {len(covered[n])} parameters covered by ± 1.96 se, "
                  f"{sum(honest[n])} by the honest interval")
    if failed:
        print(f"{len(failed)} of {args.cases} sweeps failed (cases {', '.join(map(str, failed))}): not counted")
    if not any(covered.values()):
        print("no case was measured")
        return 1
    share = np.mean([c for n in names for c in covered[n]])
    share_honest = np.mean([c for n in names for c in honest[n]])
    print(f"without the model-form shift the honest interval covers {sum(unshifted)} of {len(unshifted)}")
    if args.every_plane:
        print(f"without the cap at {PATTERNS} configurations the honest interval covers {sum(uncapped)} "
              f"of {len(uncapped)}")
    print(f"coverage of the 95 % intervals over {sum(len(c) for c in covered.values())} parameters: {share:.0%} "
          f"statistical, {share_honest:.0%} honest (goal {GOAL:.0%}); "
          f"{time.process_time() - cpu_start:.0f} s CPU")
    return 0 if share_honest >= GOAL else 1


if __name__ == "__main__":
    sys.exit(main())
