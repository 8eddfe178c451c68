"""``supply_resistance``: a dcmotor servo's drive falling with its duty (a resistance ahead of its
H-bridge), written each physics step as the servo's force range at the state.

Kept out of ``catalogue`` (the table of effects, at its line limit); listed in its ``EFFECTS``.
"""

from __future__ import annotations

import numpy as np

from lowcostdex.sim import servo
from lowcostdex.sim.effects.base import Effect, Fields, Param, Targets, Values, dcmotor_targets


class SupplyResistance(Effect):
    name = "supply_resistance"
    kind = "model"
    live = True
    doc = ("a resistance between the point where a dcmotor servo reads its supply voltage and its "
           "H-bridge (protection FET, connector, traces): the bridge draws duty x winding current "
           "through it, so its voltage falls with the drive it is asked for and the winding "
           "current is i = (d V - K w) / (R + resistance d^2) (d the firmware's duty, V the supply "
           "it reads): full-duty (stall) torque falls by R / (R + resistance), a small duty's "
           "hardly at all")
    # The XL330 on Rhoban's 7.4 V bench (bench/RESULTS.md gap-stall7): the logged PWM equals the
    # P law in the servo's units (slope 1.00 on all 16 logs), yet the load the arm breaks away
    # upward against per unit of duty x read voltage falls from ~0.06 N m/V at duty 0.3 to
    # 0.04-0.05 at duty 0.85-1: a drive that saturates softly with the duty, which a constant K/R
    # (motor_strength), the read voltage (voltage_sag) or a hard current clip (torque_limit) do not
    # give. Derivation: bridge voltage V - r d i, winding sees d (V - r d i); i (R + r d^2) = d V - K w.
    params = (Param("resistance", 0.0, 0.0, 10.0, "ohm", (0.0, 0.5), start=1.0,
                    limit=(0.0, 50.0), on="dcmotor",
                    doc="series resistance ahead of the bridge (winding side: R)"),)
    fields = ()

    @classmethod
    def live_apply(cls, f: Fields, t: Targets, v: Values, qvel: np.ndarray,
                   forcerange: np.ndarray) -> None:
        """Each physics step: the force range of the targets' dcmotor servos (..., nu, 2), in
        place, narrowed to +-|tau|, tau = K (d V - K w) / (R + r d^2) the drive torque with the
        resistance r at this state (gains as the exogenous effects left them; d V the dcmotor's
        drive voltage from its P and D paths on the goal, or on the slewed goal where the
        firmware slews it, clipped at Vmax; an integrator's share is not included). The
        force-limit flag is set where r > 0; a null (0) resistance leaves the range as it was."""
        dc = dcmotor_targets(f, t)
        if not np.any(dc):
            return
        a, dofs = t.actuators[dc], t.dofs[dc]
        r_s = np.broadcast_to(np.asarray(v["resistance"], float), qvel.shape[:-1] + (len(dc),))
        r_s = r_s[..., dc]
        g = f.array("actuator_gainprm")[..., a, :]
        res, k = g[..., servo.GAIN_R], g[..., servo.GAIN_K]
        gear = f.nominal("actuator_gear")[a, 0]
        w = gear * qvel[..., dofs]
        ctrl = np.asarray(f.ctrl)[..., a]
        cr = f.nominal("actuator_ctrlrange")[a]
        ctrl = np.where(f.nominal("actuator_ctrllimited")[a] > 0,
                        np.clip(ctrl, cr[:, 0], cr[:, 1]), ctrl)
        # a firmware that slews its goal (compiled slewmax) drives toward the slewed goal, its
        # first activation
        slewed = f.nominal("actuator_dynprm")[a, servo.DYN_SLEWMAX] > 0
        if np.any(slewed):
            adr = np.maximum(f.nominal("actuator_actadr")[a], 0)
            ctrl = np.where(slewed, np.asarray(f.act)[..., adr], ctrl)
        q = gear * np.asarray(f.qpos)[..., t.qpos[dc]]
        vmax = g[..., servo.GAIN_VMAX]
        volts = np.clip(res / k * (g[..., servo.GAIN_KP] * (ctrl - q) - g[..., servo.GAIN_KD] * w)
                        + k * w, -vmax, vmax)
        # the supply the bridge switches: the nominal one, rescaled as the exogenous effects
        # rescaled Vmax (voltage_sag)
        vmax0 = f.nominal("actuator_gainprm")[a, servo.GAIN_VMAX]
        supply = f.nominal("actuator_user")[a, servo.USER_SUPPLY_VOLTAGE] * vmax / vmax0
        duty = volts / np.where(supply > 0, supply, 1.0)
        tau = np.abs(k * (volts - k * w) / (res + r_s * duty * duty)) / np.abs(gear)
        lim = f.array("actuator_forcelimited")[..., a] > 0
        lo = np.where(lim, forcerange[..., a, 0], -np.inf)
        hi = np.where(lim, forcerange[..., a, 1], np.inf)
        on = r_s > 0
        forcerange[..., a, 0] = np.where(on, np.clip(-tau, lo, hi), forcerange[..., a, 0])
        forcerange[..., a, 1] = np.where(on, np.clip(tau, lo, hi), forcerange[..., a, 1])
        f.array("actuator_forcelimited")[..., a] = np.where(on, 1, lim)
