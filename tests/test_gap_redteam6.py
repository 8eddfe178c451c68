"""The gap analysis judged on a sixth independently written truth simulator: an Allegro-class
4-joint finger driven by host-PD torques at 333 Hz or by position servos, effects no earlier set
has (read delay, supply-voltage sag, thermal derating) and effects outside any catalogue (issue
11 item 4; gap-sim6, session 18; table in bench/RESULTS.md, "gap-sim6").

``tests/gap_truth_sim6.py`` (mujoco + numpy only) writes the cases; each is analysed as the CLI
does and scored by ``gap_truth_sim6.score``: a catalogue effect named exactly (nothing on a clean
case), every documented parameter inside its 95 % interval; for an effect outside the catalogue
nothing named, or what is named lowering the held-out error with its interval above 0. Misses
are strict xfails whose reason is the measured result (bench/gap_redteam6.py on the commit
named there); they fail (XPASS) when fixed and must then lose their mark.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import sys

import numpy as np
import pytest

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import gap_truth_sim6 as sim  # noqa: E402
import redteam_check  # noqa: E402

FAST: frozenset[str] = frozenset()

# what the analysis named instead, per case it misses (bench/gap_redteam6.py --threads 1).
# Measured on 1848272 + sim6 (session 18): clean_torque_333hz clean (288 s CPU);
# series_elastic_mcp_position pass (position_offset on mcp, -3.0 mrad, held-out 2.53 -> 2.07 mrad,
# 633 s CPU). read_delay_9ms_torque (a miss in session 18: a chaotic select episode outweighed
# the rest) exact since gap.chaos (session 19, lead): latency 8.6-10.0 ms, every interval holding
# 9 ms, held-out 32.96 -> 8.30 mrad, 321 s CPU. On main 34ab122 (session 19, lead):
# clean_torque_333hz clean again (held-out 1.98 mrad, analysed at 1 ms; 956 s CPU),
# clean_position_100hz clean (held-out 0.83 mrad, floor 0.59, analysed at 0.25 ms; 130 s CPU).
# com_offset_torque pass (position_offset on pip/dip -93/-98 mrad + mass_error as stand-ins, held-out
# 40.1 -> 1.86 mrad, gain CI [24.9, 49.8]; 810 s CPU).
# Since af3c435 (gap.standin, session 20) its verdict says the offsets "may stand in for a
# centre-of-mass shift, link geometry or a tilted base: check before re-zeroing" (pip/dip share
# 73/87 % of their information with mass_error; decision step replayed on the saved report).
# encoder_sine_torque pass on 3bd40a3 (session 20, gap-judge15; 1333 s CPU): position_offset as
# its stand-in (abd/mcp 2.9/4.0 mrad, pip/dip intervals holding 0), held-out 3.54 -> 2.19 mrad,
# gain CI [0.78, 2.06] mrad (no mass effect beside it: no stand-in note).
# voltage_sag_torque exact on b1a5c7c (session 20, gap-exo15: exogenous effects on every actuator
# kind): voltage_sag weight 1.026-1.037 on the four joints for 1 (the drive scales with V/V0),
# every 95 % interval holding 1, held-out RMSE 54.8 -> 3.02 mrad (floor 0.44), 721 s CPU.
# thermal_position exact on b1a5c7c (gap-exo15): thermal_derating alone, tempcoef 0.00486-0.00500
# for the truth's linear 0.004 (1 - a dT; the catalogue's 1 / (1 + a dT) matches it at a = 0.0042-0.005
# over 35-75 deg C: 3 of 4 intervals miss 0.004, unscored), held-out 5.97 -> 0.744 mrad (floor 0.55),
# 732 s CPU.
MISSES: dict[str, str] = {
    "deadband_torque": "main 34ab122, 488 s CPU: gain_error named as the deadband's stand-in "
    "(scale 0.59-0.82), held-out 485 -> 168 mrad but the gain's 95 % interval [-49.6, 603] mrad "
    "holds 0 (the report says 'no reliable gain ... not recommended'): the case's rule needs the "
    "interval above 0 or nothing named. Since session 21 (gap-dead16) the catalogue has "
    "deadband and the case is scored as it: deadband named alone, width 0.01 N m inside its "
    "intervals; deadband is opt-in (effects.OPT_IN), and offered by default the analysis was "
    "stopped at 2583 s CPU in its backward search (70a79fd snapshot, no report). Since "
    "gap-sig19 (session 24) the moves' gate offers it by default: main f1661d0 + this test, "
    "2359 s CPU: deadband named ALONE, widths 0.01004 / 0.00996 / 0.00998 / 0.01000 N m for "
    "0.01, held-out 486 -> 1.24 mrad (floor 0.44), but pip's interval [0.009931, 0.009994] "
    "misses 0.01 by 6e-6 (abd, mcp, dip hold it)",
}


@pytest.mark.parametrize("name", redteam_check.case_params(sim, FAST, MISSES))
def test_names_exactly_the_hidden_causes_with_intervals_holding_the_truth(name, tmp_path):
    redteam_check.assert_named_exactly(sim, name, tmp_path)


def test_the_deadband_is_offered_on_the_torque_rig_with_a_band_and_on_no_other(tmp_path):
    """The deadband's gate (``gap.offer.band_shown``) on sim6's torque rig: its rests all lean
    one way under load (a band there is a reading offset to the statics), so only the moves
    show it (``gap.band_motion``: a force lost on the command's side, measured 56-134 standard
    errors on the four joints, the fitted band 0.0093-0.0100 N m for 0.01); the clean rig,
    its 9 ms read delay and its supply sag (a force lost with the command's size) are not
    offered it (measured |z| <= 1.6, 5.2, 13.9 against a band)."""
    from lowcostdex.gap import band_motion, offer
    from lowcostdex.gap.dataset import load_dataset

    for name, shown in (("deadband_torque", True), ("clean_torque_333hz", False),
                        ("read_delay_9ms_torque", False), ("voltage_sag_torque", False)):
        files = sim.write_case(sim.CASE_BY_NAME[name], tmp_path / name)
        ds = load_dataset(files["logs"], model=files["model"])
        assert offer.offered(ds, "deadband") == shown, (name, band_motion.motion_band_scores(ds))


def test_truth_simulator_imports_nothing_from_the_project():
    names = redteam_check.imported_top_modules(HERE / "gap_truth_sim6.py")
    # redteam_grade: the sets' one grader (tests/, imports nothing from lowcostdex)
    assert names <= {"__future__", "dataclasses", "json", "math", "pathlib", "tempfile",
                     "mujoco", "numpy", "redteam_grade"}, names


def test_clean_logs_replay_at_the_read_floor_and_every_effect_shows():
    """The user's nominal model replayed open loop in plain mujoco at the truth's 0.25 ms step
    (so that goals switch at the rows' instants): the clean cases stay at the read floor (0.4
    mrad noise + 4096 ticks: ~0.6 mrad RMS; measured 0.66-0.87), every hidden effect moves some
    joint's logs well above it (measured: the smallest, the encoder's 5 mrad sinusoid, 4.4 mrad;
    the series-elastic mcp 5.2)."""
    for case in sim.CASES:
        rms = sim.effect_size(case, 4.0)["rms"]
        if case.effects:
            assert max(rms) > 0.003, (case.name, rms)
        else:
            assert max(rms) < 0.0012, (case.name, rms)


def _log(case: sim.Case, seconds: float, tmp_path) -> list[dict[str, np.ndarray]]:
    files = sim.write_case(dataclasses.replace(case, durations=(seconds,) * len(case.durations)),
                           tmp_path)
    out = []
    for path in files["logs"]:
        head = pathlib.Path(path).read_text().splitlines()[0].split(",")
        a = np.genfromtxt(path, delimiter=",", skip_header=1)
        out.append({h: a[:, k] for k, h in enumerate(head)})
    return out


def test_the_logs_carry_what_a_user_logs(tmp_path):
    """Project CSV columns only; rows at 333 Hz (torque) or 100 Hz (position) within one 0.25
    ms step of jitter; readings on the 4096-tick grid; torque goals inside +-0.7 N m; voltage
    in 0.1 V and temperatures in whole degrees where logged."""
    for name, period in (("clean_torque_333hz", 0.003), ("clean_position_100hz", 0.01)):
        (log, *_) = _log(sim.CASE_BY_NAME[name], 2.0, tmp_path / name)
        dt = np.diff(log["time"])
        assert np.all(np.abs(dt - period) <= sim.TRUTH_DT + 1e-9), (name, dt.min(), dt.max())
        for j in sim.JOINTS:
            ticks = log[f"qpos:{j}"] / sim.TICK
            np.testing.assert_allclose(ticks, np.round(ticks), atol=1e-4)
        g = np.column_stack([log[f"goal:{a}"] for a in sim.ACTS])
        if name.startswith("clean_torque"):
            assert np.abs(g).max() <= sim.TAU_MAX + 1e-9
        assert sorted(log) == sorted(["time", *(f"goal:{a}" for a in sim.ACTS),
                                      *(f"qpos:{j}" for j in sim.JOINTS)])


def test_the_supply_sags_with_the_torque_all_four_motors_draw(tmp_path):
    """voltage_sag: 12.0 V when the torques are small, falling with the sum of the four
    commanded torques (0.5 ohm x 1.5 A per 0.7 N m per motor, written out: the sag is at most
    0.5 x 4 x 1.5 = 3 V and tracks 0.5 x 1.5 / 0.7 x sum |torque|)."""
    (log, *_) = _log(sim.CASE_BY_NAME["voltage_sag_torque"], 4.0, tmp_path)
    v = log[f"voltage:{sim.ACTS[0]}"]
    load = sum(np.abs(log[f"goal:{a}"]) for a in sim.ACTS)
    want = 12.0 - 0.5 * 1.5 / 0.7 * load * v / 12.0
    assert v.min() < 11.5 and v.max() <= 12.0
    assert np.corrcoef(v, want)[0, 1] > 0.8
    assert np.median(np.abs(v - want)) < 0.25


def test_thermal_logs_are_taken_warm_and_the_read_delay_shifts_the_reading(tmp_path):
    """thermal: the three logs start at 35, 55, 75 deg C; read_delay: the torque rig's logged
    reading is the clean rig's reading (same seed, same targets) delayed: the lag that best
    aligns them is the 9 ms, not 0."""
    logs = _log(sim.CASE_BY_NAME["thermal_position"], 1.0, tmp_path / "th")
    assert [round(x[f"temperature:{sim.ACTS[1]}"][0]) for x in logs] == [35, 55, 75]
    case = sim.CASE_BY_NAME["read_delay_9ms_torque"]
    t = sim.row_times(3.0, 1000.0, np.random.default_rng(0))
    tgt = {j: 0.3 + 0.3 * np.sin(2 * math.pi * 1.0 * t) for j in sim.JOINTS}
    for c, want in ((case, 9), (dataclasses.replace(case, effects=()), 0)):
        out = sim.simulate(dataclasses.replace(c, kind="position", rate=1000.0), t, tgt,
                           np.random.default_rng(1), true_angles=True)
        q, true = out["qpos:mcp"][100:], out["true:mcp"][100:]
        err = [np.mean((q[k:] - true[:len(true) - k]) ** 2) for k in range(20)]
        assert int(np.argmin(err)) == want, (c.name, err)
