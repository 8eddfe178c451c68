"""The servo catalogue's torque-off (back-driven) friction laws against real torque-off logs.

``MotorSpec.backdriven`` holds a servo's Coulomb + viscous friction while its load back-drives
the gears with the torque off; identification sets it when no training log has the torque off
(``gap.identify_logs.backdriven_plan``). Truth: the real torque-off swings of the measured
lift_and_drop logs and the numbers the logs' authors published (BAM M1 fits). Skips cleanly
when the measured data folder is absent (LOWCOSTDEX_MEASURED_DATA overrides
../shared/data/measured next to the repository)."""

from __future__ import annotations

import numpy as np
import pytest
from real_logs import ROOT, lift_logs, swing_maes

MX = ROOT / "rhoban-bam-mx-atomic"
STS3032 = ROOT / "qua-robotics-bam-sts3032"


def test_the_catalogue_laws_are_the_published_m1_fits_or_none():
    from lowcostdex.sim import servo

    # qua-robotics/bam params/feetech_sts3032_6_0V/m1.json @4bd252b (the STS3032 logs' authors)
    assert servo.motor_spec("STS3032").backdriven == (0.0054, 0.00159)
    # nothing published for the STS3250 (Rhoban/bam, its pull request #1 and forks): none
    assert servo.motor_spec("STS3250").backdriven is None
    # Unchecked on real logs: the measured folder holds no torque-off log of an MX-64 (its one
    # MX fall, friction_1.json, model unrecorded, follows the MX-106's law: the test below) and
    # no log of an STS3215 at all (checked 2026-11-28, bench/RESULTS.md gap-real17)
    assert servo.motor_spec("MX-64(1.0)").backdriven == (0.0904, 0.0117)
    assert servo.motor_spec("STS3215").backdriven == (0.0524, 0.0591)


@pytest.mark.skipif(not STS3032.is_dir(), reason=f"measured data not found at {ROOT}")
def test_sts3032_torque_off_swings_want_the_published_m1_law():
    # The STS3032 catalogue law (the logs' authors' published M1: Coulomb 0.0054 N m + viscous
    # 0.00159 N m s/rad) on the 18 real torque-off swings (9 mass x length set-ups, kp 8 and 32;
    # a pendulum written out, gap.torque_off.simulate) at the authors' M1 armature 0.00101 kg
    # m^2. Measured 2026-11-28 (bench/RESULTS.md gap-real16): mean 127.9 mrad; no friction
    # 599.8; the Coulomb + viscous the STS3032 kp 32 -> 8 identification fits with the torque
    # off (0.0019 + 0.0003) 388.0; the XL330's law 292.7; the swings' own best Coulomb + viscous
    # (swing_fit: 0.00528 + 0.00167, armature 0.00106) 126.4.
    from lowcostdex.gap.torque_off import swings
    from lowcostdex.sim import servo

    ds, lift = lift_logs(STS3032)
    sws = swings(ds, lift)
    assert len(sws) == 18
    c, b = servo.motor_spec("STS3032").backdriven

    def mae(p):
        return swing_maes(sws, p)

    law, none, weak = mae([0.00101, c, b]), mae([0.00101, 0.0, 0.0]), mae(
        [0.00101, 0.0019, 0.0003])
    assert np.all(law < 0.6 * none) and np.mean(law) < 0.25 * np.mean(none)
    assert np.all(law < weak) and np.mean(law) < 0.4 * np.mean(weak)


@pytest.mark.skipif(not STS3032.is_dir(), reason=f"measured data not found at {ROOT}")
def test_an_sts3032_fold_without_torque_off_logs_gets_the_catalogue_law():
    from lowcostdex.gap.identify import servo_structure
    from lowcostdex.gap.identify_logs import BACKDRIVEN, BACKDRIVEN_PARAMS, backdriven_plan

    ds, lift = lift_logs(STS3032)
    rest = [i for i in range(len(ds.trajectories)) if i not in lift]
    effects = servo_structure(ds)
    assert BACKDRIVEN in effects
    # its loads (0.13-0.45 N m of gravity) back-drive the gears past the law's 0.0054 N m; the
    # law is the back-driven joint's whole friction (the gear friction's level and the joint's
    # own torque-on Coulomb and damping not kept with the torque off: ``gear``, ``joint`` 0)
    assert backdriven_plan(ds, rest, effects, "fit") == (
        BACKDRIVEN_PARAMS, {"coulomb": 0.0054, "viscous": 0.00159, "gear": 0.0, "joint": 0.0})
    # torque-off swings in training: Coulomb and viscous fitted, as before
    assert backdriven_plan(ds, lift + rest, effects, "fit") == (
        frozenset({(BACKDRIVEN, "gear"), (BACKDRIVEN, "joint")}), None)


@pytest.mark.skipif(not STS3032.is_dir(), reason=f"measured data not found at {ROOT}")
def test_sts3032_real_swings_reject_the_torque_on_joint_damping():
    # STS3032's lift_and_drop fold (no torque-off log in training, 2026-11-28) fits a joint
    # damping of 0.00997 N m s/rad on the torque-on logs (what the firmware's D term and the
    # drive add with the current on); kept with the torque off on top of the catalogue law it
    # left the replayed arm swinging out in one or two periods: held out 188.8 mrad, 46.9 with
    # the law as the joint's whole back-driven friction (``backdriven_friction.joint`` 0; BAM's
    # M1 34.3, in-sample). The 18 real torque-off swings (gap.torque_off's pendulum, armature
    # 0.00101) say the same without any fit: the law alone 127.9 mrad mean, the law + 0.00997
    # 309.7, worse on every swing. (The pendulum has no mounting offset: the real swings centre
    # 0.08-0.17 rad off the model's hanging zero, most of the law's 127.9.)
    from lowcostdex.gap.torque_off import swings
    from lowcostdex.sim import servo

    ds, lift = lift_logs(STS3032)
    sws = swings(ds, lift)
    c, b = servo.motor_spec("STS3032").backdriven
    law, kept = swing_maes(sws, [0.00101, c, b]), swing_maes(sws, [0.00101, c, b + 0.00997])
    assert np.all(law < 0.8 * kept) and np.mean(law) < 0.5 * np.mean(kept)


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


@pytest.mark.slow  # one STS3032 identification (about 5 min of CPU)
@pytest.mark.skipif(not STS3032.is_dir(), reason=f"measured data not found at {ROOT}")
def test_sts3032_lift_and_drop_fold_with_the_law_as_the_joints_whole_back_driven_friction():
    # lift_and_drop held out (18 logs; 54 torque-on logs fitted): measured 2026-11-28 0.0469 rad
    # (torque-on part 8.7 mrad, torque-off 66.1), 0.1888 with the torque-on fit's joint damping
    # (0.00997 N m s/rad) kept with the torque off, 0.2042 without the law. A LOSS to BAM: its
    # authors' M1 0.0343 on the same logs (in-sample), reference 08's refit M4 0.039 (kp 8)
    from lowcostdex.gap.identify import IdentifyConfig, identify, servo_structure

    ds, lift = lift_logs(STS3032)
    train = [i for i in range(len(ds.trajectories)) if i not in lift]
    res = identify(ds, train, lift, IdentifyConfig(effects=servo_structure(ds), nthread=1))
    assert res.mean(lift) < 0.06, (res.mean(lift), res.params())
    assert res.params()["backdriven_friction"]["joint"] == [0.0]


def _extrema_centre(q: np.ndarray) -> float:
    """The angle a decaying swing turns about, read off its own extrema [rad]: for each three
    successive turning points x0, x1, x2 (a decay by a constant ratio r: x1 - c = -r (x0 - c),
    x2 - c = r^2 (x0 - c)), c = (x0 x2 - x1^2) / (x0 + x2 - 2 x1); the median over the swing's
    turns more than 0.1 rad from the next."""
    d = np.diff(q)
    turns = [q[k] for k in np.flatnonzero(np.sign(d[1:]) != np.sign(d[:-1])) + 1]
    ext: list[float] = []
    for x in turns:
        if not ext or abs(x - ext[-1]) > 0.02:
            ext.append(x)
    cs = [(x0 * x2 - x1 ** 2) / (x0 + x2 - 2 * x1)
          for x0, x1, x2 in zip(ext, ext[1:], ext[2:], strict=False) if abs(x1 - x0) > 0.2]
    return float(np.median(cs))


@pytest.mark.skipif(not STS3032.is_dir(), reason=f"measured data not found at {ROOT}")
def test_sts3032_swings_hang_at_each_arms_own_angle_and_the_fit_reads_it():
    from lowcostdex.gap.torque_off import swing_fit, swings

    # the 0.259 kg load at kp 32 on the three arms (0.05, 0.07, 0.1 m): each arm re-mounted
    # between recordings hangs at its own encoder angle (bench/RESULTS.md lead24, gap-real20)
    ds, lift = lift_logs(STS3032)
    logs = [i for i in lift if ds.trajectories[i].meta["mass"] == 0.259
            and ds.trajectories[i].meta["kp"] == 32]
    arms = [ds.trajectories[i].meta["length"] for i in logs]
    assert sorted(arms) == [0.05, 0.07, 0.1]
    fit = swing_fit(ds, logs, centre=True)
    own = [_extrema_centre(s.q) for s in swings(ds, logs)]
    # each swing's fitted centre is the one its own turning points say (within 10 mrad)
    assert np.allclose(fit.centres, own, atol=0.01), (fit.centres, own)
    c = dict(zip(arms, fit.centres, strict=True))
    assert c[0.07] > max(c[0.05], c[0.1]) + 0.025  # measured 0.154 vs 0.105, 0.123
    # with its centre the written-out pendulum explains each swing (without: 97-166 mrad)
    assert max(fit.mae) < 0.03
    # and its armature is BAM's fitted STS3032 M1 armature (0.00103 kg m^2, reference 08
    # section 4, fitted by BAM on these benches' kp 32 logs) within 10 %
    assert fit.armature == pytest.approx(0.00103, rel=0.1)
