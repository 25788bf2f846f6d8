"""Make docs/examples/lab-poses.csv: a lab's measurements as another lab would keep them, taken
on the twin so that the worked example of docs/import.md can be checked.

The three-tendon robot of the zoo, clamped horizontally with the clamp turned 2° about the world
x axis (a hidden base tilt the model does not know); free poses off any grid: random tensions per
tendon in tension mode, each under 0 g and 10 g. Written as a lab's tracker and DAQ would: tip in
millimetres, raw load-cell counts (the robot's nominal calibration), tip mass in grams, its own
column names, no tendon lengths and no commanded bend.

    python scripts/make_lab_example.py [--poses 20] [--out docs/examples/lab-poses.csv]
"""

from __future__ import annotations

import argparse
import csv

import numpy as np

from twin.driver import open_device
from twin.experiments.protocols import apply_calibration, measure, nominal_calibration, pretension, wait_for_rest
from twin.robots import load_robot

# The hidden effect of the example (deg about world x, y): what the discrepancy workflow should name.
HIDDEN_TILT_DEG = [2.0, 0.0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=20)
    parser.add_argument("--out", default="docs/examples/lab-poses.csv")
    args = parser.parse_args()
    params = load_robot("three-tendon")
    rng = np.random.default_rng(7)
    twin = params.replace({"effects.base_tilt_deg": HIDDEN_TILT_DEG}, source="hidden (make_lab_example.py)")
    s = params.sensors
    rows = []
    with open_device("sim://?seed=7", params=twin) as device:
        apply_calibration(device, nominal_calibration(params))
        for pose in range(1, args.poses + 1):
            device.disable()
            pretension(device, params, mode="tensions", settle_s=0.3)
            device.fixture.release_holder()
            device.set_tensions(rng.uniform(0.8, 3.5, params.tendons.count))
            for mass_g in (0.0, 10.0):
                device.fixture.hang_tip_mass(mass_g * 1e-3)
                wait_for_rest(device, timeout_s=10.0)
                m = measure(device)
                counts = np.asarray(s.loadcell_offset_counts) + s.loadcell_gain_counts_per_n * m.tensions_n
                rows.append({"pose_id": pose, "load_g": mass_g,
                             **{f"cell{k + 1}_raw": round(float(c)) for k, c in enumerate(counts)},
                             "X [mm]": round(float(m.tip_position_m[0] * 1e3), 4),
                             "Y [mm]": round(float(m.tip_position_m[1] * 1e3), 4),
                             "Z [mm]": round(float(m.tip_position_m[2] * 1e3), 4)})
            device.fixture.hang_tip_mass(0.0)
    with open(args.out, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"{len(rows)} rows -> {args.out}")


if __name__ == "__main__":
    main()
