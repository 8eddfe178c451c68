"""The gap analysis judged on a fifth independently written truth simulator: plants and logs as
users bring them (issue 11 items 2 and 4; gap-judge11, session 16; table in bench/RESULTS.md).

``tests/gap_truth_sim5.py`` (mujoco + numpy only) writes a two-link arm whose MJCF already sets
armature and frictionloss (the truth has more), a finger with an unactuated joint on a passive
tendon spring and a pendulum; effects at real-world sizes and in pairs; logs in degrees, with
integer-ms or integer-us stamps, at 30-1000 Hz, columns in a user's order, rows dropped or
written twice. Each case is analysed as the CLI does, with the options a user passes for that
spelling (``--units deg``, ``--time-unit ms``), and scored by ``gap_truth_sim2.score`` (the
contract of ``tests/test_gap_redteam.py``): the named causes exactly the hidden ones (nothing on
a clean case), every documented parameter inside its 95 % interval. Misses are strict xfails
whose reason is the measured result (bench/gap_redteam5.py on the commit named there); they
fail (XPASS) when fixed and must then lose their mark.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

from lowcostdex.cli import main

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import gap_truth_sim5 as sim  # noqa: E402
import redteam_check  # noqa: E402

FAST: tuple[str, ...] = ()

# what the analysis named instead, per case it misses (bench/gap_redteam5.py --threads 1).
# backlash2deg_pendulum_500hz_us was a miss on 5329124 and 7e2206f (backlash chosen in round 1,
# width 0.0299 for 0.0349 rad, then dropped: the width scan's valley took its interval to
# [-0.003, 0.040]); since gap-drop12's gates.profile_shown (b163bbd) exact on main 8d3a53b (lead,
# session 17, 367 s CPU: kept, its removal costs 78.5 x the data's threshold; held-out
# 6.75 -> 1.89 mrad); since gap-play13's local valley (session 18, main 675e7cd + it, 378 s CPU) its
# interval is [0.0097, 0.0388], away from no play on its own (no longer kept by the null profile).
MISSES: dict[str, str] = {}


@pytest.mark.parametrize("name", redteam_check.case_params(sim, FAST, MISSES))
def test_names_exactly_the_hidden_causes_with_intervals_holding_the_truth(name, tmp_path):
    redteam_check.assert_named_exactly(sim, name, tmp_path)


def test_truth_simulator_imports_nothing_from_the_project():
    names = redteam_check.imported_top_modules(HERE / "gap_truth_sim5.py")
    assert names <= {"__future__", "dataclasses", "json", "math", "pathlib", "mujoco", "numpy",
                     "gap_truth_sim2"}, names


def test_every_hidden_effect_is_plain_and_clean_logs_replay_near_the_read_floor():
    """The user's nominal model replayed open loop in plain mujoco (2 ms): the clean arm stays
    within a few mrad RMS per joint (the 0.25 ms truth step, the model's soft frictionloss, the
    reads' ticks), every hidden effect moves its joint's logs well above that (measured: clean
    2.3 / 3.2 mrad; the smallest effect, 2 deg of backlash, 6.7 mrad)."""
    for case in sim.CASES:
        rms = sim.effect_size(case)["rms"]
        if case.effects:
            assert max(rms) > 0.006, (case.name, rms)
        else:
            assert max(rms) < 0.004, (case.name, rms)


def _twin(case: sim.Case) -> sim.Case:
    """``case`` written in the project's own spelling (rad, seconds from 0, project column
    order, no rows dropped or doubled): the same draws, the same truth."""
    import dataclasses

    return dataclasses.replace(case, angles="rad", stamps="s", order="project", dropped=0.0,
                               doubled=0.0)


def _load(files, args=()):
    from lowcostdex.gap.dataset import load_dataset

    kw = dict(zip(args[::2], args[1::2], strict=True))
    return load_dataset(files["logs"], model=files["model"],
                        angle_unit=kw.get("--units", "rad"),
                        time_unit=kw.get("--time-unit", "s"))


@pytest.mark.parametrize("name", ["clean_arm2_deg_ms", "backlash2deg_pendulum_500hz_us",
                                  "latency040_gain18_pendulum_30hz", "coulomb_more_arm2"])
def test_a_users_log_spelling_reads_as_the_project_spelling_of_the_same_truth(name, tmp_path):
    """Degrees with ``--units deg``, millis() / micros() stamps with ``--time-unit``, a user's
    column order, rows written twice: read into the trajectories of the same truth written in
    rad and seconds, to the spelling's rounding (a stamp floored to 1 ms / 1 us after a clock
    offset; 9 printed digits of a degree); rows dropped mid-log split the log there."""
    case = sim.CASE_BY_NAME[name]
    files = sim.write_case(case, tmp_path / "user")
    plain = sim.write_case(_twin(case), tmp_path / "plain")
    assert files["args"] == list(case.args)
    got, want = _load(files, files["args"]), _load(plain)
    assert sorted(got.joints) == sorted(want.joints)   # in the order of the log's columns
    w = want.trajectories
    clock = {"ms": 731.2, "us": 58_211.0}.get(case.stamps, 0.0)
    res = {"ms": 1e-3, "us": 1e-6}.get(case.stamps, 1e-9)
    n_pieces = len(got.trajectories)
    assert n_pieces == len(w) * (2 if case.dropped else 1)
    for i, tr in enumerate(w):
        pieces = got.trajectories[2 * i: 2 * i + 2] if case.dropped else [got.trajectories[i]]
        t = np.concatenate([p.time for p in pieces]) - clock
        rows = np.searchsorted(tr.time, t - res)   # each read row in the plain log
        np.testing.assert_allclose(t, tr.time[rows], rtol=0, atol=res + 1e-9)
        for f, names, mine in (("goal", "actuators", tr.actuators), ("qpos", "joints", tr.joints),
                               ("qvel", "joints", tr.joints)):
            cols = [getattr(pieces[0], names).index(x) for x in mine]
            a = np.concatenate([getattr(p, f)[:, cols] for p in pieces])
            np.testing.assert_allclose(a, getattr(tr, f)[rows], rtol=1e-8, atol=1e-8,
                                       err_msg=f)
        if case.dropped:
            gap = pieces[1].time[0] - pieces[0].time[-1]
            assert case.dropped <= gap < case.dropped + 3 / case.rate


def test_integer_stamps_without_the_option_are_refused_naming_it(tmp_path, capsys):
    """A millis() log read as seconds: refused with the unit's hint and the option that reads
    it as written (exit 2, no traceback)."""
    case = sim.CASE_BY_NAME["latency040_gain18_pendulum_30hz"]
    files = sim.write_case(case, tmp_path / "data")
    code = main(["gap", "analyze", "--model", files["model"], "--log", *files["logs"],
                 "--out", str(tmp_path / "report")])
    err = capsys.readouterr().err
    assert code == 2
    assert "median step is 33: ms?" in err and "or pass --time-unit ms" in err, err
    assert "Traceback" not in err and not (tmp_path / "report").exists()


def test_backlash_plays_on_the_output_and_the_tendon_carries_the_distal_joint():
    """The truth's structures do what they claim: on the backlash pendulum the firmware's PD
    closes on the output, so where the goal stands still the reading settles on its goal less
    gravity's steady droop kept by kp (m g l sin q / kp, written out) within a few ticks (the
    play hidden at rest, gravity holding the link on one side), while in motion it departs from
    the same pendulum without play by more than the read floor (the play crossed at every
    reversal); on the finger the unactuated dip follows the pip: its angle correlates with the
    pip's (the tendon spring pulls pip - dip to 0) and spans at least half the pip's range."""
    case = sim.CASE_BY_NAME["backlash2deg_pendulum_500hz_us"]
    qs = []
    for c in (case, sim.Case("no_play", "pendulum")):
        rng = np.random.default_rng(0)
        t = sim.row_times(4.0, 500.0, 0.1, rng)
        target = {"hinge": sim.targets("steps", "hinge", t, np.random.default_rng(5))}
        out = sim.simulate(c, t, target, rng)
        qs.append(out["qpos:hinge"])
        g = out["goal:hinge_servo"]
    q = qs[0]
    _, length, rod, tip, _, _, _, (kp, _, _) = sim.RIGS["pendulum"]["joints"]["hinge"][1:]
    mgl = 9.81 * (rod * length / 2 + tip * length)
    held = np.flatnonzero(np.r_[np.zeros(400, bool), g[400:] == g[:-400]])  # 0.8 s unchanged
    assert len(held) > 100
    err = g[held] - mgl * np.sin(q[held]) / kp - q[held]
    assert np.abs(err).max() <= 6 * sim.TICK, np.abs(err).max()
    moving = np.setdiff1d(np.arange(len(q)), held)
    assert np.sqrt(np.mean((q - qs[1])[moving] ** 2)) > 0.005
    fcase = sim.CASE_BY_NAME["gain06_finger_tendon_50hz"]
    rng = np.random.default_rng(1)
    t = sim.row_times(8.0, 50.0, 0.1, rng)
    out = sim.simulate(fcase, t, {"pip": sim.targets("sine", "pip", t, rng)}, rng)
    pip, dip = out["qpos:pip"], out["qpos:dip"]
    assert np.corrcoef(pip, dip)[0, 1] > 0.8
    assert np.ptp(dip) > 0.5 * np.ptp(pip)
