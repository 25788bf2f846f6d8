"""Length control against tension control on the antagonistic pair 1–3: does the pair fight?

With both tendons of a pair position-controlled (the thesis's length and pairs modes) the
tensions are not commanded at all: they are whatever the geometry makes of the two held lengths.
Through a practically inextensible tendon a micrometre of mismatch between the commanded and the
real path lengths is newtons of tension, so the pair's internal tension (co-contraction: the
smaller tension of the two, which bends nothing) and its sum are set by micrometre errors, and
shift with every bend and load. In tension mode they are setpoints.

The comparison, in the bending plane of the pair (φ = 0°, tendon 1 pulls):

* **bending**: κ stepped over the grid in length mode (PCC lengths) and in tension mode (the
  predictor's tensions for the same unloaded tip, the antagonist at the floor), 0 g and 10 g;
* **mismatch**: in length mode at κ = 13 1/m, both tendons of the pair shortened by a common
  δ = 0…40 encoder counts (0…38 µm, the size of a PCC model error). Tension mode has no length setpoint
  for such an error to enter through.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from twin.control.compensation import hold_tensions
from twin.control.pretension import pretension_straight
from twin.control.gains import TUNED_TENSION_GAINS
from twin.experiments.protocols import measure, wait_for_rest
from twin.experiments.report import markdown_table
from twin.params import Params
from twin.pcc import tendon_length_changes_m
from twin.rod import RodModel

__all__ = ["CocontractionStudy", "run_cocontraction_study"]

# Settling tolerance of the pair tensions' window means under a length mismatch (N). With the
# pair shortened against itself the two length loops hunt around their encoder counts — the
# fight itself: 0.02 N RMS per sample at 20 counts (measured on the twin) — and window means
# wander by more than wait_for_rest()'s default 0.01 N, so that run never came to rest.
HUNTING_TOLERANCE_N = 0.05


@dataclasses.dataclass(frozen=True)
class CocontractionStudy:
    """Pair 1–3 tensions under length and tension control.

    Attributes:
        bending: rows ``mode, kappa_per_m, mass_g, tension_1_n, tension_3_n, pair_sum_n,
            cocontraction_n, tip_z_mm``.
        mismatch: length-mode rows ``mode, offset_counts, offset_um, tension_1_n, tension_3_n,
            pair_sum_n, cocontraction_n``.
        device: the device URL.
    """

    bending: list[dict]
    mismatch: list[dict]
    device: str

    def summary(self) -> dict:
        """Per mode: the spread of the pair sum over the bends, the largest change of a pair tension
        when 10 g is hung, the largest co-contraction; for length mode also the co-contraction and
        pair-sum rise that the largest common length mismatch builds up."""
        out = {}
        for mode in ("lengths", "tensions"):
            rows = [r for r in self.bending if r["mode"] == mode]
            sums = [r["pair_sum_n"] for r in rows]
            loads = [max(abs(b["tension_1_n"] - a["tension_1_n"]), abs(b["tension_3_n"] - a["tension_3_n"]))
                     for a, b in zip(rows[::2], rows[1::2])]
            out[mode] = {
                "pair_sum_range_n": float(max(sums) - min(sums)),
                "pair_tension_change_under_10g_n": float(max(loads)),
                "max_cocontraction_n": float(max(r["cocontraction_n"] for r in rows)),
            }
        out["lengths"]["max_cocontraction_with_mismatch_n"] = float(max(r["cocontraction_n"] for r in self.mismatch))
        last = max(self.mismatch, key=lambda r: r["offset_counts"])
        out["lengths"]["largest_offset_um"] = last["offset_um"]
        out["lengths"]["pair_sum_rise_at_largest_offset_n"] = last["pair_sum_n"] - self.mismatch[0]["pair_sum_n"]
        return out

    def markdown(self) -> str:
        s = self.summary()
        lines = ["# Antagonistic pair 1–3: length control against tension control", "",
                 f"Device `{self.device}`, endoscope horizontal, bending plane φ = 0° (tendon 1 pulls, "
                 "tendon 3 is its antagonist). Co-contraction = min(τ₁, τ₃): tension both tendons carry "
                 "that bends nothing. Length mode: PCC lengths on all four tendons; tension mode: the "
                 "predictor's tensions for the same unloaded tip, antagonist at the floor.", "",
                 "## Summary", "", markdown_table([{"mode": k, **v} for k, v in s.items()]), "",
                 "## While bending, 0 g and 10 g", "", markdown_table(self.bending), "",
                 "## A common length mismatch of the pair (κ = 13 1/m)", "",
                 "Length mode only: both tendons shortened by δ encoder counts on top of their PCC setpoints. "
                 "Tension mode has no length setpoint for such an error to enter through.", "",
                 markdown_table(self.mismatch)]
        return "\n".join(lines)

    def write_report(self, folder: str | Path) -> Path:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / "cocontraction.md"
        path.write_text(self.markdown())
        return path


def _pair_row(mode: str, m, **keys) -> dict:
    t1, t3 = float(m.tensions_n[0]), float(m.tensions_n[2])
    return {"mode": mode, **keys, "tension_1_n": t1, "tension_3_n": t3, "pair_sum_n": t1 + t3,
            "cocontraction_n": min(t1, t3)}


def run_cocontraction_study(device, params: Params, *, kappas_per_m=(4.5, 8.7, 13.0, 17.5, 26.2),
                            offsets_counts=(0, 5, 10, 20, 40), floor_n: float = 1.0,
                            settle_timeout_s: float = 6.0) -> CocontractionStudy:
    """Run both parts of the study on a connected device with a fixture and a tracker.

    Raises:
        ValueError: the robot's tendons 1 and 3 are not an antagonistic pair (180° apart, both
            anchored at the tip), so the study's bending plane φ = 0° has no pair to compare.
    """
    angles, ends = params.tendons.angles_deg, params.tendon_ends_m()
    if len(angles) < 3 or abs((angles[2] - angles[0]) % 360.0 - 180.0) > 1e-9 or ends[0] != ends[2] or \
            ends[0] != params.backbone.length_m:
        raise ValueError(f"tendons.angles_deg = {list(angles)!r}: the co-contraction study needs tendons 1 and 3 "
                         "to be an antagonistic pair, 180 deg apart and both anchored at the tip")
    model = RodModel.from_params(params)
    count_m = device.info.tendon_m_per_count
    device.disable()
    device.set_gains("tensions", **TUNED_TENSION_GAINS)
    bending, mismatch, unloaded = [], [], {}
    zero = pretension_straight(device, params, mode="lengths")
    for kappa in kappas_per_m:
        device.set_lengths(zero + tendon_length_changes_m(kappa, 0.0, params))
        for mass in (0.0, 0.010):
            device.fixture.hang_tip_mass(mass)
            wait_for_rest(device, timeout_s=settle_timeout_s)
            m = measure(device)
            if mass == 0.0:
                unloaded[kappa] = m.tensions_n
            bending.append(_pair_row("lengths", m, kappa_per_m=kappa, mass_g=mass * 1e3,
                                     tip_z_mm=m.tip_position_m[2] * 1e3))
        device.fixture.hang_tip_mass(0.0)
    kappa = 13.0
    pcc = zero + tendon_length_changes_m(kappa, 0.0, params)
    for counts in offsets_counts:
        shift = np.zeros(len(angles))
        shift[[0, 2]] = counts * count_m
        device.set_lengths(pcc - shift)
        wait_for_rest(device, timeout_s=settle_timeout_s, tension_tolerance_n=HUNTING_TOLERANCE_N)
        mismatch.append(_pair_row("lengths", measure(device), offset_counts=counts, offset_um=counts * count_m * 1e6))
    if kappa not in unloaded:
        device.set_lengths(pcc)
        wait_for_rest(device, timeout_s=settle_timeout_s)
        unloaded[kappa] = measure(device).tensions_n

    pretension_straight(device, params, mode="tensions")
    bounds = dict(base_rotation=device.base_rotation, floor_n=floor_n, limit_n=params.rig.tension_limit_n - 1.0)
    for kappa in kappas_per_m:
        device.set_tensions(hold_tensions(model, unloaded[kappa], np.zeros(3), **bounds).tensions_n)
        for mass in (0.0, 0.010):
            device.fixture.hang_tip_mass(mass)
            wait_for_rest(device, timeout_s=settle_timeout_s)
            m = measure(device)
            bending.append(_pair_row("tensions", m, kappa_per_m=kappa, mass_g=mass * 1e3,
                                     tip_z_mm=m.tip_position_m[2] * 1e3))
        device.fixture.hang_tip_mass(0.0)
    device.disable()
    return CocontractionStudy(bending=bending, mismatch=mismatch, device=device.url)
