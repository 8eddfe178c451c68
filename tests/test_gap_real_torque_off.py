"""The servo catalogue's torque-off (back-driven) friction laws against real torque-off logs.

``MotorSpec.backdriven`` holds a servo's Coulomb + viscous friction while its load back-drives
the gears with the torque off; identification sets it when no training log has the torque off
(``gap.identify_logs.backdriven_plan``). Truth: the real torque-off swings of the measured
lift_and_drop logs and the numbers the logs' authors published (BAM M1 fits). Skips cleanly
when the measured data folder is absent (LOWCOSTDEX_MEASURED_DATA overrides
../shared/data/measured next to the repository)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(os.environ.get("LOWCOSTDEX_MEASURED_DATA") or os.environ.get("LOWCOSTDEX_MEASURED")
            or Path(__file__).resolve().parents[2] / "shared" / "data" / "measured")
MX = ROOT / "rhoban-bam-mx-atomic"


def _fall(pos, t, mass, length, armature, coulomb, viscous):
    """A released arm (point mass ``mass`` at ``length``, theta 0 horizontal, -pi/2 hanging) under
    a gear train's Coulomb + viscous friction, integrated at 0.1 ms from the first sample that has
    started to fall; positions at the log's times from there."""
    g, h, vs = 9.81, 1e-4, 1e-3
    k0 = int(np.argmax(pos < -0.01)) - 2
    inertia = mass * length ** 2 + armature
    q, v, tt, out = pos[k0], 0.0, t[k0], []
    for tk in t[k0:]:
        while tt < tk:
            tg = -mass * g * length * np.cos(q)
            if abs(v) < vs and abs(tg) <= coulomb:
                v = 0.0  # stuck: the gears hold the load
            else:
                s = np.sign(v) if abs(v) >= vs else np.sign(tg)
                v += h * (tg - coulomb * s - viscous * v) / inertia
            q += h * v
            tt += h
        out.append(q)
    return np.asarray(out), pos[k0:]


@pytest.mark.skipif(not (MX / "friction_1.json").is_file(), reason=f"measured data not found at {ROOT}")
def test_an_mx_arm_falling_with_the_torque_off_follows_the_mx106_catalogue_law():
    # Rhoban/bam data/friction_1.json: an MX-series servo (model not recorded) let go with the
    # torque off, 0.335 kg at 0.105 m: it falls from horizontal in about 1.3 s and stays at
    # -1.833 rad, 15 deg past hanging. BAM's published MX-106 M1 (Rhoban/bam@1b5a1ce
    # params/mx106/m1.json: armature 0.0266, Coulomb 0.1035, viscous 0.0352), the MX-106's
    # catalogue law: measured 2026-11-28 MAE 22 mrad, rest -1.858; MX-64's M1 law (0.0904 +
    # 0.0117, armature 0.0120) 284 mrad, rest -1.589 (the unknown servo is likely an MX-106);
    # no friction 991 mrad.
    import json

    from lowcostdex.sim import servo

    d = json.loads((MX / "friction_1.json").read_text())
    pos, t = np.asarray(d["positions"]), np.asarray(d["timestamps"])
    c, b = servo.motor_spec("MX-106(1.0)").backdriven
    q, meas = _fall(pos, t, d["m"], d["l"], 0.0266, c, b)
    assert np.mean(np.abs(q - meas)) < 0.04 and abs(q[-1] - meas[-1]) < 0.05
    q0, _ = _fall(pos, t, d["m"], d["l"], 0.0266, 0.0, 0.0)
    assert np.mean(np.abs(q0 - meas)) > 10 * np.mean(np.abs(q - meas))
