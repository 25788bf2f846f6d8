"""The rod model the predictor solves: geometry, stiffness, routing and loads, as plain data.

A :class:`RodModel` is built from the parameter set (:meth:`RodModel.from_params`) or by hand
(any routing, tendons ending anywhere along the rod), and is immutable: the solver caches its
compiled arrays.
"""

from __future__ import annotations

import dataclasses
import math
from functools import cached_property

import numpy as np

from twin import effects
from twin.params import Params
from twin.rod import kernel

__all__ = ["RodModel", "TendonRoute"]


@dataclasses.dataclass(frozen=True)
class TendonRoute:
    """One tendon's path through the discs, in the body frame.

    r_i(s) = ρ(s) (cos θ(s), sin θ(s), 0) with ρ linear from ``radius_m`` at the base to
    ``tip_radius_m`` at the rod's tip (converging routing) and θ(s) = angle + helix_rate·s
    (helical routing). The tendon is anchored at ``end_m`` (default: the tip).
    """

    radius_m: float
    angle_deg: float
    helix_rad_per_m: float = 0.0
    tip_radius_m: float | None = None
    end_m: float | None = None


@dataclasses.dataclass(frozen=True, eq=False)
class RodModel:
    """A uniform Cosserat rod with tendons, its weight, and the solver's settings.

    Attributes:
        length_m: rod length L.
        shear_stiffness_n, axial_stiffness_n: GA and EA (K_se = diag(GA, GA, EA)).
        bending_stiffness_nm2, torsional_stiffness_nm2: EI and the torsional stiffness
            (K_bt = diag(EI, EI, K_t)).
        tendons: routes; tension order follows this tuple.
        line_mass_kg_per_m: weight spread uniformly along the rod.
        point_masses: ((s_m, mass_kg), ...) lumped masses (discs).
        gravity_m_s2: magnitude of g, along world −z.
        steps: RK4 steps over the length (more are added to hit every event point).
        tolerance: Newton stops when |m(L) − M_e| ≤ tolerance · EI / L (dimensionless).
        max_iterations: Newton iterations per continuation step.
        friction_coeff: capstan coefficient μ per radian of tendon wrap (0 = frictionless).
        precurvature_per_m: intrinsic curvature u* of the unloaded rod, body frame (1/m; bending
            about the body x and y axes, twist about z), constant along it; no parameter of the
            parameter set carries it (a rod built straight), the discrepancy workflow's probes
            and generators set it.
    """

    length_m: float
    shear_stiffness_n: float
    axial_stiffness_n: float
    bending_stiffness_nm2: float
    torsional_stiffness_nm2: float
    tendons: tuple[TendonRoute, ...]
    gravity_m_s2: float
    line_mass_kg_per_m: float = 0.0
    point_masses: tuple[tuple[float, float], ...] = ()
    steps: int = 40
    tolerance: float = 1e-9
    max_iterations: int = 30
    friction_coeff: float = 0.0
    precurvature_per_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        for name in ("length_m", "shear_stiffness_n", "axial_stiffness_n", "bending_stiffness_nm2",
                     "torsional_stiffness_nm2"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"RodModel.{name} = {value!r}: must be finite and > 0")
        if self.steps < 1:
            raise ValueError(f"RodModel.steps = {self.steps!r}: must be >= 1")
        for t in self.tendons:
            end = self.length_m if t.end_m is None else t.end_m
            if not 0 < end <= self.length_m + 1e-12:
                raise ValueError(f"TendonRoute.end_m = {t.end_m!r}: must be in (0, {self.length_m}]")
        for s, m in self.point_masses:
            if not (0 < s <= self.length_m + 1e-12 and m >= 0):
                raise ValueError(f"point mass ({s!r} m, {m!r} kg): needs 0 < s <= L and mass >= 0")

    @classmethod
    def from_params(cls, params: Params, *, steps: int | None = None, with_effects: bool = True) -> "RodModel":
        """The endoscope of a parameter set.

        With ``with_effects`` the effects that change the rod itself are included, as they build
        the body (:func:`twin.effects.body_spec`: disc mass lumping, tendon friction).
        Sensor-side effects (gains, offsets, tracker offset, tilt) belong to the callers.
        """
        b, t, d = params.backbone, params.tendons, params.discs
        body = effects.body_spec(params) if with_effects else effects.BodySpec.nominal(params)
        disc_s = [b.length_m * (k + 1) / d.count for k in range(d.count)]
        disc_mass = body.disc_mass_kg
        routes = []
        for angle, end in zip(t.angles_deg, params.tendon_ends_m()):
            helix = 0.0
            tip_radius = None
            if t.routing == "helical":
                helix = 2 * math.pi * t.helix_turns / b.length_m
            elif t.routing == "converging":
                tip_radius = t.tip_radius_m
            routes.append(TendonRoute(t.radius_m, angle, helix_rad_per_m=helix, tip_radius_m=tip_radius,
                                      end_m=None if end >= b.length_m else end))
        return cls(
            length_m=b.length_m,
            shear_stiffness_n=b.shear_stiffness_n,
            axial_stiffness_n=b.axial_stiffness_n,
            bending_stiffness_nm2=b.bending_stiffness_nm2,
            torsional_stiffness_nm2=b.torsional_stiffness_nm2,
            tendons=tuple(routes),
            line_mass_kg_per_m=body.line_mass_kg_per_m,
            point_masses=tuple((s, disc_mass) for s in disc_s) if disc_mass > 0 else (),
            gravity_m_s2=params.environment.gravity_m_s2,
            steps=params.predictor_steps() if steps is None else steps,
            tolerance=params.solver.tolerance,
            max_iterations=params.solver.max_iterations,
            friction_coeff=body.friction_coeff,
        )

    def replace(self, **changes) -> "RodModel":
        return dataclasses.replace(self, **changes)

    @property
    def tendon_count(self) -> int:
        return len(self.tendons)

    @property
    def total_mass_kg(self) -> float:
        return self.line_mass_kg_per_m * self.length_m + sum(m for _, m in self.point_masses)

    @property
    def moment_scale_nm(self) -> float:
        """EI / L (N·m): the natural moment unit the Newton tolerance is relative to."""
        return self.bending_stiffness_nm2 / self.length_m

    @cached_property
    def arrays(self) -> dict[str, np.ndarray]:
        """Compiled-kernel inputs that do not depend on the load case."""
        L = self.length_m
        event_set = {0.0, L}
        for t in self.tendons:
            if t.end_m is not None and t.end_m < L:
                event_set.add(float(t.end_m))
        for s, _ in self.point_masses:
            if s < L:
                event_set.add(float(s))
        events = sorted(event_set)
        h = L / self.steps
        nodes = [0.0]
        mids = []
        for a, b in zip(events[:-1], events[1:]):
            n = max(1, int(math.ceil((b - a) / h - 1e-9)))
            nodes.extend(a + (b - a) * (i + 1) / n for i in range(n))
            mids.extend([0.5 * (a + b)] * n)
        table = np.zeros((len(self.tendons), kernel.TENDON_COLUMNS))
        for i, t in enumerate(self.tendons):
            table[i, kernel.T_R0] = t.radius_m
            table[i, kernel.T_R1] = t.radius_m if t.tip_radius_m is None else t.tip_radius_m
            table[i, kernel.T_ALPHA] = math.radians(t.angle_deg)
            table[i, kernel.T_OMEGA] = t.helix_rad_per_m
            table[i, kernel.T_END] = L if t.end_m is None else t.end_m
        pm = np.array(self.point_masses, dtype=float).reshape(-1, 2)
        # The weight distal to each station (kg): the rod beyond it and the point masses beyond its
        # interval's midpoint (the last station takes the last interval's), as kernel.integrate does per RK4 stage.
        stations = np.array(nodes)
        midpoints = np.array(mids + mids[-1:])
        distal = self.line_mass_kg_per_m * (L - stations) + (pm[None, :, 1] * (pm[None, :, 0] > midpoints[:, None])).sum(1)
        grav = np.array([0.0, 0.0, -self.gravity_m_s2])
        return {
            "routes": _routes(table, L, stations, np.array(mids)),
            "distal_mass_kg": distal,
            # The weight distal to each station (N, (K, 3)): the load-free part of n(s).
            "distal_weight_n": distal[:, None] * grav,
            "nodes": np.array(nodes),
            "intervals": np.array(mids),
            "kse": np.array([self.shear_stiffness_n, self.shear_stiffness_n, self.axial_stiffness_n]),
            "kbt": np.array([self.bending_stiffness_nm2, self.bending_stiffness_nm2,
                             self.torsional_stiffness_nm2]),
            "tendons": table,
            "pm_s": np.ascontiguousarray(pm[:, 0]),
            "pm_m": np.ascontiguousarray(pm[:, 1]),
            "grav": grav,
            "ustar": np.array(self.precurvature_per_m, dtype=float).reshape(3),
        }

    @property
    def stations(self) -> int:
        return self.arrays["nodes"].shape[0]


def _routes(table: np.ndarray, length_m: float, nodes: np.ndarray, mids: np.ndarray) -> np.ndarray:
    """The tendons' body-frame routes at each RK4 step's stations s, s + h/2 and s + h, as the
    kernel's :class:`~twin.rod.kernel.RodInputs` carries them: (K, 3, nt, ROUTE_COLUMNS).

    r_i(s) = ρ(s) (cos θ(s), sin θ(s), 0), ρ linear from the base radius to the tip radius,
    θ(s) = α + ω s; a tendon anchored before the step's interval midpoint is off there.
    """
    s = nodes[:-1]
    h = nodes[1:] - s
    at = np.stack([s, s + 0.5 * h, s + h], axis=1)[:, :, None]  # stations the RK4 stages evaluate at
    r0 = table[:, kernel.T_R0]
    drho = (table[:, kernel.T_R1] - r0) / length_m
    omega = table[:, kernel.T_OMEGA]
    rho = r0 + drho * at
    theta = table[:, kernel.T_ALPHA] + omega * at
    c, sn = np.cos(theta), np.sin(theta)
    out = np.empty(rho.shape + (kernel.ROUTE_COLUMNS,))
    out[..., kernel.RT_X] = rho * c
    out[..., kernel.RT_Y] = rho * sn
    out[..., kernel.RT_DX] = drho * c - rho * omega * sn
    out[..., kernel.RT_DY] = drho * sn + rho * omega * c
    out[..., kernel.RT_ON] = (table[:, kernel.T_END] >= mids[:, None, None]).astype(float)
    return out
