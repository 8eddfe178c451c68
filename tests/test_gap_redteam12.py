"""The gap analysis judged on a twelfth independently written truth simulator: a user's low-cost
gripper, its jaw on a SLIDE joint in metres (a linear servo or a rack written as a plain
``position`` actuator in N/m and N) with a finger on a hinge riding on it, the logs squeezing a
clamped block and pressing the fingertip on the table, both in the user's MJCF (issue 11;
gap-sim15, session 27; bench/RESULTS.md "gap-sim15").

``tests/gap_truth_sim12.py`` (mujoco + numpy only) writes the cases; each is analysed as the CLI
does (the user's MJCF, the log folder) and graded by ``redteam_check.assert_named_exactly``: the
named causes exactly the hidden ones (nothing on a clean case, with or without contact), every
documented parameter inside its 95 % interval, in the joint's own units. Misses are strict
xfails whose reason is the measured result (bench/gap_redteam12.py on the commit named there);
they fail (XPASS) when fixed and must then lose their mark.

The default run checks the truth's physics against numbers written out by hand (each check
fails if its effect were wrong or absent), that the user's model replayed in plain MuJoCo follows
the clean truth through its contacts, and the logs' spelling.
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
import gap_truth_sim12 as sim  # noqa: E402
import redteam_check  # noqa: E402

FAST: frozenset[str] = frozenset()

# what the analysis named instead, per case it misses (bench/gap_redteam12.py --threads 1 on the
# commit named; CPU: the analysis's user + sys). Named exactly: grip_offset (mounting_offset
# 2.869 mm [2.686, 3.066] for 2.92, named forward in round 1, 386 s, gap-sim16 session 28 on
# its paired_low block rule at RESOLVE 0.75; the same numbers at 0.375 on 502c02d, 384 s,
# gap-sweep24; a strict xfail from 5a6e8c9: viscous_damping named since
# 96768eb, the offset's 55 % select gain bounded at -0.17 %), latency (40.55 ms [39.84, 41.6] and 40.25
# [39.67, 40.51] for 40.1, 138 s, 96768eb), finger_offset (-0.06687 rad [-0.06706, -0.06677]
# for -0.0669, 257 s, 96768eb), finger_friction (0.07582 N m [0.07402, 0.07702] for 0.0748,
# 131 s, ac95024); clean: clean_free (43 s), clean_contact (49 s) on 5598aed. Not run yet (no
# mark): finger_backlash, grip_friction_finger_offset.
MISSES: dict[str, str] = {
    "grip_friction": "named exactly on 96768eb, but the interval misses: coulomb_friction on the "
    "jaw 7.814 N [7.813, 7.816] for 7.69 (1.6 % high; the interval is +-0.02 %: the 0.5 s blocks "
    "agree, so no resampling sees a bias common to all of them); 1.301 -> 0.451 (x1e-3, m and rad "
    "pooled), 276 s CPU; the report gives its unit as 'N m'",
    "grip_backlash": "miss on ac95024 (gap-sim16, first run): nothing named ('no candidate "
    "lowers the select error significantly'); the rack's 0.93 mm play left the jaw 0.379 mm "
    "RMSE held out (39 of its floors) beside the finger's 0.806 mrad; backlash was fitted in "
    "round 1 but ran to its widened bound (width 10 mm / 10 mrad, read on the motor side) with "
    "0.0 % select gain; latency 9.6 ms ranked first (-11 %); 229 s CPU at 0.5 ms. The verdict "
    "read 'no significant discrepancy' (the pooled m+rad RMSE within 3 pooled floors)",
    "grip_gain": "named exactly since gap-sim16's fit.scan_scales (session 28; was a miss: a "
    "backlash named, gain_error's two-joint fit stalled at 1.000 beside the finger's jagged "
    "cost), but the interval misses: gain_error on the jaw 0.5373 [0.5362, 0.5379] for 0.546 "
    "(1.6 % low; the jaw's own valley pins it to +-0.1 %, the finger's stick-slip on the table "
    "moves the pooled optimum); finger 0.9981 [0.9955, 1.002]; 1.162 -> 0.419 (x1e-3, m and rad "
    "pooled), analysed at 0.25 ms, 406 s CPU",
}

G = 9.81
E, C = sim.Effect, sim.Case


@pytest.mark.parametrize("name", redteam_check.case_params(sim, FAST, MISSES))
def test_names_exactly_the_hidden_causes_with_intervals_holding_the_truth(name, tmp_path):
    redteam_check.assert_named_exactly(sim, name, tmp_path)


def test_truth_simulator_imports_nothing_from_the_project():
    names = redteam_check.imported_top_modules(HERE / "gap_truth_sim12.py")
    assert names <= {"__future__", "dataclasses", "json", "math", "pathlib", "mujoco",
                     "numpy", "redteam_grade"}, names


def test_the_servo_law_by_hand():
    """F = clip(gain kp (goal - reading), -F_max, F_max): 2500 N/m x 4 mm = 10 N, clipped at
    40 N; 3 N m/rad x 0.1 rad = 0.3 N m, x0.5 gain 0.15, clipped at 1 N m."""
    assert sim.servo_force("grip", 0.024, 0.020) == pytest.approx(10.0)
    assert sim.servo_force("grip", 0.040, 0.010) == pytest.approx(40.0)
    assert sim.servo_force("grip", 0.000, 0.030) == pytest.approx(-40.0)
    assert sim.servo_force("finger", 0.3, 0.2) == pytest.approx(0.3)
    assert sim.servo_force("finger", 0.3, 0.2, gain=0.5) == pytest.approx(0.15)
    assert sim.servo_force("finger", 0.9, 0.0) == pytest.approx(1.0)


def _run(effects: tuple, grip, finger, seconds: float) -> tuple:
    t = np.arange(-sim.SETTLE, seconds, 0.01)
    out = sim.simulate(C("check", effects), t, {"grip": grip(t), "finger": finger(t)},
                       np.random.default_rng(1), true_state=True)
    return t, out


def test_the_finger_held_against_gravity_written_out():
    """Held at 0.3 rad, the finger (100 g, 35 mm out; gravity torque m g x cos q toward +q)
    sags until the servo answers it: q - goal = m g x cos q / (gain kp) = 10.9 mrad; 21.8 at
    half the kp. A sensor offset of -0.08 rad: the servo holds its reading at the goal, so the
    true angle is the goal + 0.08 (+ its sag there) and the log reads it - 0.08. The axle's
    0.01 N m of dry friction leaves a band of 0.01 / (gain kp) = 3.3 mrad / gain."""
    for effects, gain, off in (((), 1.0, 0.0), ((E("gain", 0.5, "finger"),), 0.5, 0.0),
                               ((E("offset", -0.08, "finger"),), 1.0, -0.08)):
        t, out = _run(effects, lambda t: 0.0 * t + 0.01, lambda t: 0.0 * t + 0.3, 2.0)
        late = t > 1.0
        q = float(np.mean(out["true:finger"][late]))
        sag = sim.FINGER_MASS * G * sim.FINGER_COM * math.cos(q) / (gain * sim.KP["finger"])
        band = sim.FRICTION["finger"] / (gain * sim.KP["finger"])
        assert abs(q - (0.3 - off) - sag) < band + 0.0005, (effects, q, sag)
        assert np.mean(out["qpos:finger"][late]) == pytest.approx(q + off, abs=0.0005)


def test_contact_with_the_block_and_the_table_written_out():
    """The jaw squeezing the block (goal 40 mm, the pad meets it at 35 mm: 12.5 N) stops at
    35 mm within a few um of the contact's compliance, and reads 35 mm + a 2 mm sensor offset
    with it (the block does not move with the sensor's zero); released to 20 mm it comes back
    within the rail friction's band, 1 N / 2500 N/m = 0.4 mm (+8 N: 3.6 mm). The fingertip
    pressed on the table (goal 0.9 rad) stops at asin((50 - 6) / 70 mm) = 0.680 rad."""
    grip = lambda t: np.where(t < 1.0, 0.040, 0.020)  # noqa: E731
    finger = lambda t: 0.0 * t + 0.9  # noqa: E731
    for effects, off, band in (((), 0.0, 0.0004),
                               ((E("offset", 0.002, "grip"),), 0.002, 0.0004),
                               ((E("friction", 8.0, "grip"),), 0.0, 0.0036)):
        t, out = _run(effects, grip, finger, 2.0)
        pressed, released = (t > 0.5) & (t < 1.0), t > 1.8
        assert np.all(np.abs(out["true:grip"][pressed] - sim.CONTACT_GRIP) < 2e-5), effects
        assert np.mean(out["qpos:grip"][pressed]) == pytest.approx(sim.CONTACT_GRIP + off,
                                                                   abs=2e-5)
        err = out["true:grip"][released] + off - 0.020
        assert np.all(np.abs(err) <= band + 3e-5), (effects, err.max())
        if band > 0.001:   # the added friction's band is used (MuJoCo's friction creeps)
            assert abs(err.mean()) > 0.3 * band, effects
        assert np.all(np.abs(out["true:finger"][t > 0.0] - 0.680) < 0.002), effects


def test_the_latency_and_the_racks_play_written_out():
    """A jaw step at 0.2 s: with 40 ms of latency its first motion comes 40 ms later. A play of
    1 mm between pinion and jaw: the jaw moves 1 mm against the pinion across the reversals
    (measured within the tendon limit's compliance); the finger's play of 40 mrad likewise."""
    grip = lambda t: np.where(t < 0.2, 0.01, np.where(t < 0.8, 0.025, 0.01))  # noqa: E731
    finger = lambda t: np.where(t < 0.2, -0.3, np.where(t < 0.8, 0.4, -0.3))  # noqa: E731
    first = {}
    for effects in ((), (E("latency", 0.04),)):
        t, out = _run(effects, grip, finger, 1.5)
        moved = (t > 0.2) & (out["true:grip"] > 0.0101)
        first[effects] = float(t[np.argmax(moved)])
        assert np.ptp(out["true:grip"] - out["rotor:grip"]) == 0.0
    assert first[(E("latency", 0.04),)] - first[()] == pytest.approx(0.04, abs=0.011)
    t, out = _run((E("backlash", 0.001, "grip"), E("backlash", 0.04, "finger")), grip, finger,
                  1.5)
    assert 0.00095 <= np.ptp(out["true:grip"] - out["rotor:grip"]) <= 0.00105
    assert 0.038 <= np.ptp(out["true:finger"] - out["rotor:finger"]) <= 0.042


def test_the_inertias_by_hand():
    """The joint-space inertia at rest, finger level: the slide carries armature 0.35 kg + jaw
    0.12 + finger 0.10 = 0.57 kg; the finger armature 0.002 + m x^2 = 1.225e-4 + its own 4e-5
    about y: 2.1625e-3 kg m^2; the user's model and the truth's alike."""
    for xml in (sim.model_xml(), sim.model_xml(C("check"), sim.TRUTH_DT, truth=True)):
        m = mujoco.MjModel.from_xml_string(xml)
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)
        assert np.diag(full) == pytest.approx([0.57, 2.1625e-3], rel=1e-6)


def test_the_users_model_follows_the_clean_truth_through_its_contacts():
    """The contacts are modelled: the user's MJCF replayed in plain MuJoCo at its 2 ms step
    from the truth's first state with the logged goals (zero-order hold) follows the clean
    truth's pressing log (the jaw on the block a third of the time, the fingertip on the table
    two fifths) open loop for 6 s: measured 0.08 mm / 1.7 mrad RMS (the read noise is 8 um /
    0.4 mrad; dry friction's stick positions and the fingertip's stick-slip on the table at 2 ms
    against 0.25 ms); a 2 mm sensor offset on the jaw puts it 1.26 mm RMS off (the block sits
    where it sits)."""
    rms = {}
    for effects in ((), (E("offset", 0.002, "grip"),)):
        rng = np.random.default_rng(7)
        t = sim.host_times(6.0, rng)
        goals = {j: sim.targets(j, True, t, rng) for j in sim.JOINTS}
        out = sim.simulate(C("check", effects), t, goals, rng)
        m = mujoco.MjModel.from_xml_string(sim.model_xml())
        d = mujoco.MjData(m)
        d.qpos[:] = [out["qpos:grip"][0], out["qpos:finger"][0]]
        steps = t[0] + np.arange(int((t[-1] - t[0]) / m.opt.timestep)) * m.opt.timestep
        rec = np.zeros((len(steps), 2))
        for s, ts in enumerate(steps):
            k = np.searchsorted(t, ts, side="right") - 1
            d.ctrl[:] = [goals["grip"][k], goals["finger"][k]]
            rec[s] = d.qpos
            mujoco.mj_step(m, d)
        read = np.column_stack([np.interp(steps, t, out[f"qpos:{j}"]) for j in sim.JOINTS])
        rms[effects] = np.sqrt(np.mean((rec - read) ** 2, axis=0))
    assert np.mean(goals["grip"] > sim.CONTACT_GRIP) > 0.2   # the log presses
    assert rms[()][0] < 0.0002 and rms[()][1] < 0.0025, rms[()]
    assert rms[(E("offset", 0.002, "grip"),)][0] > 4 * rms[()][0]


def test_the_logs_as_the_user_writes_them(tmp_path):
    """Seconds from 0, metres on the slide and radians on the finger, no velocity column; the
    logs press (the jaw on the block, the fingertip on the table) and clean_free's never."""
    for name, presses in (("clean_contact", True), ("clean_free", False)):
        case = sim.CASE_BY_NAME[name]
        case = C(case.name, case.effects, (3.0, 3.0), case.seed, case.contact)
        files = sim.write_case(case, tmp_path / name)
        assert "args" not in files
        for i in range(2):
            path = tmp_path / name / "logs" / f"log{i}.csv"
            assert path.read_text().splitlines()[0] == \
                "time,goal:grip,goal:finger,qpos:grip,qpos:finger"
            a = np.loadtxt(path, delimiter=",", skiprows=1)
            assert 0.0 <= a[0, 0] < 0.02 and np.all(np.diff(a[:, 0]) > 0.008)
            assert np.all((a[:, 3] > -0.001) & (a[:, 3] < 0.045))   # metres
            on_block = np.mean(np.abs(a[:, 3] - sim.CONTACT_GRIP) < 1e-4)
            on_table = np.mean(np.abs(a[:, 4] - sim.CONTACT_FINGER) < 3e-3)
            assert (on_block > 0.05 or on_table > 0.05) == presses, (name, i)


def test_a_slides_play_is_a_slide_in_metres():
    """The analysis's backlash on the gripper's slide: a slide play beside the jaw's slide (two
    slides of one body along one axis add: the jaw sits at motor + play), limited to +-width/2
    in metres. Driven up 15 mm and held, the jaw rests a half play (0.5 mm) behind the motor;
    driven back down, a half play ahead. Every model with a slide crashed ``gap analyze`` on
    acf2f02 ('backlash: 'grip' must be a hinge joint of the model'), before any replay."""
    from lowcostdex.sim.effects import AppliedEffect
    from lowcostdex.sim.plant import Plant, prepare_spec

    spec = mujoco.MjSpec.from_string(sim.model_xml())
    play = [AppliedEffect("backlash", ("grip",), {"width": np.array([0.001])})]
    model = prepare_spec(spec, play, hidden_dofs=True).compile()
    assert [int(model.jnt_type[model.joint(n).id]) for n in ("grip", "grip__play")] == \
        [int(mujoco.mjtJoint.mjJNT_SLIDE)] * 2
    plant = Plant(model, play)
    n = round(0.01 / model.opt.timestep)
    held = {}
    for k in range(150):
        plant.step(np.array([0.010 if k < 20 or k >= 80 else 0.025, 0.0]), n)
        if k in (79, 149):
            held[k] = float(plant.qpos[model.jnt_qposadr[model.joint("grip__play").id]])
    assert held[79] == pytest.approx(-0.0005, abs=1e-4)
    assert held[149] == pytest.approx(0.0005, abs=1e-4)


def test_a_slides_millimetres_are_not_lost_among_the_fingers_radians(tmp_path):
    """The selection's "nothing to explain" stop: the jaw's replay 1.5 mm off (its read floor
    is ~9 um: 170 floors) beside a finger replayed to its floor is something to explain. On
    acf2f02 the pooled RMSE (1.1e-3 "rad") sat within 3 pooled floors (0.6 mrad of the finger's
    noise beside the jaw's 9 um), and the grip_offset case (a 2.9 mm sensor offset) stopped at
    round 0 with nothing named."""
    from lowcostdex.gap.dataset import episodes, load_dataset
    from lowcostdex.gap.diagnostics import noise_floor
    from lowcostdex.gap.selection import nothing_to_explain

    case = C("floor", (), (3.0, 3.0), seed=5)
    files = sim.write_case(case, tmp_path)
    ds = load_dataset(files["logs"], model=files["model"])
    eps = episodes(ds)
    floor = noise_floor(ds.trajectories)
    assert floor[0] < 2e-5 < 3e-4 < floor[1], floor
    model = mujoco.MjModel.from_xml_string(sim.model_xml())
    exact = [ds.trajectories[w.traj].qpos[w.start:w.stop] for w in eps]
    assert nothing_to_explain(ds, eps, exact, floor, 3.0, model)
    jaw_off = [q - np.array([0.0015, 0.0]) for q in exact]
    assert not nothing_to_explain(ds, eps, jaw_off, floor, 3.0, model)


def test_a_rails_dry_friction_in_newtons_is_inside_the_search_range():
    """The jaw's servo pushes up to 40 N; a dry rail's 5-20 N of friction (the truth's
    grip_friction draws 7.69 N) must be reachable by the fit of coulomb_friction on the slide.
    On 5598aed the catalogue's hard cap of 5 (N m, a hinge's) bounded it at 5 N; the finger's
    hinge keeps its cap."""
    from lowcostdex.gap import fit as fitmod
    from lowcostdex.sim.effects import Targets

    model = mujoco.MjModel.from_xml_string(sim.model_xml())
    targets = Targets.resolve(model, sim.JOINTS)
    ctx = fitmod.Context(dt=0.002, peak_force=np.array([40.0, 40.0]),
                         damping=model.dof_damping.copy(),
                         **fitmod.servo_facts(model, targets.actuators))
    grip = fitmod.space("coulomb_friction", "frictionloss", 0, ctx)
    assert grip.lo <= 0.0 and grip.hi >= 20.0, (grip.lo, grip.hi)
    assert fitmod.hard_limits("coulomb_friction", "frictionloss", 0, ctx)[1] >= 20.0
    finger = fitmod.space("coulomb_friction", "frictionloss", 1, ctx)
    assert finger.hi <= 5.0


def test_a_rails_force_limit_in_newtons_is_inside_the_search_range():
    """The jaw's servo pushes up to 40 N (its forcerange): a torque_limit on the slide is a
    force in N and must be searchable up to that force, as dry friction's (above). On main
    811d2cc its range and hard limit stopped at the catalogue's 10 (N m, a hinge's): grip_gain's
    fit ran to that cap beside a 40 N forcerange. The finger's hinge keeps its peak (1 N m)."""
    from lowcostdex.gap import fit as fitmod
    from lowcostdex.sim.effects import Targets

    model = mujoco.MjModel.from_xml_string(sim.model_xml())
    targets = Targets.resolve(model, sim.JOINTS)
    ctx = fitmod.Context(dt=0.002, peak_force=np.array([40.0, 1.0]),
                         damping=model.dof_damping.copy(),
                         **fitmod.servo_facts(model, targets.actuators))
    grip = fitmod.space("torque_limit", "torque", 0, ctx)
    assert grip.hi == pytest.approx(40.0) and grip.start == pytest.approx(20.0), grip
    assert fitmod.hard_limits("torque_limit", "torque", 0, ctx)[1] == pytest.approx(40.0)
    finger = fitmod.space("torque_limit", "torque", 1, ctx)
    assert finger.hi == pytest.approx(1.0)
    assert fitmod.hard_limits("torque_limit", "torque", 1, ctx)[1] == pytest.approx(1.0)


def test_a_slides_parameters_are_reported_in_linear_units():
    """A slide's offset is in m, its friction in N, its damping in N s/m: the report said the
    jaw's 2.777 mm mounting offset was "0.002777 rad" and its 7.8 N friction "N m" (5598aed,
    96768eb). Hinge-only causes keep the catalogue's units."""
    from lowcostdex.gap.results import unit_on

    both, grip = np.array([True, False]), np.array([True])
    assert unit_on("rad", sim.JOINTS, both) == "rad (m on grip)"
    assert unit_on("N m", sim.JOINTS, both) == "N m (N on grip)"
    assert unit_on("N m s/rad", ("grip",), grip) == "N s/m"
    assert unit_on("rad/s", ("grip",), grip) == "m/s"
    assert unit_on("1", sim.JOINTS, both) == "1"
    assert unit_on("rad", sim.JOINTS, np.array([False, False])) == "rad"
    assert unit_on("rad", sim.JOINTS, None) == "rad"


def _grip_data(name: str, tmp_path, factor: float = 1.0):
    """Case ``name``'s logs as the analysis reads them (the model's step x ``factor``), its
    episodes and the analysis's split (``GapConfig``'s seed, as ``analyze`` draws it)."""
    from lowcostdex.gap.dataset import episodes, load_dataset, split_episodes
    from lowcostdex.gap.results import GapConfig

    files = sim.write_case(sim.CASE_BY_NAME[name], tmp_path)
    ds = load_dataset(files["logs"], model=files["model"])
    ds = ds.with_timestep(factor) if factor != 1.0 else ds
    cfg = GapConfig(nthread=1)
    eps = episodes(ds, cfg.chunk)
    return ds, eps, split_episodes(ds, eps, np.random.default_rng(cfg.seed), cfg.test_logs), cfg


def test_a_jaw_offset_seen_only_on_the_block_is_significant_on_the_select_split(tmp_path):
    """The jaw's 2.92 mm sensor offset shows only while the jaw presses the block: 2 of the
    select split's 12 blocks of 0.5 s (at the 1 ms step the analysis chose). Round 1 fitted
    offsets of 2.014 mm on the jaw and 2.4e-5 rad on the finger (select gain 55 %); on main
    811d2cc the paired block bound of that gain was -0.17 % (a resample missing both pressing
    blocks, 13 % of them, kept the other blocks' cross terms of a prediction change of <= 0.1
    noise floors, +-3 % of their error) and mounting_offset was not named. A block whose
    predictions the two models keep within 0.375 floors (``significance.RESOLVE``, half the
    default ``min_effect``) is now unchanged: bound > 0.
    The same rule gives a jaw offset of the wrong sign a negative bound and the finger's
    2.4e-5 rad alone (no block moves by a floor) no evidence (0). ~2 s CPU."""
    from lowcostdex.gap import significance as sg
    from lowcostdex.gap.diagnostics import noise_floor
    from lowcostdex.gap.replay import Replayer
    from lowcostdex.sim.effects import AppliedEffect

    ds, eps, split, cfg = _grip_data("grip_offset", tmp_path, 0.5)
    sel = [eps[i] for i in split.select]
    floor = noise_floor(ds.trajectories)
    rep = Replayer(ds, ["mounting_offset"], nthread=1)

    def predict(windows, cols):
        return rep.run(windows, cols)[0]

    def offset(grip):
        return [AppliedEffect("mounting_offset", ds.effect_joints,
                              {"offset": np.array([grip, 2.376e-05])})]

    fitted = offset(0.002014)
    a, b = predict(sel, [[], fitted])
    change = sg.block_change(ds, sel, a, b, cfg.interval_block, floor)
    assert np.sum(change > 100) == 2 and np.sum(change > sg.RESOLVE) == 2, change
    assert sg.RESOLVE == cfg.min_effect / 2   # half the analysis's default size of no change

    def low(new, floors):
        return sg.paired_low(predict, ds, sel, [], new, cfg.interval_block,
                             np.random.default_rng([cfg.seed, 1]), cfg.bootstrap,
                             *((floor, sg.RESOLVE) if floors else ()))

    assert low(fitted, False) < 0.0      # as on 811d2cc: the 55 % gain not bounded above 0
    assert low(fitted, True) > 0.2
    assert low(offset(-0.002014), True) < -1.0
    assert low(offset(0.0), True) == 0.0


def test_a_jaw_gain_that_the_joint_fit_leaves_at_one_is_found_by_a_scan(tmp_path):
    """The jaw's kp x0.546: replayed at the truth's gain the jaw's error falls ~8x, but the
    finger riding on it sticks and slips on the table and its error moves by +-10 % with
    every gain of either joint, so the two-joint Levenberg-Marquardt fit of gain_error rejects
    step after step: from the catalogue's starts (1; 0.5 and 2 on both joints) it stays at
    ~0.99 on the jaw (main 811d2cc; grip_gain named a backlash). ``fit.scan_scales`` scans each
    joint's scale alone over its range and then finer: the jaw's gain lands within 15 % of the
    truth and the jaw's error falls > 3x; the finger's gain stays at 1 +- 3 %. At the model's
    2 ms step (the analysis fits the first round there). ~8 s CPU."""
    import importlib

    from lowcostdex.gap import fit as fitmod
    from lowcostdex.gap import play_side
    from lowcostdex.sim.effects import Targets

    an = importlib.import_module("lowcostdex.gap.analyze")
    ds, eps, split, cfg = _grip_data("grip_gain", tmp_path)
    train = [eps[i] for i in split.train]
    eng = an._Engine(ds, cfg, ["gain_error"])
    m0 = eng.rep.models[ds.trajectories[0].model]
    targets = Targets.resolve(m0, eng.joints)
    ctx = fitmod.Context(dt=ds.timestep, peak_force=np.array([40.0, 1.0]),
                         damping=m0.dof_damping[targets.dofs].copy(),
                         **fitmod.servo_facts(m0, targets.actuators))
    fn = eng.residual_fn(train)
    tracks = play_side.tracks("gain_error", eng.joints, ctx)
    fitmod.lockstep_lm(tracks, fn, cfg.max_rounds, prune=fitmod.prune_tracks,
                       jacobian_at_end=False)
    best = min(tracks, key=lambda t: t.cost)

    def jaw_rms(x):
        r = fn([(best.structure, x)])[0].reshape(-1, 2)
        return float(np.sqrt(np.mean(r[:, 0] ** 2)))

    before = best.x.copy()
    assert before[0] > 0.9, before   # the stall
    assert fitmod.scan_scales(best, fn)
    fitmod.lockstep_lm([best], fn, cfg.max_rounds // 2, jacobian_at_end=False)
    assert best.x[0] == pytest.approx(sim.MAG["grip_gain"], rel=0.15), best.x
    assert best.x[1] == pytest.approx(1.0, abs=0.03), best.x
    assert jaw_rms(best.x) < jaw_rms(before) / 3


def test_the_verdict_says_each_joint_in_its_own_unit_where_a_slide_meets_a_hinge():
    """The verdict's held-out RMSE pools the joints' errors: on the gripper metres with
    radians. gap-sim15's grip_gain read "held-out RMSE 0.001187 -> 0.001106 rad" and "left:
    1.11 mrad" (811d2cc) for a jaw and a finger in different units. Where units mix the pooled
    figures now say they pool m and rad, and each joint follows in its own unit (mm / mrad,
    with its noise floor); a hinge-only rig's verdict is as it was."""
    from lowcostdex.gap.gain import Gain
    from lowcostdex.gap.results import Cause
    from lowcostdex.gap.standin import judge, per_joint_text

    before = {"per_joint_rmse": {"grip": 1.4e-3, "finger": 1.69e-3}}
    after = {"per_joint_rmse": {"grip": 1.8e-4, "finger": 1.55e-3}}
    floor = np.array([1.03e-5, 5.5e-4])
    text = per_joint_text(sim.JOINTS, np.array([True, False]), before, after, sim.JOINTS, floor)
    assert text == ("per joint, in each joint's unit (the pooled figures add m to rad): grip "
                    "1.4 -> 0.18 mm (noise floor 0.01 mm), finger 1.69 -> 1.55 mrad (noise floor "
                    "0.55 mrad)")
    assert per_joint_text(sim.JOINTS, np.array([False, False]), before, after, sim.JOINTS,
                          floor) == ""
    assert per_joint_text(sim.JOINTS, None, before, after, sim.JOINTS, floor) == ""
    gain = Gain(1.55e-3, 1.1e-3, 1e-3, 8e-4, 4.5e-4, 0.29, (2e-4, 6e-4), (0.13, 0.39), 3.9e-4,
                None, 2)
    causes = [Cause("gain_error", sim.JOINTS, {})]
    mixed = judge(causes, None, gain, "x", per_joint=text)
    assert mixed.startswith("gain_error: held-out RMSE 0.00155 -> 0.0011 rad and m pooled "
                            "(29 % lower); left: 1.1 mrad and mm pooled held-out RMSE")
    assert mixed.endswith("; " + text)
    hinge = judge(causes, None, gain, "x")
    assert hinge.startswith("gain_error: held-out RMSE 0.00155 -> 0.0011 rad (29 % lower); "
                            "left: 1.1 mrad held-out RMSE") and "pooled" not in hinge
