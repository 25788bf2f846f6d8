"""MuJoCo model of the endoscope and its rig, generated from the parameter set with ``mujoco.MjSpec``.

MuJoCo 4 has no cable element whose off-axis sites rotate with the rod, so the backbone is an
explicit chain of rigid bodies with elastic joints. The rod
of length L is cut into N = ``sim.elements`` elements of length h = L/N; the compliance of
element k is lumped in a joint at its middle, s = (k − ½) h, so the clamp holds the first
half-element and the last body is a half-element ending at the tip. A pure end moment then
bends every joint by M h / EI — the exact arc through the joints — and a tip force loads
each joint with the exact shear force and moment at its station (the midpoint rule, exact
for the linear moment of a cantilever up to the −1/(4N²) of its quadratic deflection).

Each station has hinges for bending about x and y and for twist, and, when the parameters ask
for them, slides for the shear (``sim.shear_joints``) and axial (``sim.axial_joints``) strains
of a Cosserat rod (Rucker & Webster 2011, K_se and K_bt), with stiffness from the section over
one element:

    bend x, y (hinges):  EI / h         twist z (hinge): K_t / h  (E(Ixx+Iyy) or GJ, backbone.torsion)
    shear x, y (slides): GA / h         axial z (slide): backbone.axial_stiffness_n / h

and stiffness-proportional damping ``sim.damping_time_s`` × stiffness (with continuous routing the
plant loop damps the tendons' stiffening of the twist hinges and shear slides alike). The slides need not be at
every station: with ``sim.slide_stride`` = k the middle station of each block of k takes the
block's shear and axial compliance (:func:`slide_stations`), which keeps the chain short where
those strains are small (with an isotropic G shear is ~0.5% of a tip-loaded cantilever's
deflection). The thesis's G makes shear a quarter of it; then every station needs its slides.
The twist hinges can be lumped the same way with ``sim.twist_stride``: every hinge left out saves
a dof of the ten-station chain (34 dofs instead of 40 with 3: 1.2× the speed), but a tip mass
hanging from a rod bent out of the vertical plane twists it about tangents that turn along the
rod, and one hinge per block turns the distal part about a single one of them: 0.27 mm worst
over the thesis grid instead of 0.17 mm.

Spacer discs sit at s = jL/D. Each tendon runs from a spool behind the clamp to the tip disc,
routed as ``sim.tendon_routing`` says (:data:`TENDON_SITES`): continuously, as the predictor
routes it (a fixed tendon over the joints with the tendon's length to second order,
:class:`TendonLength`), or through a site per disc in straight chords, as the real line does. Either way it is pull-only: a dead-band
spring, slack below its straight length less :data:`TAUT_STRETCH_M` (never pushing) and as stiff as the line above it
(``effects.tendon_compliance_m_per_n``, or practically inextensible when that effect is off).
Each spool is a slide joint along the clamp axis (position =
tendon paid out) with three actuators in separate groups, one group enabled at a time by the
plant: a DC motor (PWM mode, :mod:`twin.sim.motor`), an ideal tension source, and an ideal
spool-position servo. The reference holder is a set of weld constraints holding each disc
straight on the clamp, inactive until engaged. A massless body at the tip takes the hung mass.
Gravity is along world −z; the clamp can take any orientation.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from twin import effects
from twin.params import Params
from twin.pose import HORIZONTAL, matrix_to_quat
from twin.sim.motor import MotorConstants

__all__ = [
    "ACTUATOR_GROUPS",
    "STATION_JOINTS",
    "TENDON_SITES",
    "GeometricStiffness",
    "Layout",
    "TendonLength",
    "build_model",
    "build_spec",
    "model_xml",
    "slide_stations",
    "station_joints",
    "tendon_route",
    "tendon_stiffness_n_per_m",
]

# Where the spools sit behind the clamp (m). The real line turns over a load-cell pulley well
# behind the base; only its direction at the base hole matters, and that is along the clamp axis.
SPOOL_OFFSET_M = 0.05
# Spool travel either way (m): beyond the ±7 mm the validation grid needs, short of the clamp.
SPOOL_TRAVEL_M = 0.03
# Mass of the spool carriage without motor (kg): light, so the ideal modes are fast to settle.
SPOOL_CARRIAGE_MASS_KG = 1e-3
# Compliance of an "inextensible" tendon (m/N): five encoder counts (0.94 µm each) per newton.
# The discrete integrator keeps any stiffness stable, but a dead-band spring is linearised where
# the step starts, so a slack tendon going taut is springless for that step and engages with a
# spike that grows with stiffness × step. A spool pulled in onto a line gone slack while coasting
# (the device tests' start on the emulated board) peaked at 15–37 N with 1e-6 m/N, over the rig's
# 6 N tension limit, and at 1–7 N with 5e-6 m/N (2–2.5 ms steps; a real line and rod would give
# a few newtons at most), which still tripped the emulated board's limit now and then; hence the
# plant takes up slack tendons in steps of 1.25 ms (twin.sim.plant.ENGAGE_MAX_STEP_S). Softer
# still, the twin's co-contraction study no longer settles.
INEXTENSIBLE_COMPLIANCE_M_PER_N = 5e-6
# How far into its spring a "just taut" tendon starts (m): 0.2 mN at the default stiffness. From
# exactly the slack edge the rod sagging from straight engages the spring with the same spike
# (1.2 N at 2.5 ms); from 1 nm in, the first step already sees the stiffness (0.13 N, as at 1 ms).
TAUT_STRETCH_M = 1e-9
# Viscous friction of a spool's bearings and gearbox at the tendon (N·s/m): an assumption, small
# against the motor's 300 N·s/m of back-EMF damping, so that a free spool comes to rest.
SPOOL_DAMPING_N_S_PER_M = 1.0
# Ideal spool-position servo (N/m): 3 N moves it 0.3 µm, a third of an encoder count.
POSITION_GAIN_N_PER_M = 1e7
# Largest tension the ideal tension source accepts (N): far above tension_limit_n.
TENSION_SOURCE_MAX_N = 100.0
# Actuator group per drive mode; the plant disables the other groups (mjOption.disableactuator).
ACTUATOR_GROUPS = {"pwm": 0, "tension": 1, "length": 2}
# Every joint a backbone station can have, in the order MuJoCo composes them: (name, type, axis,
# strain). ``sim.shear_joints`` and ``sim.axial_joints`` choose whether the slides are there
# (:func:`station_joints`); the three hinges always are. The slides come first, so shear and
# axial strain are measured in the proximal body's frame rather than the element's mid-frame.
# A spatial tendon ("discs" routing) compressing the rod by P then puts a spurious shear force
# P·Δθ/2 on the shear slides of a station bent by Δθ; splitting the bend around the slides would
# remove it but needs a second body per station (MuJoCo allows six dofs per body) and costs 1.8×
# the step time. The continuous tendon's pull is defined on the joint coordinates themselves
# (:class:`TendonLength`), so it has none.
STATION_JOINTS = (
    ("sx", mujoco.mjtJoint.mjJNT_SLIDE, (1.0, 0.0, 0.0), "shear"),
    ("sy", mujoco.mjtJoint.mjJNT_SLIDE, (0.0, 1.0, 0.0), "shear"),
    ("az", mujoco.mjtJoint.mjJNT_SLIDE, (0.0, 0.0, 1.0), "axial"),
    ("bx", mujoco.mjtJoint.mjJNT_HINGE, (1.0, 0.0, 0.0), "bend"),
    ("by", mujoco.mjtJoint.mjJNT_HINGE, (0.0, 1.0, 0.0), "bend"),
    ("tz", mujoco.mjtJoint.mjJNT_HINGE, (0.0, 0.0, 1.0), "twist"),
)
# Tendon routings (``sim.tendon_routing``, or the ``tendon_sites`` override):
#   "continuous"  the predictor's routing. A continuously routed tendon at r(s) in the section grows
#                 as |v + u × r + r'| along s (Rucker & Webster 2011; twin.rod.kernel). Its length
#                 over the joints to second order about the straight pose is :class:`TendonLength`:
#                 a fixed tendon carries the first order (y and −x on each station's bend hinges, 1
#                 on its axial slide for straight routing; helical routing adds the twist hinges and
#                 shear slides, the tendons' tension twisting the rod) and −1 on the spool, so it
#                 pulls every joint with the arm r exactly and equal tensions leave the rod's bend
#                 alone; the plant loop adds the second order each step (:class:`GeometricStiffness`:
#                 the tension's stiffening of twist, ΣT·r² per unit twist, 15% of E(Ixx+Iyy) at 8 N,
#                 and of shear, ΣT added to GA). Sites in every joint's plane, at the offset, and at
#                 the tip trace its path (path lengths, friction, drawing) but carry no force. A
#                 spatial tendon through those sites was measured as well: a straight line between
#                 body-fixed points reaches only the arm r·(1 − Δθ²/2) at a joint bent by Δθ (0.63 mm
#                 at the tip at N = 10 and κ = 26.2 1/m) and was a third slower at N = 20.
#   "linear"      "continuous" to first order only, without the plant loop's second order (the
#                 ``tendon_sites`` override only; the cross-check shows with it what that is worth).
#   "discs"       a spatial tendon through a site per disc: straight chords between discs, as the
#                 rig's line. A chord across a bent joint lies off the offset towards the centre of
#                 curvature, so the pretension of all four tendons bends the rod further.
#   "elements"    "discs" with a site at every body's middle as well: chords one element long (the
#                 plant's ``tendon_sites`` override only; the cross-check shows with it how the
#                 chord effect shrinks with the chord).
TENDON_SITES = ("continuous", "linear", "discs", "elements")
# The routings that are a fixed tendon over the joints.
_FIXED_ROUTINGS = ("continuous", "linear")
# Sites drawn as dots the size of the tendon (m), not MuJoCo's default 5 mm spheres.
_SITE_SIZE = [0.0003, 0.0, 0.0]
_RGBA_ROD = (0.85, 0.55, 0.35, 1.0)
_RGBA_DISC = (0.75, 0.75, 0.78, 1.0)
_RGBA_TENDON = (0.1, 0.3, 0.9, 1.0)


@dataclasses.dataclass(frozen=True)
class Layout:
    """Geometry of the chain, derived from the parameters alone (no MuJoCo).

    Attributes:
        elements: N.
        element_length_m: h = L / N.
        disc_s_m: (D,) arc length of each disc (m); the last is the tip.
        disc_body: (D,) index k (1..N) of the body carrying each disc.
        site_s_m: (S,) arc lengths where each tendon has a site, base hole (0) excluded.
        site_body: (S,) index k (0 = clamp, 1..N) of the body carrying each site.
        routing: one of :data:`TENDON_SITES`.
        tendon_xy_m: (n, S + 1, 2) tendon offsets in the section at s = 0 and at each site.
        rest_length_m: (n,) tendon length spool → anchor in the straight pose: the tendon's length.
        tendon_end_m: (n,) arc length where each tendon is anchored (:meth:`Params.tendon_ends_m`).
        tendon_site_count: (n,) how many of the sites each tendon passes, up to its anchor.
    """

    elements: int
    element_length_m: float
    disc_s_m: np.ndarray
    disc_body: np.ndarray
    site_s_m: np.ndarray
    tendon_xy_m: np.ndarray
    rest_length_m: np.ndarray
    site_body: np.ndarray
    routing: str
    tendon_end_m: np.ndarray
    tendon_site_count: np.ndarray

    @classmethod
    def from_params(cls, params: Params, *, elements: int | None = None,
                    tendon_sites: str | None = None) -> "Layout":
        """Args:
            elements: override of ``sim.elements``.
            tendon_sites: override of ``sim.tendon_routing``, one of :data:`TENDON_SITES`:
                ``"continuous"``, ``"linear"``, ``"discs"`` or ``"elements"``.
        """
        n = params.sim.elements if elements is None else int(elements)
        if n < 1:
            raise ValueError(f"elements = {n!r}: must be >= 1")
        routing = params.sim.tendon_routing if tendon_sites is None else tendon_sites
        if routing not in TENDON_SITES:
            raise ValueError(f"tendon_sites = {routing!r}: expected one of {', '.join(TENDON_SITES)}")
        length = params.backbone.length_m
        h = length / n
        d = params.discs.count
        disc_s = length * np.arange(1, d + 1) / d
        disc_body = np.minimum(n, np.floor(disc_s / h + 0.5 + 1e-9)).astype(int)
        if routing in _FIXED_ROUTINGS:
            # Joint k's plane, on body k − 1 (the clamp for k = 1); then the tip on body N.
            site_s = np.append(h * (np.arange(1, n + 1) - 0.5), length)
            site_body = np.append(np.arange(n), n)
        else:
            sites = set(np.round(disc_s, 12))
            if routing == "elements":
                sites |= set(np.round(h * np.arange(1, n), 12))
            site_s = np.array(sorted(sites))
            site_body = np.minimum(n, np.floor(site_s / h + 0.5 + 1e-9)).astype(int)
        s_all = np.concatenate([[0.0], site_s])
        xy = tendon_offsets_m(params, s_all)
        z = np.broadcast_to(s_all[None, :, None], (xy.shape[0], s_all.size, 1))
        ends = np.asarray(params.tendon_ends_m())
        sites = np.count_nonzero(site_s[None, :] <= ends[:, None] + 1e-12, axis=1)
        segments = np.linalg.norm(np.diff(np.concatenate([xy, z], axis=2), axis=1), axis=2)
        # Each tendon's path up to its anchor; a tendon to the tip passes every site.
        path = np.where(np.arange(site_s.size)[None, :] < sites[:, None], segments, 0.0).sum(axis=1)
        return cls(n, h, disc_s, disc_body, site_s, xy, SPOOL_OFFSET_M + path, site_body, routing, ends, sites)

    def body_of(self, s_m: float) -> int:
        """Index k of the body whose span holds arc length ``s_m``: 0 (the clamp) before the
        first joint, then 1..N."""
        return int(min(self.elements, math.floor(s_m / self.element_length_m + 0.5 + 1e-9)))

    def body_origin_s_m(self, k: int) -> float:
        """Arc length of body k's frame origin: its joint, (k − ½) h, or the base for the clamp (k = 0)."""
        return (k - 0.5) * self.element_length_m if k > 0 else 0.0


def tendon_offsets_m(params: Params, s_m) -> np.ndarray:
    """Tendon positions in the cross-section (n, len(s), 2) at arc lengths ``s_m`` (m).

    Straight: radius and angle constant; helical: the angle turns ``helix_turns`` over L;
    converging: the radius goes linearly to ``tip_radius_m`` (as :class:`twin.rod.TendonRoute`).
    """
    return tendon_route(params, s_m)[0]


def tendon_route(params: Params, s_m) -> tuple[np.ndarray, np.ndarray]:
    """Tendon positions r_i(s) in the cross-section (m) and their slopes r_i'(s) along the rod
    (dimensionless), both (n, len(s), 2), at arc lengths ``s_m`` (m); see :func:`tendon_offsets_m`."""
    t, length = params.tendons, params.backbone.length_m
    s = np.asarray(s_m, dtype=float)[None, :]
    alpha = np.radians(np.asarray(t.angles_deg))[:, None] + np.zeros_like(s)
    radius = np.full_like(alpha, t.radius_m)
    turn = np.zeros_like(alpha)
    grow = np.zeros_like(alpha)
    if t.routing == "helical":
        rate = 2.0 * math.pi * t.helix_turns / length
        alpha = alpha + rate * s
        turn = turn + rate
    elif t.routing == "converging":
        grow = grow + (t.tip_radius_m - t.radius_m) / length
        radius = t.radius_m + grow * s
    c, sn = np.cos(alpha), np.sin(alpha)
    offsets = np.stack([radius * c, radius * sn], axis=-1)
    slopes = np.stack([grow * c - radius * turn * sn, grow * sn + radius * turn * c], axis=-1)
    return offsets, slopes


@dataclasses.dataclass(frozen=True)
class TendonLength:
    """The continuous tendons' lengths over the backbone joints, to second order about the
    straight pose (the "continuous" routing of :data:`TENDON_SITES`).

    A continuously routed tendon at r(s) grows as |q|, q = v + u × r + r', along s (Rucker &
    Webster 2011). Element e of the chain (length h) has the strains of the joints that hold its
    compliance: its bend hinges (one element), and the slides and twist hinge of its block
    (:func:`slide_stations`, lumping n elements), each joint coordinate ξ being n·h times its
    strain. So element e's tendon length h|q_e| has, about the straight pose (q⁰ = r' + e_z,
    t = q⁰/|q⁰|, P = (I − t tᵀ)/|q⁰|),

        ∂ℓ/∂ξ_j = t · c_j / n_j           ∂²ℓ/∂ξ_j∂ξ_k = c_jᵀ P c_k / (n_j n_k h)

    with c_j = ∂q/∂(strain j): e_x, e_y, e_z for the slides sx, sy, az, e_x × r, e_y × r, e_z × r
    for the hinges bx, by, tz. The gradient is the fixed tendon's coefficients: y, −x on the bend
    hinges and 1 on the axial slide for straight routing; helical routing adds the twist hinges
    (ρ²ω/|q⁰|: the tendons' tension twists the rod) and the shear slides (r'/|q⁰|). The Hessian
    times the tension is the tendon's geometric stiffness, which a linear fixed tendon has not:
    T on each shear slide (T adds to GA), T·ρ² on each twist hinge (T·ρ² adds to the torsional
    stiffness) and the shear–twist couplings −T·y, T·x (the predictor's R&W 2011 Jacobian blocks).

    Attributes:
        joints: names of the backbone joints, in the model's order.
        gradient: (n, J) ∂ℓ_i/∂ξ_j (m per m of slide, m per rad of hinge).
        hessian: (n, J, J) ∂²ℓ_i/∂ξ_j∂ξ_k (1/m, 1 and m per rad², by joint kinds).
    """

    joints: tuple[str, ...]
    gradient: np.ndarray
    hessian: np.ndarray

    @classmethod
    def from_params(cls, params: Params, layout: "Layout") -> "TendonLength":
        """The tendons of ``params`` over the joints of ``layout``'s chain (:func:`station_joints`)."""
        n, h = layout.elements, layout.element_length_m
        joints = [f"b{k}_{joint[0]}" for k in range(1, n + 1) for joint in station_joints(params, k, elements=n)]
        index = {name: j for j, name in enumerate(joints)}
        s_e = h * (np.arange(1, n + 1) - 0.5)
        xy, slope = tendon_route(params, s_e)
        count = xy.shape[0]
        r = np.concatenate([xy, np.zeros((count, n, 1))], axis=2)
        q0 = np.concatenate([slope, np.ones((count, n, 1))], axis=2)
        norm = np.linalg.norm(q0, axis=2)
        t = q0 / norm[..., None]
        p = (np.eye(3)[None, None] - t[..., :, None] * t[..., None, :]) / norm[..., None, None]
        # Each element's joints, one slot per kind (−1: the chain has none), and what they lump.
        slide_block, twist_block = _blocks(n, params.sim.slide_stride), _blocks(n, params.sim.twist_stride)
        kinds = ("sx", "sy", "az", "tz", "bx", "by")
        slot = np.full((n, len(kinds)), -1)
        lumped = np.ones((n, len(kinds)))
        for e in range(1, n + 1):
            for a, kind in enumerate(kinds):
                middle, size = (slide_block[e] if kind in ("sx", "sy", "az") else twist_block[e] if kind == "tz"
                                else (e, 1))
                slot[e - 1, a] = index.get(f"b{middle}_{kind}", -1)
                lumped[e - 1, a] = size
        # c = ∂q/∂(strain) per kind, (count, n, kinds, 3): e_x, e_y, e_z, then e_z, e_x, e_y × r.
        unit = np.broadcast_to(np.eye(3), (count, n, 3, 3))
        columns = np.concatenate([unit, np.cross(np.eye(3)[[2, 0, 1]][None, None], r[:, :, None, :])], axis=2)
        present = slot >= 0
        grad = np.einsum("tek,teak->tea", t, columns) / lumped
        hess = np.einsum("teak,tekl,tebl->teab", columns, p, columns) / (lumped[:, :, None] * lumped[:, None, :] * h)
        # A tendon anchored before the tip spans only the elements up to its anchor.
        inside = (s_e[None, :] < layout.tendon_end_m[:, None]).astype(float)
        grad, hess = grad * inside[:, :, None], hess * inside[:, :, None, None]
        gradient = np.zeros((count, len(joints)))
        hessian = np.zeros((count, len(joints), len(joints)))
        e_idx, a_idx = np.nonzero(present)
        # numpy's stubs give ufunc.at integer indices only; a tuple of index arrays is what it takes at run time.
        np.add.at(gradient, (slice(None), slot[e_idx, a_idx]), grad[:, e_idx, a_idx])  # type: ignore[arg-type]
        pairs = [(e, a, b) for e, a in zip(e_idx, a_idx) for b in np.nonzero(present[e])[0]]
        pe, pa, pb = (np.array(x) for x in zip(*pairs))
        np.add.at(hessian, (slice(None), slot[pe, pa], slot[pe, pb]), hess[:, pe, pa, pb])  # type: ignore[arg-type]
        return cls(tuple(joints), gradient, hessian)

    def geometric_stiffness(self, model: mujoco.MjModel, *, rtol: float = 1e-12) -> GeometricStiffness:
        """The Hessian's entries on ``model``'s joints, as the plant loop applies them each step.

        Entries below ``rtol`` × the joints' own stiffness (per newton of tension) are left out:
        straight routing has none on the bend hinges and axial slides, and couples only shear to
        twist.
        """
        n = self.hessian.shape[0]
        ids = np.array([model.joint(name).id for name in self.joints], dtype=np.int32)
        qpos, dofs = model.jnt_qposadr[ids], model.jnt_dofadr[ids]
        # The joints' own stiffness sets the scale of what is negligible on them (per newton).
        scale = np.sqrt(np.outer(model.jnt_stiffness[ids], model.jnt_stiffness[ids]))
        keep = np.abs(self.hessian).max(axis=0) > rtol * scale
        diagonal = [j for j in range(len(ids)) if keep[j, j]]
        pairs = [(a, b) for a in range(len(ids)) for b in range(a + 1, len(ids)) if keep[a, b]]
        joint_rows = np.array([[ids[j], qpos[j]] for j in diagonal], dtype=np.int32).reshape(-1, 2)
        pair_rows = np.array([[qpos[a], dofs[a], qpos[b], dofs[b]] for a, b in pairs], dtype=np.int32).reshape(-1, 4)
        return GeometricStiffness(
            joints=joint_rows, base_n_per_unit=model.jnt_stiffness[ids[diagonal]].copy(),
            joint_terms=np.array([self.hessian[:, j, j] for j in diagonal]).reshape(-1, n),
            pairs=pair_rows, pair_terms=np.array([self.hessian[:, a, b] for a, b in pairs]).reshape(-1, n))


@dataclasses.dataclass(frozen=True)
class GeometricStiffness:
    """The entries of :attr:`TendonLength.hessian` the plant loop applies before each step
    (``twin/sim/native/loop.cpp``, ``tendon_geometry``): with the tensions T_i of the last step,

    - each stiffened joint's stiffness is its own plus Σ_i T_i H_i,jj (integrated implicitly);
    - each coupled pair (a, b) pulls with −Σ_i T_i H_i,ab on each other's coordinate (explicitly);
    - tendon i's slack edge moves in by ½ ξᵀ H_i ξ, so that its spring stretches with its true length.

    Attributes:
        joints: (J, 2) int32 joint id and qpos address of each stiffened joint.
        base_n_per_unit: (J,) the joint's own stiffness (N/m or N·m/rad).
        joint_terms: (J, n) H_i,jj per tendon.
        pairs: (P, 4) int32 qpos and dof address of joint a, then of joint b.
        pair_terms: (P, n) H_i,ab per tendon.
    """

    joints: np.ndarray
    base_n_per_unit: np.ndarray
    joint_terms: np.ndarray
    pairs: np.ndarray
    pair_terms: np.ndarray

    def loop_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The loop's ``geometry`` (float64) and ``geometry_index`` (int32) buffers: per stiffened
        joint its base stiffness and terms, then per pair its terms; per joint its id and qpos
        address, then per pair its four addresses."""
        table = np.concatenate([np.column_stack([self.base_n_per_unit, self.joint_terms]).ravel(),
                                self.pair_terms.ravel()])
        index = np.concatenate([self.joints.ravel(), self.pairs.ravel()]).astype(np.int32)
        return np.ascontiguousarray(table, dtype=np.float64), np.ascontiguousarray(index)


def _blocks(elements: int, stride: int) -> dict[int, tuple[int, int]]:
    """For each station 1..N: (the middle station of its block of ``stride``, the block's size),
    the blocks of :func:`slide_stations`."""
    out = {}
    for first in range(1, elements + 1, stride):
        last = min(first + stride - 1, elements)
        for k in range(first, last + 1):
            out[k] = ((first + last) // 2, last - first + 1)
    return out


def _segment_inertia(mass_kg: float, length_m: float, radius_m: float) -> list[float]:
    """Principal inertia of a solid cylinder about its centre (kg·m²), axis along z."""
    lateral = mass_kg * (3.0 * radius_m**2 + length_m**2) / 12.0
    return [lateral, lateral, 0.5 * mass_kg * radius_m**2]


def _disc_inertia(mass_kg: float, params: Params) -> np.ndarray:
    d = params.discs
    return np.array(_segment_inertia(mass_kg, d.thickness_m, d.outer_radius_m))


def slide_stations(elements: int, stride: int) -> dict[int, int]:
    """Stations that carry lumped joints: ``{station: elements it lumps}``.

    The stations are cut into blocks of ``stride`` (``sim.slide_stride`` for the shear and axial
    slides, ``sim.twist_stride`` for the twist hinges; the last block may be shorter) and each
    block's middle station takes the compliance of the whole block, by the midpoint rule as the
    bend hinges take their element's. Stride 1 gives every
    station its own slides.
    """
    return dict(_blocks(elements, stride).values())


def station_joints(params: Params, station: int = 1, *, elements: int | None = None) -> tuple:
    """The joints of backbone station ``station`` (1..N), from :data:`STATION_JOINTS`: the shear
    slides if ``sim.shear_joints``, the axial slide if ``sim.axial_joints`` (both only where
    :func:`slide_stations` puts slides), and the bend and twist hinges.

    Two hinges in a row, x by a then y by b, turn the body by exp(aX + bY + ½ab·Z + …): a twist
    ab/2 that no spring resists. In the same order at every station it would add up along a rod
    bent out of the tendons' planes (κ = 26.2 1/m at φ = 45°: 3.5° of twist at N = 10; the tip
    0.39 mm off the arc at N = 20 and 0.18 mm at N = 40 instead of 0.21 and 0.05 mm, an error
    falling as 1/N rather than 1/N²), so even stations bend about y first and the twists cancel
    pairwise. A twist hinge after a bend turns the body by exp(aX + cZ − ½ac·Y + …): a bend ac/2
    that no tendon pulls for. Under helical routing the pretension alone twists the rod by 17°;
    with the twist hinge after the bends at every station those bends put the worst tip of the
    thesis grid 1.08 mm from the predictor instead of 0.28 mm (2.75 mm instead of 0.63 mm for a
    100 mm rod with G·J torsion), so every other twist station turns before its bends and the
    bends cancel pairwise, as the bend hinges' twists do.
    """
    n = params.sim.elements if elements is None else int(elements)
    slides = station in slide_stations(n, params.sim.slide_stride)
    wanted = {"shear": params.sim.shear_joints and slides, "axial": params.sim.axial_joints and slides,
              "bend": True, "twist": station in slide_stations(n, params.sim.twist_stride)}
    joints = [j for j in STATION_JOINTS if wanted[j[3]]]
    if station % 2 == 0:
        bx, by = (i for i, j in enumerate(joints) if j[3] == "bend")
        joints[bx], joints[by] = joints[by], joints[bx]
    twists = sorted(slide_stations(n, params.sim.twist_stride))
    if wanted["twist"] and twists.index(station) % 2 == 1:
        tz = joints.pop()
        joints.insert(next(i for i, j in enumerate(joints) if j[3] == "bend"), tz)
    return tuple(joints)


def build_spec(params: Params, *, base_rotation=HORIZONTAL, elements: int | None = None,
               tendon_sites: str | None = None) -> mujoco.MjSpec:
    """The MjSpec of the endoscope, rig and holder.

    Args:
        params: the parameter set.
        base_rotation: nominal clamp orientation (3×3, body → world); the effects turn it
            (:func:`twin.effects.clamp_rotation`).
        elements: number of elements N (default ``sim.elements``).
        tendon_sites: override of ``sim.tendon_routing`` (see :meth:`Layout.from_params`).
    """
    layout = Layout.from_params(params, elements=elements, tendon_sites=tendon_sites)
    sim = params.sim
    n, h = layout.elements, layout.element_length_m
    spec = mujoco.MjSpec()
    spec.modelname = "endoscope"
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    opt = spec.option
    opt.timestep = sim.timestep_s
    opt.integrator = mujoco.mjtIntegrator.mjINT_DISCRETE
    opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    # A serial chain's mass matrix is dense whatever the format; with no constraint row active the
    # Jacobian's format does not matter either (equal step times at 10, 20 and 40 elements).
    opt.jacobian = mujoco.mjtJacobian.mjJAC_DENSE
    # The solves' relative tolerance. The tendons' stiffness makes the discrete integrator solve
    # M + hD + h²K by conjugate gradients each step; stopping at 1e-3 rather than 1e-6 keeps a
    # tension step, a hung 10 g and a motor pulling (48 mm of tip motion) within 0.5 µm of the
    # 1e-6 trajectory and settled tips within 1e-8 m, at 1.3× the speed.
    opt.tolerance = 1e-3
    opt.gravity = [0.0, 0.0, -params.environment.gravity_m_s2]
    opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    spec.stat.center = [0.03, 0.0, 0.0]
    spec.stat.extent = 0.1

    clamp = spec.worldbody.add_body(
        name="clamp", quat=matrix_to_quat(effects.clamp_rotation(params, base_rotation)).tolist())
    clamp.add_geom(name="clamp", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[params.discs.outer_radius_m,
                   0.004, 0], pos=[0, 0, -0.004], rgba=[0.3, 0.3, 0.3, 1], contype=0, conaffinity=0)
    body_spec = effects.body_spec(params)
    stations = _add_backbone(spec, clamp, params, layout, body_spec)
    _add_discs(stations, params, layout, body_spec)
    tip = stations[n]
    tip.add_site(name="tip", pos=[0, 0, h / 2], size=_SITE_SIZE)
    load = tip.add_body(name="tip_load", pos=[0, 0, h / 2], mass=0.0, ipos=[0, 0, 0], inertia=[0, 0, 0])
    load.explicitinertial = True
    _add_tendons_and_spools(spec, clamp, stations, params, layout)
    for j, k in enumerate(layout.disc_body, start=1):
        weld = spec.add_equality(name=f"holder{j}", type=mujoco.mjtEq.mjEQ_WELD,
                                 objtype=mujoco.mjtObj.mjOBJ_BODY, name1=f"b{k}", name2="clamp")
        weld.active = False
        # A holder is rigid: as stiff a weld as the step resolves, not MuJoCo's default 20 ms.
        weld.solref[:2] = [2 * params.sim.timestep_s, 1.0]
        weld.solimp[:3] = [0.99, 0.999, 0.001]
    return spec


def _add_backbone(spec, clamp, params, layout, body_spec: effects.BodySpec) -> list:
    """The chain of N bodies with their elastic joints, carrying the body's line mass; returns
    [clamp, body 1, …, body N]."""
    b, sim = params.backbone, params.sim
    n, h = layout.elements, layout.element_length_m
    uniform = body_spec.line_mass_kg_per_m
    stiffness = {
        "shear": b.shear_stiffness_n / h, "axial": b.axial_stiffness_n / h,
        "bend": b.bending_stiffness_nm2 / h, "twist": b.torsional_stiffness_nm2 / h,
    }
    lumped = slide_stations(n, sim.slide_stride)
    twisted = slide_stations(n, sim.twist_stride)
    bodies = [clamp]
    parent = clamp
    for k in range(1, n + 1):
        span = h / 2 if k == n else h
        mass = uniform * span
        body = parent.add_body(name=f"b{k}", pos=[0, 0, h / 2 if k == 1 else h], mass=mass,
                               ipos=[0, 0, span / 2], inertia=_segment_inertia(mass, span, b.radius_m))
        body.explicitinertial = True
        for suffix, kind, axis, strain in station_joints(params, k, elements=n):
            k_joint = stiffness[strain] / (lumped[k] if kind == mujoco.mjtJoint.mjJNT_SLIDE
                                           else twisted[k] if strain == "twist" else 1)
            body.add_joint(name=f"b{k}_{suffix}", type=kind, axis=list(axis), stiffness=[k_joint, 0, 0],
                           damping=[sim.damping_time_s * k_joint, 0, 0])
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[0, 0, 0, 0, 0, span],
                      size=[b.radius_m, 0, 0], rgba=list(_RGBA_ROD), contype=0, conaffinity=0)
        bodies.append(body)
        parent = body
    return bodies


def _add_discs(stations, params, layout, body_spec: effects.BodySpec) -> None:
    """Disc geoms, and the body's disc masses (``discs.lumped_mass_kg`` and what the effects
    lump there, :class:`twin.effects.BodySpec`) folded into the carrying body's inertia."""
    d, b = params.discs, params.backbone
    disc_mass = body_spec.disc_mass_kg
    for s, k in zip(layout.disc_s_m, layout.disc_body):
        body = stations[k]
        z = s - layout.body_origin_s_m(k)
        # The tip disc's face is flush with the tip; the others are centred on their station.
        zc = z - d.thickness_m / 2 if k == layout.elements and abs(s - b.length_m) < 1e-12 else z
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER, pos=[0, 0, zc],
                      size=[d.outer_radius_m, d.thickness_m / 2, 0], rgba=list(_RGBA_DISC),
                      contype=0, conaffinity=0)
        if disc_mass > 0:
            m0, c0 = body.mass, np.array(body.ipos)
            i0 = np.array(body.inertia)
            m1 = m0 + disc_mass
            c1 = (m0 * c0 + disc_mass * np.array([0, 0, zc])) / m1
            # Parallel-axis shifts along z only: lateral inertia grows, axial does not.
            shift = np.array([1.0, 1.0, 0.0])
            i1 = (i0 + m0 * (c1[2] - c0[2]) ** 2 * shift
                  + _disc_inertia(disc_mass, params) + disc_mass * (c1[2] - zc) ** 2 * shift)
            body.mass, body.ipos, body.inertia = m1, c1.tolist(), i1.tolist()


def tendon_stiffness_n_per_m(params: Params) -> float:
    """Stiffness of each tendon (N/m): 1 / the body's tendon compliance
    (``effects.tendon_compliance_m_per_n``), or, with that effect off, 1 /
    :data:`INEXTENSIBLE_COMPLIANCE_M_PER_N`."""
    return 1.0 / max(effects.body_spec(params).tendon_compliance_m_per_n, INEXTENSIBLE_COMPLIANCE_M_PER_N)


def _add_tendons_and_spools(spec, clamp, stations, params, layout) -> None:
    motor = MotorConstants.from_rig(params.rig)
    lengths = TendonLength.from_params(params, layout)
    for i in range(params.tendons.count):
        x0, y0 = layout.tendon_xy_m[i, 0]
        clamp.add_site(name=f"hole{i}", pos=[x0, y0, 0], size=_SITE_SIZE)
        spool = clamp.add_body(name=f"spool{i}", pos=[x0, y0, -SPOOL_OFFSET_M],
                               mass=SPOOL_CARRIAGE_MASS_KG, inertia=[1e-9, 1e-9, 1e-9])
        spool.explicitinertial = True
        # The carriage stands for a drum turning on its axle: its weight does not pull the line.
        spool.gravcomp = 1.0
        spool.add_joint(name=f"spool{i}", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 0, 1],
                        armature=motor.reflected_mass_kg, damping=[SPOOL_DAMPING_N_S_PER_M, 0, 0],
                        limited=mujoco.mjtLimited.mjLIMITED_TRUE,
                        range=[-SPOOL_TRAVEL_M, SPOOL_TRAVEL_M])
        spool.add_site(name=f"spool{i}", size=_SITE_SIZE)
        spool.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.0015, 0, 0], rgba=[0.2, 0.2, 0.2, 1],
                       contype=0, conaffinity=0)
        tendon = spec.add_tendon(name=f"tendon{i}", width=params.tendons.diameter_m / 2,
                                 rgba=list(_RGBA_TENDON))
        # Pull-only elastic line: a spring that is slack below the straight length. A spring
        # rather than a length limit, because a soft constraint's stretch under a given tension
        # depends on the masses around it and so jumps when the spool switches drive mode.
        tendon.stiffness = [tendon_stiffness_n_per_m(params), 0, 0]
        fixed = layout.routing in _FIXED_ROUTINGS
        # The fixed tendon's length is its stretch from the straight pose; the lower end of the
        # dead band only has to lie below any slack a spool can pay out.
        tendon.springlength = ([-1.0, -TAUT_STRETCH_M] if fixed
                               else [0.0, float(layout.rest_length_m[i]) - TAUT_STRETCH_M])
        if fixed:
            for name, coefficient in zip(lengths.joints, lengths.gradient[i]):
                if coefficient != 0.0:
                    tendon.wrap_joint(name, float(coefficient))
            tendon.wrap_joint(f"spool{i}", -1.0)
        else:
            tendon.wrap_site(f"spool{i}")
            tendon.wrap_site(f"hole{i}")
        for j, (s, k) in enumerate(zip(layout.site_s_m, layout.site_body)):
            x, y = layout.tendon_xy_m[i, j + 1]
            name = f"t{i}_s{j + 1}"
            stations[k].add_site(name=name, pos=[x, y, s - layout.body_origin_s_m(k)], size=_SITE_SIZE)
            if not fixed and j < layout.tendon_site_count[i]:
                tendon.wrap_site(name)
    # Grouped by mode so that each mode's controls are one contiguous block of ctrl.
    for add in (_add_motor, _add_tension_source, _add_position_servo):
        for i in range(params.tendons.count):
            add(spec, i, motor)


_JOINT = mujoco.mjtTrn.mjTRN_JOINT


def _add_motor(spec, i: int, motor: MotorConstants) -> None:
    dc = spec.add_actuator(name=f"motor{i}", target=f"spool{i}", trntype=_JOINT,
                           group=ACTUATOR_GROUPS["pwm"], gear=[motor.transmission_rad_per_m, 0, 0, 0, 0, 0])
    dc.set_to_dcmotor(motorconst=[motor.torque_constant_nm_per_a] * 2, resistance=motor.resistance_ohm)
    dc.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    dc.ctrlrange = [-motor.supply_voltage_v, motor.supply_voltage_v]


def _add_tension_source(spec, i: int, motor: MotorConstants) -> None:
    pull = spec.add_actuator(name=f"tension{i}", target=f"spool{i}", trntype=_JOINT,
                             group=ACTUATOR_GROUPS["tension"], gear=[-1.0, 0, 0, 0, 0, 0])
    pull.set_to_motor()
    pull.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    pull.ctrlrange = [0.0, TENSION_SOURCE_MAX_N]


def _add_position_servo(spec, i: int, motor: MotorConstants) -> None:
    servo = spec.add_actuator(name=f"length{i}", target=f"spool{i}", trntype=_JOINT,
                              group=ACTUATOR_GROUPS["length"], gear=[1.0, 0, 0, 0, 0, 0])
    servo.set_to_position(kp=POSITION_GAIN_N_PER_M,
                          kv=2.0 * math.sqrt(POSITION_GAIN_N_PER_M * SPOOL_CARRIAGE_MASS_KG))
    servo.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    servo.ctrlrange = [-SPOOL_TRAVEL_M, SPOOL_TRAVEL_M]


def build_model(params: Params, *, base_rotation=HORIZONTAL, elements: int | None = None,
                tendon_sites: str | None = None) -> mujoco.MjModel:
    """Compiled :func:`build_spec`."""
    return build_spec(params, base_rotation=base_rotation, elements=elements,
                      tendon_sites=tendon_sites).compile()


def model_xml(params: Params, *, base_rotation=HORIZONTAL) -> str:
    """MJCF text of the model (what ``models/endoscope/endoscope.xml`` holds for the default parameters)."""
    spec = build_spec(params, base_rotation=base_rotation)
    spec.compile()
    return spec.to_xml()
