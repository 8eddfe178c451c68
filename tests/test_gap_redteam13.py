"""The gap analysis judged on a thirteenth independently written truth simulator: a user's
UNDERACTUATED, TENDON-driven finger, one servo (a ``position`` actuator on a fixed tendon, gear
1 / horn radius) pulling a cable over the mcp and pip joints against return springs, the dip
coupled to the pip by a joint equality; and the same finger on a LINKAGE (a servo on the mcp,
one on the pip, the dip coupled to the pip by the joint equality: an Inspire-like finger)
(issue 11; gap-sim17, session 28; bench/RESULTS.md "gap-sim17").

``tests/gap_truth_sim13.py`` (mujoco + numpy only) writes the cases; each is analysed as the CLI
does (the user's MJCF, the log folder) and graded by ``redteam_check.assert_named_exactly``: the
named causes exactly the hidden ones (nothing on a clean case), every documented parameter inside
its 95 % interval. Misses are strict xfails whose reason is the measured result
(bench/gap_redteam13.py on the commit named there); they fail (XPASS) when fixed and must then
lose their mark.

The default run checks the truth's physics against numbers written out by hand (each check fails
if its effect were wrong or absent), that the user's model replayed in plain MuJoCo follows the
clean truth, and the logs' spelling.
"""

from __future__ import annotations

import math
import pathlib
import sys

import mujoco
import numpy as np
import pytest

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import gap_truth_sim13 as sim  # noqa: E402
import redteam_check  # noqa: E402

FAST: frozenset[str] = frozenset()

# what the analysis did instead, per case it misses (bench/gap_redteam13.py --threads 1 on the
# commit named; CPU: the analysis's user + sys). The linkage rig on b77fbff (bench/gap_redteam13.py
# --threads 1): link_clean clean (0.65 mrad, 60 s); exact with every interval holding the truth:
# link_latency (46.4 / 46.4 ms [44.7, 47.0] for 45.9 on mcp / pip, 47.06 -> 0.61 mrad, 84 s),
# link_gain (pip 1.617 [1.600, 1.657] for 1.631, mcp's 0.994 holds 1; 188 s), link_friction (pip
# 0.02242 N m [0.02195, 0.02263] for 0.0223, 241 s), link_mount (pip -0.1191 [-0.1192, -0.1190] for
# -0.1191, 238 s); link_curve (outside) passes: mounting_offset named as a partial stand-in,
# 67.8 -> 47.4 mrad, CI [12.9, 27.5], 'something beyond the named causes is at work' (76 s).
# Not run yet (no mark): link_backlash (stopped unfinished at 640 s CPU on f8ccac6), link_mass,
# link_latency_friction.
# The tendon rig on gap-tendon (session 29: the servo's effects on the actuator ``flex``, the
# joints' on mcp and pip; before it, every tendon case was refused, exit 2): clean_a clean
# (nothing to explain, 1.34 mrad, 5 s), gain exact (flex 1.636 [1.613, 1.662] for 1.631, 13.43 ->
# 2.00 mrad, 27 s), stretch (below). The common extra below: a dry friction of ~0.0005 N m on
# the mcp (a quarter of the model's 0.002) that the clean truth itself carries against the
# user's MJCF: the same frictionloss rides on another constraint softness in the truth (its
# dof_invweight0 1.35x the user's on the mcp, 2.1x on the pip: the user's tendon armature is in
# the mass matrix, the truth's rotor behind the cable); without dry friction the two replay
# 0.2-0.4 mrad apart (bench/RESULTS.md gap-tendon).
EXTRA_MCP = ("named with a small coulomb_friction on the mcp (~0.0005 N m, a quarter of the "
             "model's own) that the clean truth carries against the user's MJCF (clean_b)")
MISSES: dict[str, str] = {
    "clean_b": "false on gap-tendon: coulomb_friction mcp 0.00059 N m [0.00042, 0.00072] (1.37 -> "
               "1.06 mrad, CI [0.05, 0.53]; 33 s); the clean truth replays 1.8 mrad (3 floors) "
               "off the user's MJCF at 1 ms",
    "latency": "extra on gap-tendon: latency flex 46.9 ms [43.3, 48.3] for 45.9 (30.06 -> 1.08 "
               "mrad, 36 s), " + EXTRA_MCP,
    "offset": "extra on gap-tendon: position_offset mcp -0.1169 [-0.1172, -0.1166] for -0.1168 "
              "(67.25 -> 0.94 mrad, 138 s), " + EXTRA_MCP,
    "friction": "miss on gap-tendon: viscous_damping named (3.63 -> 2.89 mrad, no reliable gain; "
                "90 s); coulomb_friction fitted pip 0.0058 N m for +0.0223 (select gain 34 %): "
                "the truth's pip has a 2.1x larger dof_invweight0 than the user's model's, "
                "on which MuJoCo's friction constraint's softness rides (inferred)",
    "mass": "family on gap-tendon: position_offset + gain_error[flex] named (24.65 -> 7.98 mrad, "
            "150 s) for the distal phalanx's mass x2.35: the dip (no actuator, coupled to the pip) "
            "is no effect joint, so mass_error can act only on the mcp and pip links",
    "latency_friction": "extra on gap-tendon: latency flex 47.6 ms [42.7, 50.4] for 45.9, "
                        "coulomb_friction (pip 0 [-0.0006, 0.0005] for +0.0223: OUT) and "
                        "viscous_damping named (33.46 -> 2.21 mrad, 75 s)",
    "backlash": "not offered on a tendon model: a horn's play needs a joint between the servo "
                "and the tendon (gap.offer.TENDON_WHY); not run",
}  # stretch (outside) passes on gap-tendon: gain_error[flex] 0.487 [0.483, 0.493] named as a
# flagged stand-in, 31.56 -> 3.42 mrad, CI [26.5, 29.2], 'something beyond ... at work' (176 s)

G = 9.81
E, C = sim.Effect, sim.Case


@pytest.mark.parametrize("name", redteam_check.case_params(sim, FAST, MISSES))
def test_names_exactly_the_hidden_causes_with_intervals_holding_the_truth(name, tmp_path):
    redteam_check.assert_named_exactly(sim, name, tmp_path)


def test_truth_simulator_imports_nothing_from_the_project():
    names = redteam_check.imported_top_modules(HERE / "gap_truth_sim13.py")
    assert names <= {"__future__", "dataclasses", "json", "math", "pathlib", "mujoco",
                     "numpy", "redteam_grade"}, names


def test_the_servo_law_by_hand():
    """tau = clip(gain kp (goal - reading), -0.5, 0.5) N m at the horn: 3 N m/rad x 0.1 rad =
    0.3 N m, x0.5 gain 0.15, clipped at 0.5 N m either way."""
    assert sim.servo_torque(1.0, 0.9) == pytest.approx(0.3)
    assert sim.servo_torque(1.0, 0.9, gain=0.5) == pytest.approx(0.15)
    assert sim.servo_torque(1.5, 0.5) == pytest.approx(0.5)
    assert sim.servo_torque(0.2, 1.0) == pytest.approx(-0.5)


def test_the_users_tendon_by_hand():
    """The user's cable: its length is 8 mm x mcp + 6 mm x pip (the dip only through the
    coupling), the actuator's length 100 x that (the servo's angle on a 10 mm horn), and a pull
    of the servo's 0.3 N m is 30 N of cable: 0.24 N m at the mcp, 0.18 at the pip."""
    m = mujoco.MjModel.from_xml_string(sim.model_xml())
    d = mujoco.MjData(m)
    d.qpos[:] = [0.4, 0.7, 0.56]
    mujoco.mj_forward(m, d)
    assert d.ten_length[0] == pytest.approx(0.008 * 0.4 + 0.006 * 0.7)
    assert d.actuator_length[0] == pytest.approx(100 * (0.008 * 0.4 + 0.006 * 0.7))
    moment = np.zeros(m.nv)
    mujoco.mju_sparse2dense(moment.reshape(1, -1), d.actuator_moment, d.moment_rownnz,
                            d.moment_rowadr, d.moment_colind)
    assert 0.3 * moment == pytest.approx([0.24, 0.18, 0.0])


def _run(effects: tuple, goal, seconds: float) -> tuple:
    t = np.arange(-sim.SETTLE, seconds, 0.01)
    out = sim.simulate(C("check", effects), t, goal(t), np.random.default_rng(1),
                       true_state=True)
    return t, out


def _gravity_on_mcp(q: np.ndarray, dip_mass: float) -> float:
    """The links' weight about the mcp axis [N m, extending]: each link's mass at its middle,
    the finger lifted by q1, q1 + q2, q1 + q2 + q3 from the horizontal."""
    l1, l2, l3 = (sim.LENGTH[j] for j in sim.JOINTS)
    m1, m2 = sim.MASS["mcp"], sim.MASS["pip"]
    a1, a2, a3 = q[0], q[0] + q[1], q[0] + q[1] + q[2]
    x1 = l1 / 2 * math.cos(a1)
    x2 = l1 * math.cos(a1) + l2 / 2 * math.cos(a2)
    x3 = l1 * math.cos(a1) + l2 * math.cos(a2) + l3 / 2 * math.cos(a3)
    return G * (m1 * x1 + m2 * x2 + dip_mass * x3)


def test_the_finger_held_on_its_cable_written_out():
    """Held at a servo goal of 1.0 rad: the cable is taut (10 mm x horn = 8 mm x mcp + 6 mm x
    pip), the dip is 0.8 x the pip, and the mcp's balance holds: its spring k (q - ref) plus the
    links' weight about it equals 8 mm x the cable's tension, the servo's torque over the 10 mm
    horn, kp gain (goal - horn) / R, within the mcp's dry friction (0.002 N m). A gain of 0.5
    doubles the horn's sag; a distal phalanx twice as heavy weighs on the balance; an mcp
    encoder 0.09 rad off moves the reading, not the finger."""
    for effects, gain, dip_mass, off in (
            ((), 1.0, sim.MASS["dip"], 0.0),
            ((E("gain", 0.5),), 0.5, sim.MASS["dip"], 0.0),
            ((E("mass", 2.0),), 1.0, 2 * sim.MASS["dip"], 0.0),
            ((E("offset", 0.09),), 1.0, sim.MASS["dip"], 0.09)):
        t, out = _run(effects, lambda t: 0.0 * t + 1.0, 1.0)
        late = t > 0.5
        q = np.array([np.mean(out[f"true:{j}"][late]) for j in sim.JOINTS])
        horn = float(np.mean(out["horn"][late]))
        assert sim.HORN * horn == pytest.approx(0.008 * q[0] + 0.006 * q[1], abs=2e-6)
        assert q[2] == pytest.approx(0.8 * q[1], abs=2e-3)
        tension = gain * sim.KP * (1.0 - horn) / sim.HORN
        load = sim.STIFF["mcp"] * (q[0] - sim.SPRINGREF["mcp"]) + _gravity_on_mcp(q, dip_mass)
        assert abs(0.008 * tension - load) < sim.FRICTION["mcp"] + 2e-4, (effects, tension, load)
        assert np.mean(out["qpos:mcp"][late]) == pytest.approx(q[0] + off, abs=5e-4)


def test_the_latency_the_horns_play_and_the_cables_stretch_written_out():
    """A goal ramp from 0.4 to 1.2 rad at 0.2 s: 40 ms of latency delays the finger's first move
    by 40 ms. A play of 0.08 rad between the servo's shaft and the horn: the cable's pull keeps
    the horn on one side, 0.04 rad behind the shaft, wherever the goal goes. An elastic cable of
    20 kN/m stretches by its tension over 20 kN/m (nothing stretches the limit-held cable)."""
    goal = lambda t: np.clip(0.4 + (t - 0.2) / 0.3 * 0.8, 0.4, 1.2)  # noqa: E731
    first = {}
    for effects in ((), (E("latency", 0.04),)):
        t, out = _run(effects, goal, 1.0)
        moved = (t > 0.2) & (out["true:mcp"] > out["true:mcp"][t < 0.2][-1] + 0.003)
        first[effects] = float(t[np.argmax(moved)])
    assert first[(E("latency", 0.04),)] - first[()] == pytest.approx(0.04, abs=0.011)
    t, out = _run((E("backlash", 0.08),), goal, 1.0)
    held = (t > -0.5) & ((t < 0.2) | (t > 0.7))
    assert np.all(np.abs(out["rotor"][held] - out["horn"][held] - 0.04) < 0.002)
    for effects, k in (((), math.inf), ((E("stretch", 20000.0),), 20000.0)):
        t, out = _run(effects, goal, 1.0)
        late = t > 0.8
        horn, rotor = (float(np.mean(out[n][late])) for n in ("horn", "rotor"))
        tension = sim.KP * (1.2 - rotor) / sim.HORN
        cable = sim.HORN * horn - np.mean(0.008 * out["true:mcp"][late]
                                          + 0.006 * out["true:pip"][late])
        assert cable == pytest.approx(tension / k, abs=5e-6), (effects, cable, tension)


def test_the_users_model_follows_the_clean_truth():
    """The user's MJCF replayed in plain MuJoCo at its 2 ms step from the truth's first state
    with the logged goals (zero-order hold) follows the clean truth's log open loop for 6 s:
    measured 1.4 / 1.9 / 1.6 mrad RMS (mcp / pip / dip; the read noise is 0.4 mrad: the dry
    friction's stick positions along the finger's underactuated direction, where only the
    springs hold it, at 2 ms against 0.25 ms); 30 ms of latency puts it > 10 mrad off."""
    rms = {}
    for effects in ((), (E("latency", 0.03),)):
        rng = np.random.default_rng(7)
        t = sim.host_times(6.0, rng)
        goal = sim.targets(t, rng)
        out = sim.simulate(C("check", effects), t, goal, rng, true_state=True)
        m = mujoco.MjModel.from_xml_string(sim.model_xml())
        d = mujoco.MjData(m)
        d.qpos[:] = [out[f"true:{j}"][0] for j in sim.JOINTS]
        steps = t[0] + np.arange(int((t[-1] - t[0]) / m.opt.timestep)) * m.opt.timestep
        rec = np.zeros((len(steps), 3))
        for s, ts in enumerate(steps):
            d.ctrl[0] = goal[np.searchsorted(t, ts, side="right") - 1]
            rec[s] = d.qpos
            mujoco.mj_step(m, d)
        read = np.column_stack([np.interp(steps, t, out[f"qpos:{j}"]) for j in sim.JOINTS])
        late = steps > 0.0
        rms[effects] = np.sqrt(np.mean((rec[late] - read[late]) ** 2, axis=0))
    assert np.all(rms[()] < 0.0025), rms[()]
    assert np.all(rms[(E("latency", 0.03),)] > 0.010), rms


def test_the_logs_as_the_user_writes_them(tmp_path):
    """Seconds from 0, the servo's goal and the three joints in radians, no velocity column,
    the finger off its joint limits; truth.json marks the stretch outside the catalogue."""
    case = sim.CASE_BY_NAME["clean_a"]
    files = sim.write_case(C(case.name, case.effects, (3.0, 3.0), case.seed), tmp_path / "a")
    assert "args" not in files and files["truth"]["causes"] == []
    for i in range(2):
        path = tmp_path / "a" / "logs" / f"log{i}.csv"
        assert path.read_text().splitlines()[0] == "time,goal:flex,qpos:mcp,qpos:pip,qpos:dip"
        a = np.loadtxt(path, delimiter=",", skiprows=1)
        assert 0.0 <= a[0, 0] < 0.02 and np.all(np.diff(a[:, 0]) > 0.008)
        assert np.all((a[:, 1] >= 0.3) & (a[:, 1] <= 1.5))
        assert np.all((a[:, 2:] > -0.1) & (a[:, 2:] < 1.3))
    files = sim.write_case(C("s", (E("stretch", 20000.0),), (1.0,), 1), tmp_path / "s")
    assert files["truth"]["outside"] and files["truth"]["causes"] == []
    with pytest.raises(ValueError, match="valid: latency"):
        E("slack", 1.0)


def _gravity_on_pip(q: np.ndarray) -> float:
    """The weight the pip servo holds [N m, extending]: the pip and dip links about the pip
    axis, plus the dip link's weight about the dip axis times 0.8 (the linkage: the dip turns
    0.8 rad per pip rad, so by virtual work its torque reaches the pip times 0.8)."""
    l2, l3 = sim.LENGTH["pip"], sim.LENGTH["dip"]
    a2, a3 = q[0] + q[1], q[0] + q[1] + q[2]
    x2 = l2 / 2 * math.cos(a2)
    x3 = l2 * math.cos(a2) + l3 / 2 * math.cos(a3)
    return G * (sim.MASS["pip"] * x2 + sim.MASS["dip"] * x3
                + sim.COUPLE * sim.MASS["dip"] * l3 / 2 * math.cos(a3))


def _linkage(effects: tuple, mcp, pip, seconds: float) -> tuple:
    t = np.arange(-sim.SETTLE, seconds, 0.01)
    out = sim.simulate_linkage(C("check", effects, rig="linkage finger"), t,
                               {"mcp": mcp(t), "pip": pip(t)}, np.random.default_rng(1),
                               true_state=True)
    return t, out


def test_the_linkage_finger_held_written_out():
    """The linkage rig held at mcp 0.5, pip 0.8 rad: the pip servo's torque kp gain (goal - s)
    holds the pip and dip links' weight (the dip's own through the linkage, x0.8) within the
    pins' dry friction (0.003 + 0.8 x 0.001 N m); the dip is 0.8 x the pip. A kp x0.5 doubles the
    sag. A servo mounted 0.1 rad off holds its reading at the goal: the link sits 0.1 rad below
    it, the log's pip reads the goal (less the sag), the dip's encoder sees 0.08 rad less. A
    four-bar's curve c = 0.2: dip = 0.8 pip + 0.2 pip^2."""
    one = lambda v: (lambda t: 0.0 * t + v)  # noqa: E731
    for effects, gain, off, curve in (((), 1.0, 0.0, 0.0),
                                      ((E("gain", 0.5, ("pip",)),), 0.5, 0.0, 0.0),
                                      ((E("mount", 0.1, ("pip",)),), 1.0, 0.1, 0.0),
                                      ((E("curve", 0.2),), 1.0, 0.0, 0.2)):
        t, out = _linkage(effects, one(0.5), one(0.8), 1.0)
        late = t > 0.5
        q = np.array([np.mean(out[f"true:{j}"][late]) for j in sim.JOINTS])
        assert q[2] == pytest.approx(0.8 * q[1] + curve * q[1] ** 2, abs=1e-3), effects
        if not curve:
            held = gain * sim.LKP["pip"] * (0.8 - off - q[1])
            band = sim.LFRIC["pip"] + 0.8 * sim.LFRIC["dip"] + 2e-4
            assert abs(held - _gravity_on_pip(q)) < band, (effects, held, _gravity_on_pip(q))
        assert np.mean(out["qpos:pip"][late]) == pytest.approx(q[1] + off, abs=5e-4)
        assert np.mean(out["qpos:dip"][late]) == pytest.approx(q[2], abs=5e-4)


def test_the_linkage_pips_play_written_out():
    """A play of 0.08 rad between the pip servo and its link: gravity pulls the link down (to
    -q), so it hangs 0.04 rad behind the servo's rotor wherever the goal holds it (after a
    step up it swings across the play and back: measured settled within 0.45 s)."""
    t, out = _linkage((E("backlash", 0.08, ("pip",)),), lambda t: 0.0 * t + 0.4,
                      lambda t: np.where(t < 0.3, 0.3, 0.9), 1.0)
    held = (t > -0.5) & ((t < 0.3) | (t > 0.8))   # the step's swing across the play settled
    assert np.all(np.abs(out["rotor:pip"][held] - out["true:pip"][held] - 0.04) < 0.002)


def test_the_users_linkage_model_follows_the_clean_truth():
    """The user's linkage MJCF replayed in plain MuJoCo at 2 ms from the truth's first state
    with the logged goals follows the clean truth's log open loop for 6 s: measured 0.7 / 1.0 /
    0.8 mrad RMS (read noise 0.4); a four-bar's curve of 0.15 puts the dip > 50 mrad off."""
    rms = {}
    for effects in ((), (E("curve", 0.15),)):
        rng = np.random.default_rng(7)
        t = sim.host_times(6.0, rng)
        goals = {j: sim.targets(t, rng, sim.LGOALS[j]) for j in sim.SERVOS}
        out = sim.simulate_linkage(C("check", effects, rig="linkage finger"), t, goals, rng)
        m = mujoco.MjModel.from_xml_string(sim.linkage_xml())
        d = mujoco.MjData(m)
        d.qpos[:] = [out[f"qpos:{j}"][0] for j in sim.JOINTS]
        steps = t[0] + np.arange(int((t[-1] - t[0]) / m.opt.timestep)) * m.opt.timestep
        rec = np.zeros((len(steps), 3))
        for s, ts in enumerate(steps):
            k = np.searchsorted(t, ts, side="right") - 1
            d.ctrl[:] = [goals["mcp"][k], goals["pip"][k]]
            rec[s] = d.qpos
            mujoco.mj_step(m, d)
        read = np.column_stack([np.interp(steps, t, out[f"qpos:{j}"]) for j in sim.JOINTS])
        late = steps > 0.0
        rms[effects] = np.sqrt(np.mean((rec[late] - read[late]) ** 2, axis=0))
    assert np.all(rms[()] < 0.0015), rms[()]
    assert rms[(E("curve", 0.15),)][2] > 0.05, rms


def test_the_linkage_logs_as_the_user_writes_them(tmp_path):
    """Two goals (the mcp and pip servos), three joints read, radians, no velocity column."""
    case = sim.CASE_BY_NAME["link_clean"]
    files = sim.write_case(C(case.name, (), (2.0,), case.seed, rig=case.rig), tmp_path)
    path = tmp_path / "logs" / "log0.csv"
    assert path.read_text().splitlines()[0] == \
        "time,goal:mcp,goal:pip,qpos:mcp,qpos:pip,qpos:dip"
    m = mujoco.MjModel.from_xml_string(pathlib.Path(files["model"]).read_text())
    assert [m.actuator(i).name for i in range(m.nu)] == ["mcp", "pip"] and m.neq == 1
