"""The exogenous effects (``thermal_derating``, ``voltage_sag``: a measured temperature or supply
voltage rescales the drive each control step) and the drive scale they set on every actuator kind.

One physical thing on every kind (issue 11 item 1): a PWM drive's current per command goes as
V / R, so a hot winding (R = R0 (1 + a dT)) or a sagging supply (V < V_nom) gives less torque per
command and a lower force limit. A ``dcmotor`` servo carries its own motor model (R, K, firmware
gains, Vmax: rescaled in its gain fields, as before); on any other actuator (``motor``,
``position``, ``velocity``, ``general`` with fixed or affine gain and bias) the plant multiplies
its torque per command (gainprm[0:3] and the servo's bias biasprm[0:3], so a position servo keeps
its goal and its kp/kv ratio) and its force range by the effects' drive scale (``scale_drive``).
Kept out of ``catalogue`` (the table of effects); listed in its ``EFFECTS``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.sim import servo
from lowcostdex.sim.effects.base import (
    DEFAULT_REFERENCE_TEMPERATURE,
    Effect,
    Fields,
    Param,
    Targets,
    Values,
)
from lowcostdex.sim.effects.base import (
    dcmotor_targets as _dcmotor,
)

# The supply a drive without a servo's nominal one (a user's motor/position actuator, no
# actuator_user) is rated at when no log gives one: the D'Claw's servo (lowcostdex.motors).
DEFAULT_SUPPLY_MOTOR = "XM430-W210"


def _drive_rows(t: Targets, dc: np.ndarray, drive: np.ndarray | None) -> np.ndarray:
    """Actuator ids of the targets whose drive scale is written (not dcmotor servos)."""
    return t.actuators[~dc] if drive is not None else t.actuators[:0]


class ThermalDerating(Effect):
    name = "thermal_derating"
    kind = "exogenous"
    requires = ("temperature",)
    doc = ("winding resistance rises with the measured temperature: R = R0 (1 + a (T - T_ref)); "
           "a dcmotor servo's R (its firmware gains and stall torque follow), on any other "
           "actuator (motor, position, velocity, general) the torque per command and the force "
           "range divided by 1 + a (T - T_ref) (a PWM drive's current is V / R)")
    params = (Param("tempcoef", 0.0, 0.0, 0.03, "1/K", (0.0039, 0.0039), start=0.004,
                    limit=(0.0, 0.1)),)

    @classmethod
    def exogenous(cls, f: Fields, t: Targets, v: Values, channels: Mapping[str, np.ndarray],
                  gain: np.ndarray, drive: np.ndarray | None = None) -> None:
        temp = channels["temperature"]  # (..., n_targets) [deg C]
        dc = _dcmotor(f, t)
        tref = f.nominal("actuator_gainprm")[t.actuators, servo.GAIN_TREF]
        # servos compiled without a thermal state carry no reference (and another actuator's
        # gainprm[3] is no temperature): use 25 deg C
        tref = np.where((tref > 0) & dc, tref, DEFAULT_REFERENCE_TEMPERATURE)
        factor = np.maximum(1.0 + v["tempcoef"] * (temp - tref), 0.2)
        if np.any(dc):
            scale_resistance(gain, t.actuators[dc], factor[..., dc])
        rows = _drive_rows(t, dc, drive)
        if len(rows):
            drive[..., rows] = drive[..., rows] / factor[..., ~dc]


class VoltageSag(Effect):
    name = "voltage_sag"
    kind = "exogenous"
    requires = ("voltage",)
    optional = ("supply",)
    doc = ("the supply follows the measured input voltage instead of the nominal one: "
           "V = V_nom + weight (V_meas - V_nom); a dcmotor servo's drive voltage, firmware gains "
           "and Vmax scale with V / V_nom (its nominal from the servo's model); on any other "
           "actuator (motor, position, velocity, general: a PWM drive) the torque per command "
           "and the force range, V_nom the log's unloaded supply (channel ``supply``: its "
           "highest reading) or the catalogue servo's when no log gives one")
    params = (Param("weight", 0.0, 0.0, 1.5, "1", (1.0, 1.0), start=0.5, limit=(0.0, 3.0)),)

    @classmethod
    def exogenous(cls, f: Fields, t: Targets, v: Values, channels: Mapping[str, np.ndarray],
                  gain: np.ndarray, drive: np.ndarray | None = None) -> None:
        dc = _dcmotor(f, t)
        # (..., n_targets) [V] and the weight, on one shape
        w, vm = np.broadcast_arrays(np.asarray(v["weight"], float), channels["voltage"])
        if np.any(dc):
            a = t.actuators[dc]
            vnom = f.nominal("actuator_user")[a, servo.USER_SUPPLY_VOLTAGE]
            ratio = 1.0 + w[..., dc] * (vm[..., dc] - vnom) / vnom
            ratio = np.maximum(ratio, 0.05)
            gain[..., a, servo.GAIN_KP] *= ratio
            gain[..., a, servo.GAIN_KI] *= ratio
            gain[..., a, servo.GAIN_VMAX] *= ratio
            backemf = gain[..., a, servo.GAIN_K] ** 2 / gain[..., a, servo.GAIN_R]
            gain[..., a, servo.GAIN_KD] = backemf + (gain[..., a, servo.GAIN_KD] - backemf) * ratio
        rows = _drive_rows(t, dc, drive)
        if len(rows):
            vnom = servo.motor_spec(DEFAULT_SUPPLY_MOTOR).voltage
            if "supply" in channels:
                sup = np.broadcast_to(channels["supply"], vm.shape)[..., ~dc]
                vnom = np.where(sup > 0, sup, vnom)
            ratio = np.maximum(1.0 + w[..., ~dc] * (vm[..., ~dc] - vnom) / vnom, 0.05)
            drive[..., rows] = drive[..., rows] * ratio


def scale_resistance(gain: np.ndarray, a: np.ndarray, factor: np.ndarray) -> None:
    """R -> R * factor, keeping the firmware's voltage gains (kp, kd in torque space scale 1/R)."""
    k = gain[..., a, servo.GAIN_K]
    r = gain[..., a, servo.GAIN_R]
    backemf = k * k / r
    extra_kd = gain[..., a, servo.GAIN_KD] - backemf
    gain[..., a, servo.GAIN_R] = r * factor
    gain[..., a, servo.GAIN_KP] /= factor
    gain[..., a, servo.GAIN_KI] /= factor
    gain[..., a, servo.GAIN_KD] = backemf / factor + extra_kd / factor


def rescale(f: Fields, bound: Sequence, channels: Mapping[str, np.ndarray] | None,
            static_gain: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """One control step of the exogenous effects among ``bound`` (the plant's effects: ``cls``,
    ``targets``, ``values``) on the measured ``channels`` (..., nu): the rescaled copy of
    ``static_gain`` (..., nu, mjNGAIN) and the drive scale (..., nu) of the actuators ``rows``
    ((nu,) bool; None when there are none). Raises ConfigError when a required channel is
    missing."""
    exo = [b for b in bound if b.cls.kind == "exogenous"]
    missing = sorted({c for b in exo for c in b.cls.requires if not channels or c not in channels})
    if missing:
        raise ConfigError(f"step() needs measured channels {missing} for the applied effects")
    gain = np.array(static_gain, copy=True)
    drive = np.ones(gain.shape[:-1]) if np.any(rows) else None
    for b in exo:
        chans = {c: np.asarray(channels[c], float)[..., b.targets.actuators]
                 for c in b.cls.requires + b.cls.optional if c in channels}
        b.cls.exogenous(f, b.targets, b.values, chans, gain, drive)
    return gain, drive


class Readings:
    """The measured channels of a plant's last rescale (``rescale``), kept when nothing else
    rewrites the drives between steps: a step with the same readings finds the gains, bias and
    force ranges as that rescale left them (a replay holds each log row for several physics
    steps)."""

    def __init__(self) -> None:
        self.last: dict[str, np.ndarray] | None = None

    def same(self, channels: Mapping[str, np.ndarray] | None) -> bool:
        last = self.last
        return (last is not None and channels is not None and channels.keys() == last.keys()
                and all(np.array_equal(last[c], channels[c]) for c in last))

    def keep(self, channels: Mapping[str, np.ndarray] | None, held: bool) -> None:
        """Remember ``channels`` (copies) when ``held`` (nothing rewrites the drives)."""
        self.last = ({c: np.array(v, copy=True) for c, v in channels.items()}
                     if held and channels is not None else None)


def drive_targets(model: mujoco.MjModel, targets: list[np.ndarray]) -> np.ndarray:
    """(nu,) the actuators of ``targets`` (actuator ids of the exogenous effects) whose drive
    scale the plant applies: every one but the dcmotor servos. Raises ConfigError for a kind
    without a torque per command (gain or bias other than fixed / affine / none: a muscle)."""
    out = np.zeros(model.nu, dtype=bool)
    for a in targets:
        out[a] = True
    out &= model.actuator_gaintype != mujoco.mjtGain.mjGAIN_DCMOTOR
    ok = (np.isin(model.actuator_gaintype, (mujoco.mjtGain.mjGAIN_FIXED,
                                            mujoco.mjtGain.mjGAIN_AFFINE))
          & np.isin(model.actuator_biastype, (mujoco.mjtBias.mjBIAS_NONE,
                                              mujoco.mjtBias.mjBIAS_AFFINE)))
    if np.any(out & ~ok):
        bad = [model.actuator(int(i)).name or str(int(i)) for i in np.flatnonzero(out & ~ok)]
        raise ConfigError(
            f"thermal_derating / voltage_sag scale a drive's torque per command; actuators {bad} "
            "have a gain or bias type without one (they apply to dcmotor, motor, position, "
            "velocity and general actuators with fixed or affine gain and bias)")
    return out


def scale_drive(f: Fields, gain: np.ndarray, drive: np.ndarray, rows: np.ndarray,
                static_bias: np.ndarray, static_range: np.ndarray) -> np.ndarray:
    """Apply the drive scale s (..., nu) of the actuators ``rows`` ((nu,) bool): force =
    s (gain ctrl + bias), clipped at s x the force range. Writes gainprm[0:3] of ``gain`` (the
    plant's gain copy) in place and biasprm[0:3] from ``static_bias``; returns the scaled copy
    of ``static_range`` (..., nu, 2), the force range the plant puts in force."""
    s = drive[..., rows, None]
    gain[..., rows, 0:3] = gain[..., rows, 0:3] * s
    f.array("actuator_biasprm")[..., rows, 0:3] = static_bias[..., rows, 0:3] * s
    out = np.array(static_range, copy=True)
    out[..., rows, :] = out[..., rows, :] * s
    return out
