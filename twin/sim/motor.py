"""The spool drive: Maxon DC gear motor behind a DRV8871 H-bridge, and its quadrature encoder.

The thesis gives the motor as "24 V, 0.13 N·m, 1321 rpm, gearbox 5.3:1" (thesis §4). Read as the
figures of the gear motor's *output shaft*: 1321 rpm × 5.3 ≈ 7000 rpm and 0.13 N·m / 5.3 ≈
25 mN·m at the motor shaft are the rated point of a ~20 W Maxon motor, while motor-shaft
figures would put 815 N on a 0.4 mm line. The encoder sits on the motor shaft (4 × 1024
counts per motor revolution, thesis §4).

Derivations (linear DC motor, electrical time constant neglected — it is well under the 1 ms
step), all referred to the output shaft from ``rig.*``:

    K = V / ω₀                    (back-EMF = torque constant, V·s/rad = N·m/A)
    R = K · V / τ_stall           (terminal resistance, Ω)
    τ = K (V_pwm − K ω) / R       (output torque, N·m)

and to the tendon (spool radius r, tendon paid out x = r θ):

    F = τ / r,   back-EMF damping c = K² / (R r²),   reflected mass m = J_rotor G² / r².

The H-bridge is driven by a PWM duty in [−1, 1]: the mean terminal voltage is duty × supply
(slow-decay, i.e. brake, PWM, which is linear in the duty). Positive duty pays tendon out.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from twin.params import Rig

__all__ = ["MotorConstants", "spool_position_m"]


@dataclasses.dataclass(frozen=True)
class MotorConstants:
    """Electrical and mechanical constants of one spool drive, derived from ``rig.*``.

    Attributes:
        supply_voltage_v: H-bridge supply (V).
        torque_constant_nm_per_a: K at the output shaft (N·m/A = V·s/rad).
        resistance_ohm: terminal resistance R (Ω).
        transmission_rad_per_m: output-shaft angle per metre of tendon, 1/r (rad/m).
        reflected_mass_kg: rotor inertia seen at the tendon, J_rotor G² / r² (kg).
        back_emf_damping_n_s_per_m: damping of a shorted motor seen at the tendon, K²/(R r²).
        stall_force_n: tendon force at stall and full supply, τ_stall / r (N).
        no_load_speed_m_per_s: tendon speed at no load and full supply, ω₀ r (m/s).
    """

    supply_voltage_v: float
    torque_constant_nm_per_a: float
    resistance_ohm: float
    transmission_rad_per_m: float
    reflected_mass_kg: float
    back_emf_damping_n_s_per_m: float
    stall_force_n: float
    no_load_speed_m_per_s: float

    @classmethod
    def from_rig(cls, rig: Rig) -> "MotorConstants":
        omega0 = rig.motor_no_load_speed_rpm * 2.0 * math.pi / 60.0
        k = rig.motor_voltage_v / omega0
        resistance = k * rig.motor_voltage_v / rig.motor_stall_torque_nm
        r = rig.spool_radius_m
        return cls(
            supply_voltage_v=rig.motor_voltage_v,
            torque_constant_nm_per_a=k,
            resistance_ohm=resistance,
            transmission_rad_per_m=1.0 / r,
            reflected_mass_kg=rig.motor_reflected_mass_kg,
            back_emf_damping_n_s_per_m=k * k / (resistance * r * r),
            stall_force_n=rig.motor_stall_force_n,
            no_load_speed_m_per_s=rig.motor_no_load_speed_m_per_s,
        )


def spool_position_m(counts, rig: Rig) -> np.ndarray:
    """Tendon paid out (m) at the lower edge of each encoder count: the inverse of the plant's
    quadrature counter (:meth:`twin.sim.plant.Plant.encoder_counts`, the floor of the tendon
    paid out over ``Rig.tendon_m_per_count``: 2π / (4·1024) rad of motor shaft, 9.4e-7 m)."""
    return np.asarray(counts, dtype=float) * rig.tendon_m_per_count
