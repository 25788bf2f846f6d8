"""The thesis's error signatures (§9.2, §9.2.1) beside the signature each effect of the library
leaves on the same grid.

Each effect is hidden, alone or in a pair, in a synthetic validation dataset made by the
predictor on the thesis's grid (§8.3, noise off so that only the effect's own signature shows);
the nominal model then predicts every row from the recorded tensions, as the thesis did, and the
errors p̂ − p* (m) are summarised as the thesis read them:

* z: mean z error (mm) and the fraction of rows with a positive z error (thesis: always positive);
* y: correlation of e_y with −sin φ and the least-squares amplitude of that sine (mm)
  (thesis: an inverted sine over the bending plane, clearest at 10 g);
* U: RMS 3-D error (mm) with the recorded tensions scaled by s = 1.0 … 0.7, and whether the curve
  is U-shaped, that is its minimum lies strictly inside (s < 1) and the error rises again
  below it (thesis §9.2.1, figure 23).

Usage: python scripts/thesis_signatures.py [--quick] [NAME ...]
  --quick: φ every 60°, κ ≤ 13 1/m; NAME: only the cases whose name contains it.
Prints one table in Markdown; docs/thesis-signatures.md quotes it.
"""

from __future__ import annotations

import sys
import tempfile
import time

import numpy as np

from twin import load_params
from twin.data.prediction import predict_rows
from twin.discrepancy.residuals import thesis_signature
from twin.discrepancy.synthetic import synthetic_validation_dataset
from twin.pcc import validation_grid

NOMINAL = load_params()
B = NOMINAL.backbone
# Sizes: the ones the discrepancy workflow is checked at (README "smallest sizes named") or
# the thesis's own guesses (tension fractions for friction, heavier weight, §10.1).
CASES = {
    "none (nominal)": ({}, {}),
    "tension_gain +10 %": ({"effects.tension_gain_error": [0.1] * 4}, {}),
    "tension_offset +0.1 N": ({"effects.tension_offset_error_n": [0.1] * 4}, {}),
    "tendon_friction μ 0.3": ({"effects.tendon_friction_coeff": 0.3}, {}),
    "weight ×1.5": ({"backbone.mass_kg": 1.5 * B.mass_kg}, {}),
    "tip_load +20 %": ({"effects.tip_load_error_fraction": 0.2}, {}),
    "stiffness E −20 %": ({"backbone.youngs_modulus_pa": 0.8 * B.youngs_modulus_pa}, {}),
    "base_tilt 1° (about x)": ({"effects.base_tilt_deg": [1.0, 0.0]}, {}),
    "tracker_offset 1 mm z": ({"effects.tracker_offset_m": [0.0, 0.0, 0.001]}, {}),
    "tendon_compliance 0.5 mm/N": ({"effects.tendon_compliance_m_per_n": 5e-4}, {}),
    "tip moment 1.5 mN·m (outside the library)": ({}, {"tip_moment_nm": (1.5e-3, 0.0, 0.0)}),
    "intrinsic curvature 1.5 1/m (outside)": ({}, {"precurvature_per_m": (1.5, 0.0, 0.0)}),
    "tension_gain +10 % + weight ×1.5": ({"effects.tension_gain_error": [0.1] * 4,
                                          "backbone.mass_kg": 1.5 * B.mass_kg}, {}),
    "tendon_friction μ 0.3 + weight ×1.5": ({"effects.tendon_friction_coeff": 0.3,
                                             "backbone.mass_kg": 1.5 * B.mass_kg}, {}),
    "stiffness E −20 % + tension_gain +10 %": ({"backbone.youngs_modulus_pa": 0.8 * B.youngs_modulus_pa,
                                                "effects.tension_gain_error": [0.1] * 4}, {}),
    "stiffness E −20 % + tendon_friction μ 0.3": ({"backbone.youngs_modulus_pa": 0.8 * B.youngs_modulus_pa,
                                                   "effects.tendon_friction_coeff": 0.3}, {}),
}
SCALES = (1.0, 0.95, 0.9, 0.85, 0.8, 0.7)


def rms_mm(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(err ** 2, axis=1)))) * 1e3


def signature(hidden: dict, extra: dict, grid) -> dict:
    truth = NOMINAL.replace(hidden) if hidden else NOMINAL
    data = synthetic_validation_dataset(tempfile.mkdtemp(), NOMINAL, truth, grid=grid, seed=0,
                                        tracker_noise_m=0.0, loadcell_noise_n=0.0, **extra)
    curve, failed = [], []
    for s in SCALES:
        tip, ok, _, _ = predict_rows(NOMINAL, data.base_rotation, s * data.tensions_n, data["tip_mass_kg"],
                                     data.lengths_m, sliding_state=data.sliding_state)
        err = (tip - data.tip_positions_m)[ok]
        curve.append(rms_mm(err))
        failed.append(int(np.sum(~ok)))
        if s == 1.0:
            sig = thesis_signature(err, np.asarray(data["phi_cmd_deg"])[ok])
            heavy = np.asarray(data["tip_mass_kg"])[ok] > 0.009
            sig10 = thesis_signature(err[heavy], np.asarray(data["phi_cmd_deg"])[ok][heavy])
    best = int(np.argmin(curve))
    u_shaped = 0 < best < len(SCALES) - 1 and curve[best] < 0.9 * curve[0] and curve[-1] > 1.1 * curve[best]
    return {"mean_z_mm": sig["mean_z_m"] * 1e3, "pos_z": sig["positive_z_fraction"],
            "corr_y": sig["corr_y_minus_sin_phi"], "amp_y_mm": sig["y_sine_amplitude_m"] * 1e3,
            "corr_y10": sig10["corr_y_minus_sin_phi"], "curve": curve, "failed": failed, "best_s": SCALES[best],
            "u": u_shaped}


def main() -> None:
    grid = validation_grid()
    if "--quick" in sys.argv:
        grid = [g for g in grid if g[2] % 60 == 0 and g[1] <= 13.0]
    print(f"grid: {len(grid)} rows; tension scales {SCALES}")
    print("| hidden effect | mean e_z (mm) | e_z > 0 | corr(e_y, −sin φ) all / 10 g | sine amplitude (mm) "
          "| RMS (mm) at s = " + ", ".join(f"{s:g}" for s in SCALES) + " | best s | U-shaped |")
    print("|---|---|---|---|---|---|---|---|")
    only = [a for a in sys.argv[1:] if not a.startswith("--")]
    for name, (hidden, extra) in CASES.items():
        if only and not any(o in name for o in only):
            continue
        t = time.process_time()
        r = signature(hidden, extra, grid)
        print(f"| {name} | {r['mean_z_mm']:+.2f} | {100 * r['pos_z']:.0f} % | {r['corr_y']:+.2f} / {r['corr_y10']:+.2f} "
              f"| {r['amp_y_mm']:+.2f} | " + ", ".join(f"{c:.2f}" for c in r["curve"])
              + f" | {r['best_s']:g} | {'yes' if r['u'] else 'no'} |", flush=True)
        print(f"<!-- {name}: failed rows per scale {r['failed']}, cpu {time.process_time() - t:.0f} s -->", flush=True)


if __name__ == "__main__":
    main()
