"""Length control against tension control on an antagonistic pair: does the pair fight?

With both tendons of a pair position-controlled (the thesis's length and pairs modes) the
tensions are not commanded at all: they are whatever the geometry makes of the two held lengths.
Through a practically inextensible tendon a micrometre of mismatch between the commanded and the
real path lengths is newtons of tension, so the pair's internal tension (co-contraction: the
smaller tension of the two, which bends nothing) and its sum are set by micrometre errors, and
shift with every bend and load. In tension mode they are setpoints.

The pair is any two tendons anchored at the same disc whose directions oppose (more than 90°
apart, so that each one's pull bends against the other's): by default the two furthest apart
(:func:`antagonistic_pair`; tendons 1 and 3 of the thesis endoscope, 1 and 2 of a three-tendon
robot, where the antagonist is 120° away). The comparison, in the bending plane of the pair's
first tendon (φ = its angle, it pulls):

* **bending**: κ stepped over bend angles κL = 15, 30, 45, 60, 90° of the robot's length (κ = 4.4
  … 26.2 1/m on the 60 mm endoscope, the thesis's grid) in length mode (PCC lengths) and in
  tension mode (the predictor's tensions for the same unloaded tip), 0 g and 10 g;
* **mismatch**: in length mode at κL = 45°, both tendons of the pair shortened by a common
  δ = 0…40 encoder counts (0…38 µm on the thesis rig, the size of a PCC model error). Tension mode has
  no length setpoint for such an error to enter through.
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
from twin.pose import matrix_to_quat
from twin.rod import RodModel

__all__ = ["BEND_ANGLES_DEG", "CocontractionStudy", "antagonistic_pair", "run_cocontraction_study"]

# Bend angles κL of the study's curvatures (deg): the thesis grid's 4.5 … 26.2 1/m on its 60 mm
# endoscope (thesis §8.3), as angles so that they hold for any length.
BEND_ANGLES_DEG = (15.0, 30.0, 45.0, 60.0, 90.0)
# Bend angle of the mismatch part (deg): the middle of the grid, κ = 13 1/m at 60 mm.
MISMATCH_BEND_DEG = 45.0


def antagonistic_pair(params: Params, pair: tuple[int, int] | None = None) -> tuple[int, int]:
    """Indices (0-based) of an antagonistic pair of the robot's tendons: ``pair`` checked, or by
    default the two anchored at the same disc that are furthest apart in angle (the first of them
    with the lower index).

    Raises:
        ValueError: ``pair`` names a tendon the robot does not have, the same tendon twice, two
            tendons anchored at different discs or less than 90° apart; or no two tendons of the
            robot are such a pair.
    """
    angles, ends = params.tendons.angles_deg, params.tendon_ends_m()
    n = len(angles)

    def separation(i: int, j: int) -> float:
        d = (angles[j] - angles[i]) % 360.0
        return min(d, 360.0 - d)

    def opposed(i: int, j: int) -> bool:
        return i != j and ends[i] == ends[j] and separation(i, j) > 90.0 + 1e-9

    if pair is not None:
        i, j = (int(k) for k in pair)
        if not (0 <= i < n and 0 <= j < n) or not opposed(i, j):
            raise ValueError(f"pair = {i + 1},{j + 1}: tendons of an antagonistic pair must be two of 1..{n}, anchored "
                             f"at the same disc and more than 90 deg apart (tendons.angles_deg = {list(angles)!r})")
        return i, j
    candidates = [(separation(i, j), -i, -j) for i in range(n) for j in range(i + 1, n) if opposed(i, j)]
    if not candidates:
        raise ValueError(f"tendons.angles_deg = {list(angles)!r}: no two tendons anchored at the same disc are "
                         "more than 90 deg apart; the robot has no antagonistic pair")
    _, i, j = max(candidates)
    return -i, -j

# Settling tolerance of the pair tensions' window means under a length mismatch (N). With the
# pair shortened against itself the two length loops hunt around their encoder counts — the
# fight itself: 0.02 N RMS per sample at 20 counts (measured on the twin) — and window means
# wander by more than wait_for_rest()'s default 0.01 N, so that run never came to rest.
HUNTING_TOLERANCE_N = 0.05


@dataclasses.dataclass(frozen=True)
class CocontractionStudy:
    """The pair's tensions under length and tension control.

    Attributes:
        bending: rows ``mode, kappa_per_m, mass_g, tension_a_n, tension_b_n, pair_sum_n,
            cocontraction_n, tip_z_mm`` (a: the pulling tendon, b: its antagonist).
        mismatch: length-mode rows ``mode, offset_counts, offset_um, tension_a_n, tension_b_n,
            pair_sum_n, cocontraction_n``.
        device: the device URL.
        pair: the pair's tendon indices (0-based): the pulling one, its antagonist.
        angles_deg: their angles (deg).
        base_quat: the device's base pose, body → world, as a quaternion (w, x, y, z).
    """

    bending: list[dict]
    mismatch: list[dict]
    device: str
    pair: tuple[int, int] = (0, 2)
    angles_deg: tuple[float, float] = (0.0, 180.0)
    base_quat: tuple[float, ...] = (0.7071, 0.0, 0.7071, 0.0)

    def summary(self) -> dict:
        """Per mode: the spread of the pair sum over the bends, the largest change of a pair tension
        when 10 g is hung, the largest co-contraction; for length mode also the co-contraction and
        pair-sum rise that the largest common length mismatch builds up."""
        out = {}
        for mode in ("lengths", "tensions"):
            rows = [r for r in self.bending if r["mode"] == mode]
            sums = [r["pair_sum_n"] for r in rows]
            loads = [max(abs(b["tension_a_n"] - a["tension_a_n"]), abs(b["tension_b_n"] - a["tension_b_n"]))
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
        a, b = (k + 1 for k in self.pair)
        lines = [f"# Antagonistic pair {a}–{b}: length control against tension control", "",
                 f"Device `{self.device}`, base pose (w, x, y, z) = {self.base_quat}, bending plane φ = {self.angles_deg[0]:g}° (tendon {a} pulls "
                 f"as τ_a, tendon {b} at {self.angles_deg[1]:g}° is its antagonist, τ_b). Co-contraction = "
                 "min(τ_a, τ_b): tension both tendons carry that bends nothing. Length mode: PCC lengths on "
                 "every tendon; tension mode: the predictor's tensions for the same unloaded tip.", "",
                 "## Summary", "", markdown_table([{"mode": k, **v} for k, v in s.items()]), "",
                 "## While bending, 0 g and 10 g", "", markdown_table(self.bending), "",
                 f"## A common length mismatch of the pair (κL = {MISMATCH_BEND_DEG:g}°)", "",
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


def _pair_row(mode: str, m, pair: tuple[int, int], **keys) -> dict:
    ta, tb = float(m.tensions_n[pair[0]]), float(m.tensions_n[pair[1]])
    return {"mode": mode, **keys, "tension_a_n": ta, "tension_b_n": tb, "pair_sum_n": ta + tb,
            "cocontraction_n": min(ta, tb)}


def run_cocontraction_study(device, params: Params, *, pair: tuple[int, int] | None = None, kappas_per_m=None,
                            offsets_counts=(0, 5, 10, 20, 40), floor_n: float = 1.0,
                            settle_timeout_s: float = 6.0) -> CocontractionStudy:
    """Run both parts of the study on a connected device with a fixture and a tracker.

    Args:
        pair: the antagonistic pair (0-based: the pulling tendon, its antagonist); default
            :func:`antagonistic_pair`'s.
        kappas_per_m: the bends (1/m); default :data:`BEND_ANGLES_DEG` over the robot's length.

    Raises:
        ValueError: ``pair`` is not an antagonistic pair, or the robot has none (:func:`antagonistic_pair`).
    """
    pair = antagonistic_pair(params, pair)
    angles = params.tendons.angles_deg
    length_m = params.backbone.length_m
    if kappas_per_m is None:
        kappas_per_m = tuple(round(float(np.radians(a)) / length_m, 2) for a in BEND_ANGLES_DEG)
    phi = float(angles[pair[0]])
    model = RodModel.from_params(params)
    count_m = device.info.tendon_m_per_count
    device.disable()
    device.set_gains("tensions", **TUNED_TENSION_GAINS)
    bending, mismatch, unloaded = [], [], {}
    zero = pretension_straight(device, params, mode="lengths")
    for kappa in kappas_per_m:
        device.set_lengths(zero + tendon_length_changes_m(kappa, phi, params))
        for mass in (0.0, 0.010):
            device.fixture.hang_tip_mass(mass)
            wait_for_rest(device, timeout_s=settle_timeout_s)
            m = measure(device)
            if mass == 0.0:
                unloaded[kappa] = m.tensions_n
            bending.append(_pair_row("lengths", m, pair, kappa_per_m=kappa, mass_g=mass * 1e3,
                                     tip_z_mm=m.tip_position_m[2] * 1e3))
        device.fixture.hang_tip_mass(0.0)
    kappa = round(float(np.radians(MISMATCH_BEND_DEG)) / length_m, 2)
    pcc = zero + tendon_length_changes_m(kappa, phi, params)
    for counts in offsets_counts:
        shift = np.zeros(len(angles))
        shift[list(pair)] = counts * count_m
        device.set_lengths(pcc - shift)
        wait_for_rest(device, timeout_s=settle_timeout_s, tension_tolerance_n=HUNTING_TOLERANCE_N)
        mismatch.append(_pair_row("lengths", measure(device), pair, offset_counts=counts, offset_um=counts * count_m * 1e6))
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
            bending.append(_pair_row("tensions", m, pair, kappa_per_m=kappa, mass_g=mass * 1e3,
                                     tip_z_mm=m.tip_position_m[2] * 1e3))
        device.fixture.hang_tip_mass(0.0)
    device.disable()
    return CocontractionStudy(bending=bending, mismatch=mismatch, device=device.url, pair=pair,
                              angles_deg=(phi, float(angles[pair[1]])), base_quat=tuple(round(float(q), 4) for q in matrix_to_quat(device.base_rotation)))
