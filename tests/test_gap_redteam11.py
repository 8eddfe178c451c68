"""The gap analysis judged on an eleventh independently written truth simulator: a user's
pan-tilt camera head on two servos in VELOCITY mode under the user's own 100 Hz python position
loop, logged in degrees and integer ms, failed reads' rows absent, a logger pause (issue 11;
gap-sim13, session 26; bench/RESULTS.md "gap-sim13").

``tests/gap_truth_sim11.py`` (mujoco + numpy only) writes the cases; each is analysed as the CLI
does (the user's MJCF, the log folder, ``--units deg --time-unit ms``) and graded by
``redteam_check.assert_named_exactly``: the named causes exactly the hidden ones (nothing on a
clean case), every documented parameter inside its 95 % interval. Misses are strict xfails
whose reason is the measured result (bench/gap_redteam11.py on the commit named there); they
fail (XPASS) when fixed and must then lose their mark.

The default run checks the truth's physics against numbers written out by hand (each check
fails if its effect were wrong or absent), the logs' spelling, that such logs are read at all
(they were refused on a78784e) and one clean case end to end.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import sys

import mujoco
import numpy as np
import pytest

from lowcostdex.gap.dataset import load_dataset

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import gap_truth_sim11 as sim  # noqa: E402
import redteam_check  # noqa: E402

# in the default run: the clean case's analysis (2.6 s CPU measured; it stops at "no significant
# discrepancy"); the rest are slow
FAST = frozenset({"clean_pantilt"})

# what the analysis named instead, per case it misses (bench/gap_redteam11.py --threads 1 on
# 89b2d65 + the replay fix of ab2d25b, session 26; CPU: the analysis's user + sys). Named
# exactly: friction_pan (0.2508 N m [0.2479, 0.2528], 11 s), speed_pan (1.999 rad/s [1.997,
# 2.002], 61 s), gain_tilt (2.509 [2.497, 2.521], 61 s), offset_gain_tilt (-0.1201 rad
# [-0.1308, -0.1131] and 0.4992 [0.495, 0.5026], 33 s); clean: clean_pantilt (3 s),
# clean_pantilt_long (8 s). Since gap-sim14 (session 27, gates.settle_untold: a scalar on a
# bound that the data do not need is held at its null) also mass_tilt (2.0015 [1.994, 2.010]
# for 2, 233 -> 1.21 mrad, 35 s; it was a mounting_offset stand-in, mass_error rejected at a
# bound by its pan scale) and offset_tilt (0.1523 [0.1236, 0.1739] for 0.15, 16.19 -> 1.00
# mrad, 33 s; it was extra: a velocity_limit beside it, 108 s).
MISSES: dict[str, str] = {
    "latency50": "extra, on ab2d25b: latency 45.6 / 43.8 ms (the tilt's interval [36.1, 47.1] "
    "misses 50) + inertia_error 1.53 / 1.90 + backlash 12.5 / 7.9 mrad (kept by the backward "
    "search); 27.6 -> 1.71 mrad (3.4 floors), 204 s CPU. The true 50 ms replays the 1 s windows "
    "at 2.7 / 1.8 mrad, ~1 in all but the two that start in motion (a log begun mid-move, the "
    "piece after the logger pause: 4.8 / 6.7 mrad, the commands in flight there are not logged) "
    "and the fit trades delay for inertia there. (On 89b2d65: inertia_error 7.9 / 7.8 alone.) "
    "Re-measured on 811d2cc (gap-sweep23, session 28): identical (45.6 / 43.8 ms, inertia 1.53 / "
    "1.90, backlash 12.5 / 7.9 mrad, 27.63 -> 1.71 mrad), 388 s CPU",
    "backlash_pan": "gain_error 0.94 / 1.007 named, flagged 'no reliable gain ... at best a "
    "partial stand-in' (9.45 -> 9.77 mrad, 18 floors; 32 s CPU on ab2d25b); backlash not among "
    "the six fitted. The truth's loop read across the play HUNTS at every hold (a limit cycle, "
    "14.6 mrad row to row). Measured by gap-sim14 (session 27): our plant's play hunts as the "
    "truth's does (closed around the host's 100 Hz loop in plain MuJoCo with Backlash.command's "
    "law: 15.7 / 13.9 / 14.6 mrad row to row at 2 / 0.5 / 0.25 ms; with the play ANGLE term of "
    "a velocity actuator dropped 16.1 / 13.8 / 13.3: that term is not the miss), and open loop "
    "from the logged commands the true play (sensor 1, hinge) gives the logs' spread (row to row "
    "23.3 mrad per 1 s segment, logs 22.9, nominal 18.2) but not its phase: pan RMSE 21.5 vs "
    "the nominal 20.1 mrad (whole episodes 24.4 vs 18.9). The replay then keeps the massless "
    "play operator (19.7: closer to the data), where the sensor does nothing (0 and 1 replay "
    "alike). An open-loop RMSE ranks a limit cycle below none: naming it needs a phase-free "
    "score (e.g. the holds' row-to-row spread). Re-measured on 811d2cc (gap-sweep23): identical "
    "(gain_error 0.944 / 1.007, 9.45 -> 9.77 mrad), 54 s CPU; bench/gap_phase_free.py: the "
    "hunting amplitude ranks the hinge play first (1.27 vs nominal 3.89 mrad) but a 20 mrad "
    "play alone beats the truth on latency_backlash",
    "latency_backlash": "torque_limit 0.54 / 0.78 N m named (42.0 -> 41.2 mrad, 82 floors; 71 s "
    "CPU): latency fitted 27.9 / 30.8 ms (truth 30) but its select gain 0.12 is not "
    "significant beside the pan's hunting play (see backlash_pan). On 811d2cc (gap-sweep23, "
    "session 28) BETTER but still a miss: latency alone named, 24.1 / 31.1 ms (both intervals "
    "hold 30: pan [4.8, 41.3], tilt [26.2, 33.9]), 39.06 -> 13.52 mrad (27.8 floors left, "
    "'something beyond the named causes'), the play not named; 118 s CPU",
    "armature_pan": "extra: inertia_error on the pan 2.955 [2.659, 3.009] (truth 3) AND "
    "velocity_limit 6.1 / 4.9 rad/s (9.94 -> 1.32 mrad, 103 s CPU)",
    "friction_pan_mass_tilt": "coulomb_friction on the pan 0.2501 [0.2464, 0.2540] (truth 0.25) "
    "+ mounting_offset -0.307 on the tilt for the 2x camera (457 -> 25.9 mrad, 51 floors; 86 s "
    "CPU; the same on 54cec05, 92 s): mass_error was never fitted (screened 0.64 in round 1, below the six fitted; gain_error, "
    "coulomb_friction, viscous_damping accepted, max_effects reached); the backward search "
    "from all seven kept the offset, and gain_error and viscous_damping were dropped on their "
    "intervals",
}

G = 9.81
E, C = sim.Effect, sim.Case


@pytest.mark.parametrize("name", redteam_check.case_params(sim, FAST, MISSES))
def test_names_exactly_the_hidden_causes_with_intervals_holding_the_truth(name, tmp_path):
    redteam_check.assert_named_exactly(sim, name, tmp_path)


def test_truth_simulator_imports_nothing_from_the_project():
    names = redteam_check.imported_top_modules(HERE / "gap_truth_sim11.py")
    assert names <= {"__future__", "dataclasses", "json", "math", "pathlib", "mujoco",
                     "numpy", "redteam_grade"}, names


def test_the_servos_velocity_loop_and_torque_speed_line_by_hand():
    """tau = kv gain (u - w) clipped to 1.5 N m; with a no-load speed s the torque along the
    motion is at most 1.5 (1 - |w| / s), against it 1.5."""
    assert sim.firmware_torque(1.0, 0.4) == pytest.approx(0.5 * 0.6)
    assert sim.firmware_torque(1.0, 0.4, gain=2.5) == pytest.approx(2.5 * 0.5 * 0.6)
    assert sim.firmware_torque(9.0, 0.0) == pytest.approx(1.5)
    assert sim.firmware_torque(-9.0, 0.0) == pytest.approx(-1.5)
    assert sim.firmware_torque(4.0, 1.0, speed=2.0) == pytest.approx(0.75)   # along: 1.5 x 0.5
    assert sim.firmware_torque(-9.0, 1.0, speed=2.0) == pytest.approx(-1.5)  # against: full
    assert sim.firmware_torque(-4.0, -1.5, speed=2.0) == pytest.approx(-0.375)
    assert sim.firmware_torque(4.0, 2.5, speed=2.0) == pytest.approx(0.0)


def _run(effects: tuple, target: dict, seconds: float, drop: float = 0.0) -> tuple:
    t = np.arange(-sim.SETTLE, seconds, 0.01)
    out = sim.simulate(C("check", effects), t, {j: target[j](t) for j in sim.JOINTS},
                       np.random.default_rng(1), drop=drop, true_angles=True)
    return t, out


def test_the_tilt_held_against_gravity_written_out():
    """Held at 0.3 rad, the camera (250 g, 60 mm ahead of the axis; gravity torque m g x cos q,
    pulling toward +q) sags until the servo's loop answers it: kv gain u = -m g x cos q with
    the host's u = KP_HOST (target - reading), so reading - target = m g x cos q / (kv gain
    KP_HOST): 35.1 mrad; 14.1 with the loop gain 2.5x; 70.3 with the camera 2x. Measured 34.8,
    13.9, 67.6 mrad (the model's 0.02 N m of dry friction leaves a band of 0.02 / (kv gain
    KP_HOST) = 5 mrad / gain). A reading offset of 0.15 rad: the joint's true angle is the
    reading less 0.15, and gravity acts at it (36.4 mrad predicted, 36.2 measured)."""
    hold = {"pan": lambda t: 0.0 * t, "tilt": lambda t: 0.0 * t + 0.3}
    for effects, mass, gain, offset in (((), 1.0, 1.0, 0.0),
                                        ((E("gain", 2.5, "tilt"),), 1.0, 2.5, 0.0),
                                        ((E("mass", 2.0, "tilt"),), 2.0, 1.0, 0.0),
                                        ((E("offset", 0.15, "tilt"),), 1.0, 1.0, 0.15)):
        t, out = _run(effects, hold, 2.5)
        late = t > 1.5
        read = float(np.mean(out["qpos:tilt"][late]))
        q = read - offset
        sag = mass * sim.CAM_MASS * G * sim.CAM_X * math.cos(q) / (sim.KV * gain * sim.KP_HOST)
        band = sim.FRICTION / (sim.KV * gain * sim.KP_HOST)
        assert abs(read - 0.3 - sag) < band + 0.001, (effects, read - 0.3, sag)
        assert np.mean(out["true:tilt"][late]) == pytest.approx(q, abs=0.0015), effects


def test_the_pan_speed_latency_friction_and_play_written_out():
    """A pan step of 2.4 rad (the host asks VMAX = 4 rad/s): the servo's speed settles where
    kv (4 - w) = damping w + friction, w = (2 - 0.02) / 0.55 = 3.60 rad/s; with a no-load speed
    of 2 rad/s where 1.5 (1 - w / 2) = 0.05 w + 0.02, w = 1.48 / 0.8 = 1.85 rad/s. A latency of
    50 ms moves the first motion after the step 50 ms later. Dry friction of +0.25 N m stops
    the pan where the host's command no longer breaks it away: |error| < 0.27 / (kv KP_HOST) =
    67.5 mrad (measured 54-58 mrad after three steps; 4.5-5.5 without). A 40 mrad play: the
    output moves 40 mrad against the gear across the reversals (41.8 measured: the gear
    contact's compliance at the stall torque), and where the host holds the pan the loop read
    across the play hunts: the output swings inside the play (row-to-row steps of 14.6 mrad
    RMS measured; 0.8-0.9 without a play, the read noise)."""
    step = {"pan": lambda t: np.where(t < 0.2, -1.2, 1.2), "tilt": lambda t: 0.0 * t}
    first = {}
    for effects, speed in (((), 3.60), ((E("speed", 2.0, "pan"),), 1.85),
                           ((E("latency", 0.05),), 3.60)):
        t, out = _run(effects, step, 1.5)
        w = np.diff(out["true:pan"]) / 0.01
        assert w.max() == pytest.approx(speed, abs=0.05), effects
        moved = (t > 0.2) & (np.abs(out["qpos:pan"] + 1.2) > 3 * sim.TICK)
        first[effects] = float(t[np.argmax(moved)])
    late = first[(E("latency", 0.05),)] - first[()]
    assert late == pytest.approx(0.05, abs=0.011)
    steps = {"pan": lambda t: np.select([t < 0.5, t < 1.5, t < 2.5], [0.0, 0.5, -0.3], 0.2),
             "tilt": lambda t: 0.0 * t}
    ends = np.array([1.45, 2.45, 3.35])
    for effects, lo, hi in (((), 0.0, 0.008), ((E("friction", 0.25, "pan"),), 0.04, 0.068)):
        t, out = _run(effects, steps, 3.4)
        k = np.searchsorted(t, ends)
        err = np.abs(out["qpos:pan"][k] - steps["pan"](t[k]))
        assert np.all((err >= lo) & (err <= hi)), (effects, err)
        assert np.ptp(out["true:pan"] - out["rotor:pan"]) == 0.0
        held = (t > 3.0) & (t < 3.4)   # row-to-row motion: read noise and a slow creep
        assert np.std(np.diff(out["qpos:pan"][held])) < 0.0015, effects
    t, out = _run((E("backlash", 0.04, "pan"),), steps, 3.4)
    assert 0.040 <= np.ptp(out["true:pan"] - out["rotor:pan"]) <= 0.043
    # the loop read across the play hunts: the held output swings inside it
    assert np.std(np.diff(out["qpos:pan"][(t > 3.0) & (t < 3.4)])) > 0.005


def test_the_inertias_by_hand():
    """The joint-space inertia at rest, tilt level: pan = armature 0.004 + yoke 1e-5 + camera
    (its own 250 g (0.09^2 + 0.06^2) / 12 = 2.44e-4 about the vertical, and m x^2 = 9e-4):
    5.154e-3 kg m^2; tilt = 0.004 + 2.44e-4 + 9e-4 = 5.144e-3. The pan's rotor 3x: 1.3154e-2;
    the camera 2x: both 2.288e-3 above the armature (+1e-5 on the pan)."""
    cam = sim.CAM_MASS * ((0.09 ** 2 + 0.06 ** 2) / 12 + sim.CAM_X ** 2)
    for effects, pan, tilt in (((), 0.004 + 1e-5 + cam, 0.004 + cam),
                               ((E("armature", 3.0, "pan"),), 0.012 + 1e-5 + cam, 0.004 + cam),
                               ((E("mass", 2.0, "tilt"),), 0.004 + 1e-5 + 2 * cam,
                                0.004 + 2 * cam)):
        m = mujoco.MjModel.from_xml_string(sim.model_xml(C("check", effects), sim.TRUTH_DT))
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)
        assert np.diag(full) == pytest.approx([pan, tilt], rel=1e-3), effects


def test_the_logs_as_the_user_writes_them(tmp_path):
    """Integer ms stamps of a clock far from 0, angles in degrees and velocity goals in deg/s
    (the host's 4 rad/s = 229 deg/s), no velocity column, about 2 % of the rows absent (failed
    reads), the second log's logger pause of 1.2 s; the user's model has velocity actuators."""
    case = dataclasses.replace(sim.CASE_BY_NAME["clean_pantilt"], durations=(4.0, 4.0))
    files = sim.write_case(case, tmp_path)
    assert files["args"] == ["--units", "deg", "--time-unit", "ms"]
    m = mujoco.MjModel.from_xml_string(pathlib.Path(files["model"]).read_text())
    assert all(m.actuator_biasprm[i, 2] == -sim.KV for i in range(m.nu))
    fastest = 0.0
    for i in range(2):
        path = tmp_path / "logs" / f"log{i}.csv"
        head = path.read_text().splitlines()[0]
        assert head == "time,goal:pan,goal:tilt,qpos:pan,qpos:tilt"
        a = np.loadtxt(path, delimiter=",", skiprows=1)
        assert np.all(a[:, 0] == np.round(a[:, 0])) and a[0, 0] > 4e6
        gaps = np.diff(a[:, 0])
        assert 0.005 < np.mean(gaps > 15) < 0.06   # rows of failed reads absent
        assert (gaps.max() > 1200) == (i == 1)    # the pause
        fastest = max(fastest, np.abs(a[:, 1:3]).max())
        assert np.abs(a[:, 3:5]).max() > 30          # deg
    assert 150 < fastest < 230   # deg/s


def test_velocity_mode_logs_are_read(tmp_path):
    """Such logs were refused on a78784e ('qpos:tilt' frozen 0.042 s while 'goal:tilt' moves
    over [-2.21, -0.264] "rad"): the stuck-encoder check compared a velocity command with the
    reading; a joint at rest reads one tick for the 50 ms its new command takes to arrive.
    Now the goal-against-reading checks skip actuators whose goal is not a position."""
    case = dataclasses.replace(sim.CASE_BY_NAME["latency50"], durations=(6.0,))
    files = sim.write_case(case, tmp_path)
    ds = load_dataset(files["logs"], model=files["model"], angle_unit="deg", time_unit="ms")
    assert len(ds.trajectories) >= 1


def test_a_delayed_velocity_goal_starts_from_the_command_that_held_the_joint(tmp_path):
    """Replayed with its true 50 ms latency, a velocity-mode log's first goal arrives 50 ms in;
    until then the servo runs on the command the host wrote before the log: the one that held
    the first reading (gravity over kv, plus the first speed). On a78784e the replay took the
    measured POSITION as that command (rad as rad/s): the pan of a log starting at rest ran
    33 mrad RMS off over its first 0.2 s, the log starting in motion 137 mrad over its whole
    3 s; measured now 0.5 and 15 mrad (the nominal model without the latency: 58, 132)."""
    from lowcostdex.gap.dataset import episodes
    from lowcostdex.gap.replay import Replayer
    from lowcostdex.sim.effects import AppliedEffect

    case = dataclasses.replace(sim.CASE_BY_NAME["latency50"], durations=(3.0, 3.0))
    files = sim.write_case(case, tmp_path)
    ds = load_dataset(files["logs"], model=files["model"], angle_unit="deg", time_unit="ms")
    eps = [w for w in episodes(ds) if w.start == 0][:2]
    assert [w.traj for w in eps] == [0, 1]
    lat = [AppliedEffect("latency", sim.JOINTS, {"delay": np.array([0.05, 0.05])})]
    (pred,), _ = Replayer(ds, ["latency"]).run(eps, [lat])
    err = [ds.trajectories[w.traj].qpos[w.start:w.stop] - p
           for w, p in zip(eps, pred, strict=True)]
    assert np.sqrt(np.mean(err[0][:20] ** 2)) < 0.002     # at rest: the floor
    assert np.sqrt(np.mean(err[1] ** 2)) < 0.025          # in motion: the speed carried
