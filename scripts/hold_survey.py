"""Tension mode holding commanded tensions in bent poses on every zoo robot under tendon friction.

``twin bench hold`` measures one mid bend per robot; this looks further: per robot and μ, the
most bent pose of the compensation grid (κ·L = 90°) in two planes and a 60° bend between two
tendons, a 10 g tip mass, and four commands each (:func:`twin.control.settling.hold_commanded`):
``held`` the tensions measured at the switch to tension mode, and ``U/L`` the upper half of them
(the tendons bending the rod) at U and the lower half at L times the duty clamp's pull (a
compensation's command near its ceiling: long's that cycled was 0.95/0.37-0.46, and
0.84/0.37-0.46 rang most). One line per hold: the worst
channel's true tension peak to peak (every 5 ms tick), that of its 0.1 s means, and its mean
offset from the setpoint (N), beside the goals (0.05 N, 0.02 N); exit 1 when a hold misses one.

    PYTHONPATH=. python scripts/hold_survey.py [--robots long,helical] [--mu 0.1,0.3] [--kinds held,0.95/0.4] [--seed 1] [--jobs 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

ROBOTS = ("endoscope", "endoscope-soft-g", "helical", "long", "stiff-long", "three-tendon", "two-segment")
# The goals of twin bench hold (twin/bench.py): peak to peak of the held tension, mean offset (N).
PTP_GOAL_N = 0.05
OFFSET_GOAL_N = 0.02
# The tip mass (kg): the compensation grid's heaviest (twin.pcc.GRID_TIP_MASS_KG).
MASS_KG = 0.010
# The commands beside ``held``: (upper, lower) shares of the duty clamp's pull, around long's
# that cycled at 20 Hz (5.115 N of the clamp's 5.385 N against 2.0 / 2.5 N).
COMMANDS = ("held", "0.95/0.4", "0.85/0.4", "0.95/0.2")
# How long a hold may take to stop after its 2 s (s): a command that bends the rod on slides it at
# the clamp's pull for several seconds (long at 0.95/0.2, μ = 0.1: 1.6 mm still moving at 4 s).
STILL_TIMEOUT_S = 10.0


def poses(params):
    """(κ 1/m, φ deg) of the survey: the grid's bends of 90° in two planes, 60° between tendons."""
    from twin.pcc import GRID_KAPPA_PER_M, THESIS_LENGTH_M

    scale = THESIS_LENGTH_M / params.backbone.length_m
    most, second = GRID_KAPPA_PER_M[-1] * scale, GRID_KAPPA_PER_M[-2] * scale
    return [(most, 0.0), (most, 270.0), (second, 45.0)]


def command(kind, clamp_n):
    def make(start):
        if kind == "held":
            return start
        upper_share, lower_share = (float(v) for v in kind.split("/"))
        return np.where(start >= np.median(start), upper_share, lower_share) * clamp_n
    return make


def one(job):
    robot, mu, kappa, phi, kind, seed = job
    from twin.control.gains import tension_gains_for
    from twin.control.settling import hold_commanded
    from twin.robots import load_robot

    params = load_robot(robot)
    gains = tension_gains_for(params)
    clamp_n = gains["output_limit"] * params.rig.motor_stall_force_n
    t0 = time.process_time()
    hold = hold_commanded(params, command(kind, clamp_n), kappa_per_m=kappa, phi_deg=phi, mass_kg=MASS_KG,
                          twin_params=params.replace({"effects.tendon_friction_coeff": mu}), robot=robot, seed=seed,
                          still_timeout_s=STILL_TIMEOUT_S)
    f = hold.figures()
    return {"robot": robot, "mu": mu, "kappa": kappa, "phi": phi, "kind": kind, "ptp": float(f["ptp_n"].max()),
            "mean_ptp": float(f["mean_ptp_n"].max()), "offset": float(np.abs(f["offset_n"]).max()),
            "setpoints": np.round(hold.setpoints_n, 3).tolist(), "faults": hold.fault_flags,
            "settled_s": hold.settled_s, "spool_um": float(hold.spool_ptp_m.max() * 1e6),
            "cpu_s": time.process_time() - t0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", default=",".join(ROBOTS))
    ap.add_argument("--mu", default="0.1,0.3")
    ap.add_argument("--kinds", default=",".join(COMMANDS))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args(argv)
    from twin.robots import load_robot

    robots = a.robots.split(",")
    for r in robots:
        if r not in ROBOTS:
            print(f"hold_survey: --robots {r}: not a zoo robot ({', '.join(ROBOTS)})", file=sys.stderr)
            return 2
    try:
        mus = [float(mu) for mu in a.mu.split(",")]
    except ValueError:
        print(f"hold_survey: --mu {a.mu}: not a comma-separated list of numbers", file=sys.stderr)
        return 2
    kinds = a.kinds.split(",")
    for kind in kinds:
        try:
            command(kind, 1.0)(np.ones(2))
        except ValueError:
            print(f"hold_survey: --kinds {kind}: neither 'held' nor UPPER/LOWER shares such as 0.95/0.4", file=sys.stderr)
            return 2
    jobs = [(r, mu, k, p, kind, a.seed) for r in robots for mu in mus
            for k, p in poses(load_robot(r)) for kind in kinds]
    missed = 0
    with ProcessPoolExecutor(a.jobs) as pool:
        for row in pool.map(one, jobs):
            bad = row["mean_ptp"] > PTP_GOAL_N or row["offset"] > OFFSET_GOAL_N or row["faults"]
            missed += bool(bad)
            print(f"{row['robot']:17s} mu {row['mu']:.1f} k {row['kappa']:6.2f} phi {row['phi']:5.1f} {row['kind']:8s} "
                  f"ptp {row['ptp']:.3f} means_ptp {row['mean_ptp']:.3f} offset {row['offset']:.3f} "
                  f"faults {row['faults']} settled {row['settled_s']:.1f} s spool {row['spool_um']:.0f} um sp {row['setpoints']} cpu {row['cpu_s']:.1f}{'  MISSED' if bad else ''}",
                  flush=True)
    print(f"{missed} of {len(jobs)} holds missed a goal")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
