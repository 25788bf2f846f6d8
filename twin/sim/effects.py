"""Effects real rigs have, as the twin makes them happen (``[effects]`` in the parameter set).

All are off (zero) by default. Each changes the data the way the physical effect would, so the
discrepancy workflow can find it from recordings alone:

=============================  ====================================================================
``tendon_friction_coeff`` μ    Capstan friction at the disc holes (:class:`TendonFriction`): the
                               tension decays as e^(−μθ) over the wrap angle θ from the spool to
                               each disc while the tendon is pulled, and grows so while it is
                               released; the load cell, at the spool, reads the undecayed end. So
                               the tip bends less than the measured tension says on loading, more
                               on unloading: hysteresis.
``tendon_compliance_m_per_n``  The tendon stretches this much per newton over its length (its
                               dead-band spring, :mod:`twin.sim.model`, is that much softer than
                               the practically inextensible default). Encoders see the spool, not
                               the stretch.
``tension_gain_error``,        What each load cell reports against the true tension
``tension_offset_error_n``     (:class:`twin.sim.sensors.LoadCells`).
``disc_mass_fraction``         This fraction of ``backbone.mass_kg`` sits at the discs instead of
                               spread uniformly (:mod:`twin.sim.model`): the sag changes shape.
``base_tilt_deg``              The clamp is tilted about world x, then y, on top of the nominal base
                               orientation (:func:`twin.sim.model.clamp_rotation`); the world,
                               gravity and the tracker stay put.
``tip_load_error_fraction``    A hung mass weighs this fraction more than its nominal value
                               (:meth:`twin.sim.plant.Plant.set_tip_mass_kg`).
``tracker_offset_m``           The probe cap's origin is this far from the tip, in the tip frame
                               (:class:`twin.sim.sensors.Tracker`).
=============================  ====================================================================
"""

from __future__ import annotations

import mujoco
import numpy as np

__all__ = ["FRICTION_MAX_STEP_S", "PRESLIDING_M", "TendonFriction"]

# Tendon travel over which the friction turns from one direction to the other (m): the
# presliding (Dahl) displacement of a braided line in a printed hole, an assumption of a few
# hundredths of a millimetre, well above an encoder count (0.94 µm).
PRESLIDING_M = 2e-5
# Longest physics step (s) the explicit friction update is stable at: measured, a spool pulled in
# tension mode settles at 1 ms and chatters (±0.03 N of spool tension) at 2.5 ms; in the twin's
# friction sweep (tests/test_discrepancy_twin.py) 1 ms steps diverged once, in tension mode after
# 124 s, and 0.83 ms steps (2.5 ms / 3, 5 ms / 6) never did.
FRICTION_MAX_STEP_S = 0.84e-3


class TendonFriction:
    """Capstan friction of the tendons over the disc holes, applied as body forces.

    MuJoCo's tendon carries one tension T₀ along its whole path — the spool's. With friction
    coefficient μ the tension in segment k (spool = 0) is T_k = T₀ exp(−σ μ Σ_{m≤k} θ_m), where
    θ_m is the angle the tendon turns at site m (the base hole and each disc, or each joint
    with continuous routing) and σ ∈ [−1, 1]
    the state of a Dahl model of the sliding direction: σ → +1 while the spool pulls tendon
    in, → −1 while it pays out, over :data:`PRESLIDING_M` of travel, and it holds when the
    tendon stops, so a static state remembers how it was reached. The difference between the
    friction profile and MuJoCo's uniform one is added at each disc site as a force (and its
    moment about the body's centre of mass) through ``xfrc_applied``; the forces include the
    friction on the disc, so momentum balances.

    Call :meth:`apply` before every step of at most :data:`FRICTION_MAX_STEP_S`; it costs a few
    tens of µs of Python, which is why the plant only steps one step at a time when friction is on.
    """

    def __init__(self, model: mujoco.MjModel, coeff: float, spool_dofs: np.ndarray, sites: np.ndarray):
        """Args:
            model: the compiled twin.
            coeff: μ per radian of wrap.
            spool_dofs: (n,) dof index of each spool.
            sites: (n, S) site ids along each tendon's path, spool first, tip last.
        """
        self.coeff = float(coeff)
        self._sites = np.asarray(sites)
        self._bodies = model.site_bodyid[self._sites]
        self._spool_dofs = np.asarray(spool_dofs)
        self.state = np.zeros(len(self._sites))

    def reset(self) -> None:
        self.state[:] = 0.0

    def apply(self, model: mujoco.MjModel, data: mujoco.MjData, spool_tension_n: np.ndarray) -> None:
        """Update the sliding state over the last step and set ``data.xfrc_applied``."""
        pull_speed = -data.qvel[self._spool_dofs]
        self.state = np.clip(self.state + pull_speed * model.opt.timestep / PRESLIDING_M, -1.0, 1.0)
        p = data.site_xpos[self._sites]                          # (n, S, 3)
        seg = np.diff(p, axis=1)
        u = seg / np.linalg.norm(seg, axis=2, keepdims=True)      # (n, S-1, 3)
        cos = np.clip(np.einsum("nkj,nkj->nk", u[:, :-1], u[:, 1:]), -1.0, 1.0)
        wrap = np.cumsum(np.arccos(cos), axis=1)                  # at sites 1 .. S-2
        t0 = np.asarray(spool_tension_n, dtype=float)[:, None]
        decay = np.exp(-self.state[:, None] * self.coeff * wrap)
        excess = np.concatenate([np.zeros_like(t0), t0 * (decay - 1.0)], axis=1)  # T_k − T₀
        pulls = excess[:, :, None] * u                            # per segment
        force = np.zeros_like(p)
        force[:, 1:] -= pulls                                     # towards the previous site
        force[:, :-1] += pulls                                    # towards the next site
        data.xfrc_applied[:] = 0.0
        bodies = self._bodies.ravel()
        f = force.reshape(-1, 3)
        torque = np.cross(p.reshape(-1, 3) - data.xipos[bodies], f)
        np.add.at(data.xfrc_applied[:, :3], bodies, f)
        np.add.at(data.xfrc_applied[:, 3:], bodies, torque)
