"""The gap analysis judged on a THIRD independently written truth simulator (issue 11 item 4).

``tests/gap_truth_sim3.py`` (mujoco + numpy only, written without reading the analyzer, its
effect catalogue, plant, servo or the two earlier truth simulators): a D'Claw-like 3-joint finger
on plain ``position`` actuators with an effect on one joint (or a pair on two), and a one-joint
servo whose truth is a ``motor`` driven by its own 1 kHz integer-tick P-D firmware.

The fast tests check the truth physics itself against physics written out here (the play band,
the latency's time shift, frictions that only dissipate and hold below their breakaway, the
torque-speed line, the gain's steady-state sag, offsets, the firmware against the user's
position model) and the log format and scorer. The slow tests run every case through ``gap
analyze`` as a user would (``bench/gap_redteam3.py`` prints the table); a case the analysis
misses today is a strict xfail whose reason is the MEASURED result (bench/RESULTS.md), so a fix
turns it into XPASS and the mark must go. Unmeasured cases carry no mark.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import pathlib
import sys

import mujoco
import numpy as np
import pytest

from lowcostdex.cli import main

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import gap_truth_sim3 as sim  # noqa: E402

# srv_dirfric_50hz was a miss (position_offset -0.0167 alone, held-out 39.2 -> 31.1 mrad on main
# 9b54389); with coulomb_friction's asymmetry freed when the data need it (gap-fric2, session 9,
# lowcostdex.gap.gates): coulomb_friction 0.1052 [0.0939, 0.1164] asymmetry 0.490 [0.394, 0.587]
# (truth 0.15 / 0.05 N m: 0.1, 0.5) alone, held-out 39.2 -> 4.70 mrad, 107 s CPU.
# srv_stribeck was 'interval' (static 0.0497 [0.0242, 0.0751] and velocity 0.697 for 0.12 / 0.05,
# ecf1ae1); re-run on main c5443ac (gap-fric2, bench/gap_redteam3.py --threads 1, 60 s wall):
# stribeck_friction coulomb 0.0852 [0.0691, 0.1013], static 0.1054 [0.0576, 0.1533], velocity
# 0.0447 [0.0392, 0.0509] (truth 0.08 / 0.12 / 0.05) alone, held-out 28.7 -> 1.77 mrad.
# measured by bench/gap_redteam3.py (2026-11-26, see bench/RESULTS.md): what was named instead.
# fin_mount_offset020_prox was a miss (position_offset on prox and dist: at the model's 2 ms step
# the mounting offset fits worse); since the first cause is chosen again at the refined step
# (gap-offset, session 8): mounting_offset prox 0.1986 [0.191, 0.206] alone, held-out 2.69 ->
# 0.79 mrad (was 1.12 with the position offset).
# srv_gain25_posonly was 'extra' (gain 2.594 [2.573, 2.616] for 2.5 plus mass_error 1.045: the
# truth's 1 kHz firmware replayed as a continuous position law); with the servo update period
# tried on the first cause (gap-servo5, session 12, stepsize.refine_fitted): gain_error 2.538
# [2.416, 2.667] alone at 0.5 ms with a 1 ms period, held-out 49.9 -> 0.95 mrad, 39 s CPU.
# srv_backlash_output was 'interval' (width 0.0332 [0.0281, 0.0382] at 3483c63, 0.0382 [0.0358,
# 0.0406] on ebac3a1, truth 0.05: its cost is jagged in the width, the loop on the output shaft
# hunting in the play, and the fit stopped in the dip nearest its search path's start); with
# the width scanned over its range (gap.width_scan, gap-play6, session 13): exact, width
# 0.04895 [0.04531, 0.05594], held-out 11.53 -> 4.57 mrad, 280 s CPU.
MISSES: dict[str, str] = {
    "fin_pair_latency080_abd_backlash050_prox": "miss (gap-play, main 3483c63, 379 s): latency "
                                                "80.22 ms on abd alone, its interval [79.74, "
                                                "80.70] now holds 80 (was [80.42, 80.65]); "
                                                "the 0.05 rad play on prox not sought: the "
                                                "model with latency is within explain_above "
                                                "(1.26 mrad train + select at 1 ms = 1.8 "
                                                "floors; prox held-out 1.47 mrad = 2.2 of its "
                                                "0.66 floor); held-out 49.1 -> 1.05 mrad. Not "
                                                "the gate alone (gap-sim3-11, session 16): the "
                                                "catalogue's backlash reads the link, the "
                                                "finger's encoder the rotor; with the latency "
                                                "at 80 ms every prox width replays worse than "
                                                "none (2.20 floors at 2 ms; 0.01 rad: 4.02, "
                                                "0.05: 18.4). gap-rotor12 (session 17): "
                                                "read on the motor side (backlash.read 0) "
                                                "the true play replays closer than none "
                                                "(1.254 vs 1.496 mrad at 2 ms, 0.685 vs "
                                                "1.211 at 0.5 ms); not re-run through the "
                                                "analysis (explain_above stops it before a "
                                                "second cause). The same on acf2f02 (gap-sweep22, "
                                                "session 27, play_step on, 98 s CPU): "
                                                "latency abd 80.28 ms [78.53, 81.03], "
                                                "held-out 49.1 -> 1.06 mrad",
    "fin_backlash080_dist": "miss by design, not below the read floor (gap-play, main 3483c63, "
                            "68 s): 'no significant discrepancy', the nominal train + select "
                            "RMSE 0.83 mrad at 0.5 ms is within explain_above (3 floors of "
                            "0.68). Against the clean truth replay (gap_truth_sim3.effect_size) "
                            "the play adds 0.18-0.39 mrad RMS on dist but 0.56-0.97 mrad on "
                            "prox (0.8-1.4 floors, max 6 ticks) in quadrature over the 3 logs: "
                            "a systematic signal 3600 rows could resolve; held-out 0.83 mrad. "
                            "No gate on the nominal residual can seek it safely and no "
                            "catalogue width fits it (gap-sim3-11, session 16): srv_clean's "
                            "firmware misfit is larger and smoother (RMS 1.16 vs 0.82 mrad "
                            "above the floor), and every dist width replays worse than none "
                            "(1.22 floors; 0.002 rad: 1.46, 0.08: 19.7): the catalogue's "
                            "play is read on the link, this encoder on the rotor. gap-rotor12 "
                            "(session 17): backlash.read 0 (the motor side) replays the true "
                            "play at the floor (0.683 vs 0.827 mrad, whole logs at 0.5 ms) "
                            "and the analysis fits that side; still 'no significant "
                            "discrepancy' (the gate, 33 s CPU); with explain_above 1 "
                            "(367 s CPU) backlash ranks first, read on the motor side, "
                            "select MSE 27 % lower (paired low 6.7 %), but width 0.0366 on "
                            "dist (0.0079 prox) and its effect 0.42 mrad RMS, below the "
                            "0.68 floor: not accepted. The same on acf2f02 (gap-sweep22, "
                            "session 27, play_step on: 'within 3 noise floors' at 0.5 ms, "
                            "held-out 0.83 mrad, 21 s CPU)",
    "fin_stribeck_prox": "interval (re-run by gap-fric4, session 11, main 69aace3, 1069 s "
                         "CPU): named exactly stribeck_friction[prox] (abd and dist listed "
                         "idle), analysed at 0.5 ms; its velocity no longer at the 0.01 "
                         "bound (was 0.010) but 0.118 [0.081, 0.174] for 0.05 and static "
                         "0.037 [0.022, 0.052] for 0.07 (breakaway 0.12 - Coulomb 0.05): a "
                         "lower, wider breakaway; Coulomb 0.054 [0.012, 0.097] holds 0.05; "
                         "held-out 10.41 -> 2.58 mrad (was 10.8 -> 2.18)",
}


def _steps(goals_at, t_end, rate=100.0):
    t = np.arange(0.0, t_end, 1.0 / rate)
    return t, np.array([goals_at(x) for x in t])


def _case(rig, *effects, **kw):
    return sim.Case("t", rig, tuple(effects), **kw)


# ------------------------------------------------------------ truth physics


def test_backlash_output_stays_in_the_play_band_and_crosses_it():
    """The link (output) moves relative to the rotor only inside the play, and a trajectory
    with reversals drives it to both ends of the band (15 % allowed for the stiff contact)."""
    for case, j in ((_case("servo", sim.Effect("backlash", ("q",), 0.06)), 0),
                    (_case("finger", sim.Effect("backlash", ("prox",), 0.08)), 1)):
        nj = len(case.joints)
        t, g = _steps(lambda x, nj=nj: np.full(nj, 0.5 * np.sin(2 * np.pi * 0.8 * x)), 3.0)
        tr = sim.simulate(case, g, t)
        rel = tr["q_link"][:, j] - tr["q_motor"][:, j]
        h = case.effects[0].value / 2
        assert np.all(np.abs(rel) <= 1.15 * h), (rel.min(), rel.max(), h)
        assert rel.max() > 0.9 * h and rel.min() < -0.9 * h, (rel.min(), rel.max(), h)
        clean = sim.simulate(_case(case.rig), g, t)
        assert np.all(np.abs(clean["q_link"] - clean["q_motor"]) == 0)


@pytest.mark.parametrize("rig", ["finger", "servo"])
def test_latency_shifts_the_response_by_the_set_time(rig):
    """A goal that arrives d late gives the same response d later (a time-invariant plant,
    started at rest on its first goal); d = 40 ms is a whole number of firmware cycles."""
    d = 0.040
    joints = ("abd", "prox", "dist") if rig == "finger" else ("q",)
    t, g = _steps(lambda x: np.full(len(joints), 0.0 if x < 0.3 else 0.4), 1.0)
    base = sim.simulate(_case(rig), g, t)
    late = sim.simulate(_case(rig, sim.Effect("latency", joints, d)), g, t)
    k = int(round(d / sim.TRUTH_DT))
    moved = np.abs(base["q"][:-k] - base["q"][0]).max()
    assert moved > 0.3
    tol = 1e-6 if rig == "finger" else 2 * sim.TICK   # the firmware's integer chatter
    assert np.abs(late["q"][k:] - base["q"][:-k]).max() < tol
    # and not the same response unshifted
    assert np.abs(late["q"] - base["q"]).max() > 0.1


def _servo_free(effect, q0, v0, applied=0.0, seconds=1.5):
    """Servo bench truth model with the firmware off (torque 0) and gravity off, a constant
    external torque ``applied``: returns (t, q, v, energy)."""
    case = _case("servo", effect)
    model = mujoco.MjModel.from_xml_string(sim.servo_xml(case, truth=True))
    model.opt.gravity[:] = 0
    model.dof_damping[:] = 0
    data = mujoco.MjData(model)
    data.qpos[0], data.qvel[0] = q0, v0
    inertia = model.dof_armature[0] + model.body_mass[1] * sim.SERVO_ARM[1] ** 2 + model.body_inertia[1][0]
    out = []
    for _ in range(int(seconds / sim.TRUTH_DT)):
        data.qfrc_applied[0] = applied
        push = data.qfrc_actuator[0] + data.qfrc_passive[0] - data.qfrc_bias[0] + applied
        model.dof_frictionloss[0] = sim._friction_level(effect, data.qvel[0], push)
        mujoco.mj_step(model, data)
        out.append((data.time, data.qpos[0], data.qvel[0], 0.5 * inertia * data.qvel[0] ** 2))
    return np.array(out)


def test_stribeck_breaks_away_above_coulomb_and_only_dissipates():
    """Stribeck (Coulomb 0.08, breakaway 0.2 N m): 0.15 N m from rest does not move it, the same
    torque keeps it sliding once it moves (0.15 > Coulomb), and unforced it only loses energy
    at the Coulomb rate (dE/dt ~ -Fc |v| at speed)."""
    e = sim.Effect("stribeck", ("q",), 0.08, (0.20, 0.05))
    rest = _servo_free(e, 0.0, 0.0, applied=0.15)
    assert np.abs(rest[:, 1]).max() < 1e-3
    slide = _servo_free(e, 0.0, 1.0, applied=0.15)
    assert slide[-1, 2] > 1.0 and slide[-1, 1] > 1.0      # accelerates: 0.15 - 0.08 > 0
    free = _servo_free(e, 0.0, 3.0)
    energy = free[:, 3]
    assert np.all(np.diff(energy) <= 1e-9)
    assert free[-1, 2] == pytest.approx(0.0, abs=1e-3)
    fast = free[:, 2] > 1.0                                 # far above the Stribeck speed
    p = -np.diff(energy)[fast[1:]] / sim.TRUTH_DT / free[1:, 2][fast[1:]]
    assert np.median(p) == pytest.approx(0.08, rel=0.05)


def test_direction_dependent_friction_and_friction_near_stall():
    """dirfric (0.15 N m for positive motion, 0.05 negative): +-0.1 N m from rest moves it only
    backwards. Coulomb 1.2 N m (80 % of stall): 1.1 N m from rest does not move it."""
    e = sim.Effect("dirfric", ("q",), 0.15, (0.05,))
    assert np.abs(_servo_free(e, 0.0, 0.0, applied=0.1)[:, 1]).max() < 1e-3
    assert _servo_free(e, 0.0, 0.0, applied=-0.1)[-1, 1] < -0.5
    stall = sim.Effect("coulomb", ("q",), 1.2)
    assert np.abs(_servo_free(stall, 0.0, 0.0, applied=1.1)[:, 1]).max() < 1e-3
    assert _servo_free(stall, 0.0, 0.0, applied=1.3)[-1, 1] > 0.5
    # and the firmware can still move it: a 1 rad step (P saturates at the 1.5 N m stall)
    case = _case("servo", stall)
    t, g = _steps(lambda x: np.array([0.0 if x < 0.2 else 1.0]), 2.0)
    tr = sim.simulate(case, g, t)
    assert 0.4 < tr["q"][-1, 0] < 1.0      # stops short: 3 N m/rad x error = 1.2 N m - gravity


def test_velocity_limit_caps_the_speed_that_the_nominal_servo_exceeds():
    t, g = _steps(lambda x: np.array([0.0 if x < 0.2 else (1.0 if x < 1.2 else -1.0)]), 2.2)
    fast = sim.simulate(_case("servo"), g, t)
    slow = sim.simulate(_case("servo", sim.Effect("vlimit", ("q",), 1.5)), g, t)
    assert np.abs(fast["v"]).max() > 4.0
    assert np.abs(slow["v"]).max() < 1.5 * 1.05
    assert np.abs(slow["v"]).max() > 1.5 * 0.8


def test_gain_error_scales_the_stiffness_seen_in_the_gravity_sag():
    """At the end of a hold, kp_true (goal - q) balances gravity (MuJoCo's bias force, plain
    mujoco on the nominal model): kp_true = 0.35 x 3 N m/rad on abd only."""
    case = _case("finger", sim.Effect("gain", ("abd",), 0.35))
    goal = np.array([0.3, 0.9, 0.7])
    t, g = _steps(lambda x: goal, 2.0)
    tr = sim.simulate(case, g, t)
    q = tr["q"][-1]
    model = mujoco.MjModel.from_xml_string(sim.finger_xml())
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    kp = data.qfrc_bias / (goal - q)
    assert kp == pytest.approx([0.35 * 3.0, 3.0, 3.0], rel=0.02)


def test_mass_and_armature_errors_change_only_their_link_and_joint():
    nominal = mujoco.MjModel.from_xml_string(sim.finger_xml())
    case = _case("finger", sim.Effect("mass", ("dist",), 2.5), sim.Effect("armature", ("prox",), 0.4))
    truth = mujoco.MjModel.from_xml_string(sim.finger_xml(case, truth=True))
    ratio_m = truth.body_mass[2:] / nominal.body_mass[2:]
    assert ratio_m == pytest.approx([1.0, 1.0, 2.5])
    assert truth.body_inertia[4] / nominal.body_inertia[4] == pytest.approx([2.5] * 3, rel=1e-3)
    assert truth.dof_armature / nominal.dof_armature == pytest.approx([1.0, 0.4, 1.0])


def test_offsets_reading_and_mounting():
    """Reading offset: the log reads q + 0.15, the servo holds q at the goal. Mounting offset:
    the servo reads q + 0.2 and holds that reading at the goal (the true angle is 0.2 lower)."""
    rng = np.random.default_rng(0)
    read = _case("finger", sim.Effect("offset_read", ("prox",), 0.15), noise=0.0)
    run = sim.make_run(read, 3.0, 0, rng)
    i = np.round(run.t / sim.TRUTH_DT).astype(int)
    assert np.abs(run.qpos[:, 1] - run.extra["q"][i, 1] - 0.15).max() <= sim.TICK
    assert np.abs(run.qpos[:, 0] - run.extra["q"][i, 0]).max() <= sim.TICK
    mount = _case("servo", sim.Effect("offset_mount", ("q",), 0.2))
    t, g = _steps(lambda x: np.array([0.5]), 1.5)
    tr = sim.simulate(mount, g, t)
    sag = 0.15 * 9.81 * 0.06 * np.sin(0.3) / sim.SERVO_KP        # gravity at the true angle
    assert tr["q"][-1, 0] == pytest.approx(0.5 - 0.2 - sag, abs=3 * sim.TICK)


def test_clean_truth_matches_the_users_model_in_plain_mujoco():
    """Without effects the truth (0.25 ms; the servo's 1 kHz integer firmware) and the user's
    nominal model (here replayed at 0.25 ms with plain mujoco) agree within a few mrad: the
    clean controls are clean, and the user's model is a fair nominal."""
    for rig, tol in (("finger", 1e-4), ("servo", 6e-3)):
        case = _case(rig)
        n = len(case.joints)
        t, g = _steps(lambda x, n=n: np.full(n, 0.0 if x < 0.3 else 0.6 * np.sin(3 * x)), 2.0)
        tr = sim.simulate(case, g, t)
        xml = sim.finger_xml() if rig == "finger" else sim.servo_xml()
        model = mujoco.MjModel.from_xml_string(xml)
        model.opt.timestep = sim.TRUTH_DT
        data = mujoco.MjData(model)
        data.qpos[:] = g[0]
        for _ in range(int(1.0 / sim.TRUTH_DT)):
            data.ctrl[:] = g[0]
            mujoco.mj_step(model, data)
        q = []
        for k in range(len(tr["t"])):
            tt = tr["t"][k]
            data.ctrl[:] = g[max(np.searchsorted(t + sim.BUS_DELAY, tt, side="right") - 1, 0)]
            mujoco.mj_step(model, data)
            q.append(data.qpos.copy())
        err = np.abs(np.array(q) - tr["q"]).max()
        assert err < tol, (rig, err)
        assert np.abs(tr["q"] - tr["q"][0]).max() > 0.3


def test_clean_controls_sit_at_the_floor_and_effects_stand_out():
    """The logged clean cases, against the user's model replayed in plain mujoco: the finger at
    the read-noise + tick floor (sqrt(0.5^2 + 1.53^2 / 12) = 0.67 mrad); the servo bench adds its
    firmware's 1 kHz integer discretisation (measured 1.7 mrad RMS); a 0.1 rad reading offset
    on one joint stands out there and only there."""
    fin = sim.effect_size(sim.CASE_BY_NAME["fin_clean_jitter_posonly"])
    assert max(fin["rms"]) < 0.0009
    srv = sim.effect_size(sim.CASE_BY_NAME["srv_clean"])
    assert srv["rms"][0] < 0.0025
    off = sim.effect_size(sim.CASE_BY_NAME["fin_offset_read010_dist"])
    assert off["rms"][2] == pytest.approx(0.1, abs=0.002) and max(off["rms"][:2]) < 0.0009


def _user_servo_replay(run, scale: float, period: float = 0.0) -> np.ndarray:
    """The user's servo model (``position`` kp, kv, forcerange; plain mujoco at the truth's
    0.25 ms) with kp scaled by ``scale``, driven by ``run``'s goals as the log says, from rest
    on the first goal; ``period`` > 0 samples its P-D law kp (g - q) - kv q' every ``period``
    seconds and holds the (clipped) torque in between, as a servo's firmware does, instead of
    MuJoCo's continuous actuator. Its angle at the row times."""
    model = mujoco.MjModel.from_xml_string(sim.servo_xml())
    dt = model.opt.timestep = sim.TRUTH_DT
    kp = sim.SERVO_KP * scale
    if period:   # the same law, written out here and held: a torque actuator
        model.actuator_gainprm[0, 0], model.actuator_biasprm[0, :3] = 1.0, 0.0
        model.actuator_ctrlrange[0] = [-sim.SERVO_TMAX, sim.SERVO_TMAX]
        model.actuator_ctrllimited[0] = 1
    else:
        model.actuator_gainprm[0, 0], model.actuator_biasprm[0, 1] = kp, -kp
    data = mujoco.MjData(model)
    data.qpos[:] = run.goals[0]
    n0 = int(round(1.0 / dt))
    steps = (np.arange(n0 + int(np.ceil((run.t[-1] + 0.05) / dt))) - n0) * dt
    idx = np.maximum(np.searchsorted(run.t + sim.BUS_DELAY, steps, side="right") - 1, 0)
    every = int(round(period / dt)) if period else 1
    out = np.empty(len(steps))
    for i in range(len(steps)):
        goal = run.goals[idx[i], 0]
        if not period:
            data.ctrl[0] = goal
        elif i % every == 0:
            data.ctrl[0] = np.clip(kp * (goal - data.qpos[0]) - sim.SERVO_KV * data.qvel[0],
                                   -sim.SERVO_TMAX, sim.SERVO_TMAX)
        mujoco.mj_step(model, data)
        out[i] = data.qpos[0]
    return out[np.minimum(n0 + np.round(run.t / dt).astype(int), len(out) - 1)]


def test_a_gain_error_under_the_servos_1khz_firmware_needs_its_update_period():
    """srv_gain25_posonly's 'extra' traced (gap-fric4, session 11): the analysis fits gain
    2.594 [2.573, 2.616] for the truth's 2.5 because a continuous ``position`` actuator is not
    the firmware's law held for 1 ms. Against the case's first log (12 s of steps and ramps),
    the user's model in plain mujoco: continuous, the RMSE still falls from gain 2.5 to 2.6
    (measured 5.67 -> 3.30 mrad; its best over 3 logs is 2.62, 2.72 mrad); the same P-D law in
    floats (no integer ticks) sampled and held every 1 ms fits best at 2.5 (0.93 mrad, 2.45 and
    2.55 each > 1.9 mrad; over 3 logs 2.498, 0.86 mrad: near the 0.67 mrad read floor). So the
    bias is the servo's update period, not its integer arithmetic; a model of it must hold the
    servo's force between firmware cycles (the project's dcmotor servo, ``sim.servo``, and the
    replay run the P law continuously at every physics step)."""
    case = sim.CASE_BY_NAME["srv_gain25_posonly"]
    run = sim.make_run(case, case.durations[0], 0, np.random.default_rng(case.seed))

    def rmse(scale, period=0.0):
        return float(np.sqrt(np.mean((run.qpos[:, 0] - _user_servo_replay(run, scale, period)) ** 2)))

    cont = {s: rmse(s) for s in (2.5, 2.6)}
    held = {s: rmse(s, 0.001) for s in (2.45, 2.5, 2.55)}
    assert cont[2.6] < 0.75 * cont[2.5], cont
    assert held[2.5] < 0.6 * min(held[2.45], held[2.55]), held
    assert held[2.5] < 0.4 * cont[2.6] and held[2.5] < 0.0015, (held, cont)


def test_a_rotor_side_play_on_dist_is_not_below_the_read_floor():
    """fin_backlash080_dist (a strict xfail: the analysis says "no significant discrepancy")
    was called unidentifiable, below the read floor. Against its clean twin (same seed, same
    noise and ticks) replayed in plain mujoco, the 0.08 rad play moves the prox reading by more
    than one read floor (0.67 mrad) in quadrature, peaks several ticks out, and shows on dist:
    the miss is the analysis' explain_above threshold (3 floors), not the data (gap-play,
    session 8: prox 1.21 vs 0.64 mrad RMS, max 9.3 vs 2.1 mrad)."""
    case = sim.CASE_BY_NAME["fin_backlash080_dist"]
    play, clean = sim.effect_size(case), sim.effect_size(dataclasses.replace(case, effects=()))
    floor = 0.00067
    assert np.sqrt(play["rms"][1] ** 2 - clean["rms"][1] ** 2) > floor
    assert play["max"][1] > 3 * clean["max"][1]
    assert play["rms"][2] > clean["rms"][2]
    assert abs(play["rms"][0] - clean["rms"][0]) < 0.3 * floor


def _nominal_residuals(case) -> list[np.ndarray]:
    """Every log of ``case`` minus the user's nominal model replayed in plain mujoco at the
    truth's step (``sim.nominal_replay``): (rows, joints) per log, rad."""
    out = []
    for k, d in enumerate(case.durations):
        run = sim.make_run(case, d, k, np.random.default_rng(case.seed + k))
        out.append(run.qpos - sim.nominal_replay(case, run))
    return out


def test_a_clean_servos_misfit_is_larger_and_smoother_than_the_dist_plays_signal():
    """Why no gate on the nominal residual alone can name fin_backlash080_dist's play (gap-sim3-11,
    session 16; the brief asked for a whiteness / systematic-residual gate in place of
    explain_above). Against the user's model replayed in plain mujoco, the play's systematic
    part on prox (RMS above the read floor sqrt(0.5^2 + 1.53^2 / 12) = 0.67 mrad, in
    quadrature; and the same of a 9-sample moving mean, whose white-noise level is floor / 3)
    is SMALLER than that of srv_clean, where nothing is hidden and the misfit is the servo
    firmware's 1 kHz integer loop (measured: RMS 1.16 vs 0.82 mrad above the floor, moving mean
    0.80 vs 0.34 mrad). Any statistic of size or smoothness (autocorrelation, low-pass energy,
    per-log consistency: both are in every log) that flags the play flags the clean servo, where
    the analysis named a 1.25 % gain_error before explain_above existed."""
    floor = float(np.hypot(0.0005, sim.TICK / np.sqrt(12)))

    def excess(name, j):
        rs = [r[:, j] for r in _nominal_residuals(sim.CASE_BY_NAME[name])]
        r = np.concatenate(rs)
        lp = np.concatenate([np.convolve(x, np.ones(9) / 9, mode="valid") for x in rs])
        return (np.sqrt(max(np.mean(r * r) - floor ** 2, 0.0)),
                np.sqrt(max(np.mean(lp * lp) - floor ** 2 / 9, 0.0)))

    play, servo = excess("fin_backlash080_dist", 1), excess("srv_clean", 0)
    assert play[0] > 0.6 * floor and play[1] > 0.3 * floor, play   # the play is there ...
    assert servo[0] > 1.2 * play[0] and servo[1] > 1.8 * play[1], (servo, play)   # ... smaller


@pytest.mark.parametrize("name,fixed,joint,width", [
    ("fin_backlash080_dist", [], 2, 0.08),
    ("fin_pair_latency080_abd_backlash050_prox", [("latency", {"delay": [0.08, 0.0, 0.0]})], 1,
     0.05)])
def test_the_catalogue_backlash_read_on_the_motor_side_replays_a_rotor_read_play_closer_than_none(
        name, fixed, joint, width, tmp_path):
    """The project's replay of the case's logs with the catalogue's backlash at the true width
    on its joint, beside the nominal model (with the case's other effect at its true value), at
    the user's 2 ms step. Read on the link (``read`` 1, the null) every width replays worse than
    none (gap-sim3-11, session 16: a strict xfail here; 20.1 vs 1.29 mrad and 12.9 vs 1.50);
    read on the motor side, as sim3's finger encoder is (``read`` 0, gap-rotor12, session 17),
    closer than none: measured 1.263 vs 1.293 and 1.254 vs 1.496 mrad (at 0.5 ms, 0.683 vs
    0.827 and 0.685 vs 1.211: every joint at the read floor). Before the lock of a null play
    hinge went from an armature of 1e12 to 1e8 kg m^2, the motor-side play hinge replayed
    fin_backlash080_dist at 8.4 mrad (the locked abd and prox hinges spoiled the other joints)
    and the replay's regime choice kept the play operator instead, equal to the nominal."""
    from lowcostdex.gap.dataset import load_dataset
    from lowcostdex.gap.replay import Replayer
    from lowcostdex.sim.effects import AppliedEffect

    files = sim.write_case(sim.CASE_BY_NAME[name], tmp_path)
    ds = load_dataset(files["logs"], model=files["model"])
    eff = [AppliedEffect(n, ds.effect_joints, {k: np.asarray(v) for k, v in p.items()})
           for n, p in fixed]
    widths = [0.0] * 3
    widths[joint] = width
    plays = [AppliedEffect("backlash", ds.effect_joints, {"width": np.asarray(widths),
                                                          "sensor": np.zeros(3),
                                                          "read": np.full(3, read)})
             for read in (0.0, 1.0)]
    wins = _whole_logs(ds)
    (nom, motor, link), _ = Replayer(ds, ["backlash", *(n for n, _ in fixed)], nthread=1).run(
        wins, [eff, [*eff, plays[0]], [*eff, plays[1]]])

    def rms(pred):
        r = [ds.trajectories[w.traj].qpos[w.start:w.stop] - p
             for w, p in zip(wins, pred, strict=True)]
        return float(np.sqrt(np.mean(np.concatenate([x.ravel() for x in r]) ** 2)))
    assert rms(motor) < rms(nom) < rms(link), (rms(motor), rms(nom), rms(link))


def _whole_logs(ds):
    from lowcostdex.gap.dataset import Window
    return [Window(k, 0, len(tr.time), 0) for k, tr in enumerate(ds.trajectories)]


def test_logs_are_in_the_project_format(tmp_path):
    case = dataclasses.replace(sim.CASE_BY_NAME["fin_gain035_abd_50hz_posonly"], durations=(2.0,))
    files = sim.write_case(case, tmp_path)
    with open(files["logs"][0]) as fh:
        rows = list(csv.reader(fh))
    head, body = rows[0], np.array(rows[1:], dtype=float)
    assert head == ["time", "goal_time", "goal:servo_abd", "goal:servo_prox", "goal:servo_dist",
                    "qpos:abd", "qpos:prox", "qpos:dist"]
    assert np.diff(body[:, 0]) == pytest.approx(0.02)
    assert body[:, 1] - body[:, 0] == pytest.approx(sim.BUS_DELAY)
    ticks = body[:, 2:8] / sim.TICK
    assert np.abs(ticks - np.round(ticks)).max() < 1e-5
    model = mujoco.MjModel.from_xml_string((tmp_path / "model.xml").read_text())
    assert [model.actuator(i).name for i in range(model.nu)] == [h[5:] for h in head[2:5]]
    assert json.loads((tmp_path / "truth.json").read_text())["causes"][0]["effect"] == "gain_error"
    jit = dataclasses.replace(sim.CASE_BY_NAME["fin_clean_jitter_posonly"], durations=(3.0,))
    t = sim.row_times(jit, 3.0, np.random.default_rng(0))
    assert 0.010 <= np.diff(t).min() and np.diff(t).max() <= 0.030 and np.diff(t).std() > 0.004


def test_scoring_tells_exact_extra_family_miss_and_false_apart():
    def report(*causes):
        return {"causes": [{"effect": e, "joints": [j], "params": {p: {"value": [v], "interval": [[lo, hi]]}}}
                           for e, j, p, v, lo, hi in causes]}
    truth = sim.truth_dict(_case("finger", sim.Effect("latency", ("prox",), 0.06)))
    lat = ("latency", "prox", "delay", 0.061, 0.059, 0.063)
    s = sim.score(report(lat), truth)
    assert s["result"] == "exact" and s["params"][0]["inside"]
    assert sim.score(report(("latency", "prox", "delay", 0.05, 0.049, 0.051)), truth)["params"][0]["inside"] is False
    assert sim.score(report(lat, ("mass_error", "abd", "scale", 1.1, 1.05, 1.2)), truth)["result"] == "extra"
    idle = sim.score(report(lat, ("mass_error", "abd", "scale", 1.1, 0.95, 1.2)), truth)
    assert idle["result"] == "exact" and idle["idle"] == ["mass_error[abd]"]
    assert sim.score(report(("latency", "abd", "delay", 0.06, 0.05, 0.07)), truth)["result"] == "miss"
    assert sim.score(report(), truth)["result"] == "miss"
    gain = sim.truth_dict(_case("servo", sim.Effect("mass", ("q",), 2.5)))
    assert sim.score(report(("inertia_error", "q", "scale", 2, 1.5, 3)), gain)["result"] == "family"
    assert sim.score(report(("inertia_error", "q", "scale", 2, 1.5, 3), ("latency", "q", "delay", 0.01, 0.005, 0.02)), gain)["result"] == "extra_family"
    clean = sim.truth_dict(_case("finger"))
    assert sim.score(report(), clean)["result"] == "clean"
    assert sim.score(report(lat), clean)["result"] == "false"


def test_scoring_a_stribeck_level_that_holds_zero_is_idle_whatever_its_velocity():
    """gap-fric2 (session 9): the analysis fits a per-joint effect on every joint; a Stribeck
    level coulomb + static exp(-(v / velocity)^2) with coulomb and static intervals holding 0 is
    no friction on that joint, whatever its Stribeck velocity (no null of its own). The scorer
    listed it as named (fin_stribeck_prox: 'extra' on the two clean joints); a static or coulomb
    interval above 0 still names it, and the velocity is still checked on the hidden joint."""
    truth = sim.truth_dict(_case("finger", sim.Effect("stribeck", ("prox",), 0.05, (0.12, 0.05))))
    iv = {"abd": ((0.0, -0.01, 0.01), (0.0, -0.02, 0.02), (0.01, 0.01, 0.01)),
          "prox": ((0.07, 0.06, 0.08), (0.05, 0.045, 0.055), (0.05, 0.03, 0.07)),
          "dist": ((0.001, -0.004, 0.006), (0.0, -0.001, 0.001), (1.7, 0.2, 9.0))}

    def rep(dist_static_lo=-0.004):
        j = ("abd", "prox", "dist")
        rows = {n: [list(iv[x][i]) for x in j] for i, n in enumerate(("static", "coulomb", "velocity"))}
        rows["static"][2][1] = dist_static_lo
        return {"causes": [{"effect": "stribeck_friction", "joints": list(j), "params": {
            n: {"value": [r[0] for r in rows[n]], "interval": [r[1:] for r in rows[n]]}
            for n in rows}}]}

    s = sim.score(rep(), truth)
    assert s["result"] == "exact" and s["idle"] == ["stribeck_friction[abd]", "stribeck_friction[dist]"]
    assert {p["param"]: p["inside"] for p in s["params"]} == {"static": True, "coulomb": True, "velocity": True}
    s = sim.score(rep(dist_static_lo=0.0005), truth)
    assert s["result"] == "extra" and s["named"] == ["stribeck_friction[dist]", "stribeck_friction[prox]"]


# ------------------------------------------------------------ the analysis, per case (slow)


def _params():
    for case in sim.CASES:
        marks = [pytest.mark.slow, pytest.mark.timeout(3600)]
        if case.name in MISSES:
            marks.append(pytest.mark.xfail(strict=True, reason=MISSES[case.name]))
        yield pytest.param(case.name, marks=marks, id=case.name)


@pytest.mark.parametrize("name", list(_params()))
def test_names_exactly_the_hidden_causes_with_intervals_holding_the_truth(name, tmp_path):
    case = sim.CASE_BY_NAME[name]
    files = sim.write_case(case, tmp_path / "data")
    out = tmp_path / "report"
    code = main(["gap", "analyze", "--model", files["model"], "--log", *files["logs"],
                 "--out", str(out), "--seed", "0", "--threads", "2"])
    assert code == 0, f"gap analyze exited {code} on {name}"
    s = sim.score(json.loads((out / "report.json").read_text()), files["truth"])
    assert s["result"] in ("exact", "clean"), (
        f"hidden {sorted(case.causes) or 'nothing'}, named {s['named'] or 'nothing'}")
    outside = [p for p in s["params"] if not p["inside"]]
    assert not outside, f"true values outside their 95 % intervals: {outside}"
