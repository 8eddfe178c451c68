"""The gap analysis on real servo logs (BAM pendulum benches). Skips cleanly when the measured
data folder is absent (LOWCOSTDEX_MEASURED_DATA or LOWCOSTDEX_MEASURED overrides
../shared/data/measured next to the repository)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from real_logs import ROOT, lift_logs, swing_maes

from lowcostdex.gap import GapConfig, analyze, load_dataset
from lowcostdex.gap import bam_measure as bm

STS3250 = ROOT / "rhoban-bam-feetech-sts3250"
RHOBAN = ROOT / "rhoban-bam-xl330"
PHAM = ROOT / "pham-tuan-binh-bam-xl330"


@pytest.mark.skipif(not STS3250.is_dir(), reason=f"measured data not found at {ROOT}")
def test_real_feetech_bench_logs_are_explained_better_after_extension():
    files = sorted(STS3250.glob("*.json"))
    ds = load_dataset(files)  # BAM JSON auto-detected and mapped onto the bench
    assert len(ds.trajectories) == 4 and ds.trajectories[0].meta["motor"] == "sts3250"
    assert {"voltage", "torque_enable"} <= ds.channels()
    res = analyze(ds, GapConfig(seed=0))
    # the nominal (datasheet) model is far off on real hardware; the named causes cut the
    # held-out error substantially and every accepted fit is inside its bounds
    assert res.causes, res.verdict
    assert all(not c.flags for c in res.causes)
    base = np.mean(res.baseline["per_episode_mae"])
    ext = np.mean(res.extended["per_episode_mae"])
    assert ext < 0.5 * base
    assert res.extended["heldout_rmse"] < res.baseline["heldout_rmse"]


# BAM's published XL330 parameters, typed in from Rhoban/bam@1b5a1cee2e6dcd2ab8c12b013f1e05482b16cb96
# bam/params/xl330/m1.json and m3.json (kt [N m/A], R [Ohm], armature [kg m^2], q_offset [rad],
# friction_base [N m], load_friction_base [1], friction_viscous [N m s/rad]).
BAM_M1 = dict(kt=0.3866957639281311, R=4.017129222290597, armature=0.0018141672784458866,
              q_offset=0.030871000250528358, friction_base=0.01283272036582759,
              load_friction_base=0.0, friction_viscous=0.003661672282824312)
BAM_M3 = dict(kt=0.38042022855161584, R=3.380066954773944, armature=0.001917772275220315,
              q_offset=0.029439576907685533, friction_base=0.008881712972862601,
              load_friction_base=0.12166455532811028, friction_viscous=0.004379099756757558)
XL330_ERROR_GAIN = (4096 / (2 * np.pi)) / (256 * 885)  # duty per (kp rad), BAM's XL330Actuator


def bam_reference_rollout(tr, p: dict, dt: float = bm.BAM_DT) -> np.ndarray:
    """BAM's pendulum rollout written out from its documented physics (not its code): duty =
    clip(error_gain kp (goal - q), +-1), tau_m = kt (vin duty - kt qdot) / R (0 with the torque
    off), gravity at q + q_offset, a friction budget friction_base + load_friction_base
    |tau_e - tau_m| + viscous |qdot| clipping the torque that would stop the arm in one step,
    semi-implicit Euler at dt."""
    h = tr.meta
    m, l_, arm = h["mass"], h["length"], h.get("arm_mass", 0.0)
    inertia = m * l_ ** 2 + arm * l_ ** 2 / 3 + p["armature"]
    q, dq = float(tr.qpos[0, 0]), float(tr.qvel[0, 0])
    out = np.empty(len(tr.time))
    on = tr.channels["torque_enable"][:, 0] > 0.5
    for k in range(len(tr.time)):
        out[k] = q
        duty = np.clip((tr.goal[k, 0] - q) * h["kp"] * XL330_ERROR_GAIN, -1.0, 1.0)
        tau_m = (p["kt"] * h["vin"] * duty - p["kt"] ** 2 * dq) / p["R"] if on[k] else 0.0
        tau_e = -(m + arm / 2) * 9.80665 * l_ * np.sin(q + p["q_offset"])
        budget = (p["friction_base"] + p["load_friction_base"] * abs(tau_e - tau_m)
                  + p["friction_viscous"] * abs(dq))
        net = tau_m + tau_e
        stop = inertia / dt * dq + net
        net -= np.sign(stop) * min(abs(stop), budget)
        acc = net / inertia
        dq += acc * dt
        q += dq * dt + 0.5 * acc * dt * dt
    return out


@pytest.mark.skipif(not (RHOBAN.is_dir() and PHAM.is_dir()),
                    reason=f"measured data not found at {ROOT}")
def test_bam_grid_reproduces_bams_published_errors():
    # 08-bam-reference-errors.md section 2: bam.mae on bam.process'ed logs, mean per-log MAE
    published = {("rhoban", "m1"): 0.0819, ("rhoban", "m3"): 0.0691,
                 ("pham", "m1"): 0.0259, ("pham", "m3"): 0.0218}
    for name, folder in (("rhoban", RHOBAN), ("pham", PHAM)):
        ds = load_dataset(sorted(folder.glob("*.json")))
        grid = [bm.resample(tr) for tr in ds.trajectories]
        for tr, raw in zip(grid, ds.trajectories, strict=True):
            assert tr.time[0] == 0.0 and tr.time[-1] < raw.time[-1] <= tr.time[-1] + bm.BAM_DT
            assert set(np.unique(tr.channels["torque_enable"])) <= {0.0, 1.0}
        for model, p in (("m1", BAM_M1), ("m3", BAM_M3)):
            mae = np.mean([np.mean(np.abs(bam_reference_rollout(tr, p) - tr.qpos[:, 0]))
                           for tr in grid])
            assert mae == pytest.approx(published[(name, model)], abs=5e-5)


def test_resample_interpolates_like_bam_process():
    from lowcostdex.gap.logs import Trajectory

    t = np.array([0.0035, 0.0087, 0.0121, 0.0200, 0.0260])
    q = np.array([0.0, 0.1, 0.3, 0.2, 0.6])[:, None]
    te = np.array([1.0, 1.0, 0.0, 0.0, 0.0])[:, None]
    tr = Trajectory("t", t, q + 1, q, ("j",), ("j",), qvel=2 * q,
                    channels={"torque_enable": te})
    g = bm.resample(tr)
    np.testing.assert_allclose(g.time, [0.0, 0.005, 0.010, 0.015, 0.020, 0.025], atol=1e-15)
    # t = 0 extrapolates the first segment; later times interpolate the segment that ends at
    # the first sample at or after them
    want = [0.0 - 0.1 * 0.0035 / 0.0052, 0.1 * 0.0015 / 0.0052,
            0.1 + 0.2 * 0.0013 / 0.0034, 0.3 - 0.1 * 0.0029 / 0.0079, 0.2, 0.2 + 0.4 * 5 / 6]
    np.testing.assert_allclose(g.qpos[:, 0], want, atol=1e-12)
    np.testing.assert_allclose(g.goal[:, 0], np.array(want) + 1, atol=1e-12)
    np.testing.assert_allclose(g.qvel[:, 0], 2 * np.array(want), atol=1e-12)
    # torque_enable interpolated, then thresholded at 0.5: 1 - 0.0013 / 0.0034 = 0.62 -> on
    np.testing.assert_array_equal(g.channels["torque_enable"][:, 0], [1, 1, 1, 0, 0, 0])


def _split(ds, held_kp):
    kps = [int(tr.meta["kp"]) for tr in ds.trajectories]
    return ([i for i, k in enumerate(kps) if k not in held_kp],
            [i for i, k in enumerate(kps) if k in held_kp])


@pytest.mark.skipif(not (RHOBAN.is_dir() and PHAM.is_dir()),
                    reason=f"measured data not found at {ROOT}")
def test_identified_servo_beats_bam_on_held_out_gains():
    from lowcostdex.gap.identify import IdentifyConfig, identify, servo_structure

    # BAM on the same held-out logs, 08-bam-reference-errors.md: Rhoban XL330 held out kp 200
    # and 800 after fitting kp 100 and 400, BAM's refit M6 0.0599 rad (section 3); Pham XL330 at
    # kp 400, BAM's best published model M3 0.022 rad (section 2, per-kp column). Issue 11's
    # targets on the same splits: Rhoban < 0.050 rad, Pham < 0.022 (Rhoban 0.0425 since the
    # restart kept by cost and the family by the fitted logs, gap.identify_select; 0.056 before,
    # a near tie on 4 held-back logs: bench/RESULTS.md gap-real5; 0.031 since the drive's fall
    # with the duty, gap-stall7)
    for folder, held, bam, target in ((RHOBAN, (200, 800), 0.0599, 0.050),
                                      (PHAM, (400,), 0.022, 0.022)):
        ds = bm.grid_dataset(load_dataset(sorted(folder.glob("*.json")), timestep=bm.BAM_DT))
        train, test = _split(ds, held)
        res = identify(ds, train, test, IdentifyConfig(effects=servo_structure(ds)))
        assert res.mean(test) < min(bam, target), (folder.name, res.mean(test), res.params())
        assert res.mean(test) < 0.3 * res.mean(test, identified=False)
        if folder == RHOBAN:
            # on the heavy bench the load-carrying gear friction is what the model leans on
            # most (it holds the arm near stall and stops the free fall of lift_and_drop)
            assert max(res.ablation, key=res.ablation.get) == "gearbox_friction"
            _drive_falls_with_the_duty(ds, test, res)


def _drive_falls_with_the_duty(ds, test, res):
    """Rhoban's XL330 at 7.4 V: the load the arm holds per unit of duty falls towards full duty
    (its logged PWM is the P law, yet kp 800's full duty stops the slow up_and_down lift at the
    same 0.882 rad, 0.371 N m of load, as kp 400's duty 0.8 does): the identified drive must
    fall with the duty (supply_resistance), and the model must stop that lift where the real arm
    did (the truth: the log's own final reading). Before the effect (main 2359690): held out
    42.5 mrad, the lift stopped at 0.97 rad; with it 31.1 and 0.88 (bench/RESULTS.md
    gap-stall7)."""
    from lowcostdex.gap.replay import Replayer

    assert res.mean(test) < 0.036, res.mean(test)
    assert res.params()["supply_resistance"]["resistance"][0] > 0.3
    assert res.ablation["supply_resistance"] > 1.5 * res.mean(test), res.ablation
    lift = [i for i in test if ds.trajectories[i].meta["kp"] == 800
            and ds.trajectories[i].meta["trajectory"] == "up_and_down"]
    pred, _ = Replayer(ds, [e.name for e in res.effects]).run(bm.whole_logs(ds, lift),
                                                             [res.effects])
    real = ds.trajectories[lift[0]].qpos[-200:, 0]  # the last second: stopped
    assert np.ptp(real) < 0.005
    assert abs(float(np.mean(pred[0][0][-200:, 0])) - float(np.mean(real))) < 0.03


@pytest.mark.slow  # three Rhoban identifies (about 1.5 min of CPU)
@pytest.mark.skipif(not RHOBAN.is_dir(), reason=f"measured data not found at {ROOT}")
def test_rhoban_identification_does_not_hinge_on_where_its_fits_start():
    from lowcostdex.gap.identify import IdentifyConfig, identify, servo_structure

    # a user runs the identification once: its answer must not be a draw of its starts. Every
    # start jittered by x (1 + 0.001 N(0, 1)) (seeds 1, 2; 0: the catalogue's starts): on main
    # 57537c7 five seeds gave 41.5-56.0 mrad held out (held.1, held.2, free.0 chosen), since
    # gap.identify_select 42.5 on all five (bench/RESULTS.md gap-real5)
    ds = bm.grid_dataset(load_dataset(sorted(RHOBAN.glob("*.json")), timestep=bm.BAM_DT))
    train, test = _split(ds, (200, 800))
    runs = [identify(ds, train, test, IdentifyConfig(effects=servo_structure(ds), seed=seed,
                                                     jitter=1e-3 if seed else 0.0))
            for seed in (0, 1, 2)]
    held = [r.mean(test) for r in runs]
    assert max(held) - min(held) < 0.001, held  # one basin: within a mrad
    assert {r.family for r in runs} == {"free"}, [r.selection["chosen"] for r in runs]


@pytest.mark.skipif(not STS3250.is_dir(), reason=f"measured data not found at {ROOT}")
def test_a_heavy_arm_s_torque_off_swing_is_not_held_by_a_breakaway_counted_twice():
    from lowcostdex.gap.identify import IdentifyConfig, identify, servo_structure

    # the real STS3250 arm (1.13 kg at 0.12 m) swings back and settles hanging after the torque
    # goes off. Fitted on the three torque-on trajectories, lift_and_drop held out: the fit's
    # gear breakaway share (0.45 x the gravity torque) already reaches the rest level the
    # training logs allow (0.256 N m), so gap.rest_friction adds none; stacked, the two held the
    # model's arm at +0.63 rad for 3.4 s: 373.9 mrad held out (bench/RESULTS.md gap-drop8)
    ds = bm.grid_dataset(load_dataset(sorted(STS3250.glob("*.json")), timestep=bm.BAM_DT))
    kinds = [tr.meta["trajectory"] for tr in ds.trajectories]
    test = [kinds.index("lift_and_drop")]
    train = [i for i in range(len(kinds)) if i not in test]
    res = identify(ds, train, test, IdentifyConfig(effects=servo_structure(ds)))
    assert res.mean(test) < 0.15, (res.mean(test), res.params())  # measured 0.1003; 0.0419
    # since the drive's fall with the duty (gap-stall7: its fit is another one, in which
    # gap.rest_friction adds a rest breakaway that does not hold the arm up, so the swing itself
    # is checked, not the absence of that term)
    # the real arm after the drop: its last second hangs within 50 mrad of the bottom; so must
    # the model's (the stacked breakaway held it at +0.63 rad)
    from lowcostdex.gap.replay import Replayer

    tr = ds.trajectories[test[0]]
    last = tr.time > tr.time[-1] - 1.0
    assert np.max(np.abs(tr.qpos[last, 0])) < 0.05
    pred, _ = Replayer(ds, [e.name for e in res.effects]).run(bm.whole_logs(ds, test),
                                                             [res.effects])
    assert np.max(np.abs(pred[0][0][last, 0])) < 0.05, res.params()


STS3032 = ROOT / "qua-robotics-bam-sts3032"


@pytest.mark.slow  # about 3 min of CPU: 36 whole training logs, three families
@pytest.mark.skipif(not STS3032.is_dir(), reason=f"measured data not found at {ROOT}")
def test_identified_feetech_servo_beats_bam_m4_and_issue_target_on_held_out_gain():
    from lowcostdex.gap.identify import IdentifyConfig, identify, servo_structure

    # 08-bam-reference-errors.md section 4: fit kp 32 (36 logs), hold out kp 8 (36 logs); BAM's
    # refit M4 0.0297 rad held out; issue 11's target 0.025 rad. Measured 0.0243 (nominal_motor.1,
    # gap.identify_select; 0.0347 on main 57537c7 with the fit chosen on the held-back logs: a
    # strict xfail until then; bench/RESULTS.md gap-real5)
    ds = bm.grid_dataset(load_dataset(sorted(STS3032.glob("*.json")), timestep=bm.BAM_DT))
    train, test = _split(ds, (8,))
    assert len(train) == len(test) == 36
    res = identify(ds, train, test, IdentifyConfig(effects=servo_structure(ds)))
    assert res.mean(test) < 0.025, (res.mean(test), res.family, res.params())  # < BAM M4 too


BAM_FOLDERS = [ROOT / d for d in ("rhoban-bam-xl330", "pham-tuan-binh-bam-xl330",
                                  "rhoban-bam-feetech-sts3250", "qua-robotics-bam-sts3032")]


@pytest.mark.skipif(not all(d.is_dir() for d in BAM_FOLDERS),
                    reason=f"measured data not found at {ROOT}")
def test_no_real_log_is_refused_and_the_frozen_check_is_live_on_the_nearest():
    """The signal checks' false-positive rate on real hardware: every BAM raw log in the measured
    folders (XL330, STS3250, STS3032 benches: 104 logs) loads - none is taken for a frozen
    encoder, a clipped or wrapped register or a dead channel. The frozen-encoder statistic's
    largest value over all of them (measured 2026-11-26: 0.0775 rad, an STS3032 stalled under its
    load for 2.2 s, against FROZEN_CROSS 0.2: bench/RESULTS.md) stays below the threshold. The
    control: that same log with its reading stuck from 1 s on, at the middle of the range it
    covers from there (the goal still moving across it), is refused."""
    from dataclasses import replace

    from lowcostdex.gap.log_checks import FROZEN_CROSS, check_signals, frozen_crossing
    from lowcostdex.gap.logs import LogError, read_bam

    logs = sorted(p for d in BAM_FOLDERS for p in d.glob("*.json"))
    assert len(logs) == 104
    worst = (-np.inf, None)
    for path in logs:
        traj, _ = read_bam(path)  # raises LogError on a refusal
        crossing, _, _ = frozen_crossing(traj, 0)
        worst = max(worst, (crossing, traj), key=lambda w: w[0])
    crossing, traj = worst
    assert 0 < crossing < FROZEN_CROSS, crossing
    q = traj.qpos.copy()
    stuck = traj.time >= traj.time[0] + 1.0
    q[stuck] = 0.5 * (q[stuck].max() + q[stuck].min())
    with pytest.raises(LogError, match="is frozen at"):
        check_signals(replace(traj, qpos=q, qvel=None))


def _bench_module():
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "bench" / "gap_real.py"
    spec = importlib.util.spec_from_file_location("gap_real_bench", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.skipif(not all(d.is_dir() for d in BAM_FOLDERS),
                    reason=f"measured data not found at {ROOT}")
def test_bench_references_reproduce_bams_trivial_baselines():
    # 08-bam-reference-errors.md: predicting q = goal_position gives 0.654 rad (Rhoban) and
    # 0.163 rad (Pham), q = q(0) 0.416 and 0.965 (section 2); STS3032, all 72 logs: q = goal
    # 0.395, q = q(0) 0.726 (section 4). The bench's reference rows on BAM's 5 ms grid.
    gr = _bench_module()
    want = {"rhoban-xl330": (0.654, 0.416), "pham-xl330": (0.163, 0.965),
            "sts3032": (0.395, 0.726)}
    for name, (goal, start) in want.items():
        _, ds = gr.load_set(name, ROOT)
        ref = gr.reference_mae(ds)
        assert np.mean(list(ref["q = goal"].values())) == pytest.approx(goal, abs=6e-4), name
        assert np.mean(list(ref["q = q(0)"].values())) == pytest.approx(start, abs=6e-4), name


@pytest.mark.skipif(not RHOBAN.is_dir(), reason=f"measured data not found at {ROOT}")
def test_bench_bam_numbers_on_the_trajectory_folds_are_bams_per_trajectory_errors():
    # 08-bam-reference-errors.md section 2, breakdown table: published M3 on Rhoban XL330 per
    # trajectory (all gains) 0.052 / 0.073 / 0.039 / 0.113 rad, i.e. BAM's number on each fold
    # of the bench's leave-one-trajectory-out run; the bench's finer values (bam.mae re-run on
    # each fold's 4 logs) must agree with both the reference and BAM's rollout written out here.
    gr = _bench_module()
    ref08 = dict(zip(gr.TRAJ, (0.052, 0.073, 0.039, 0.113), strict=True))
    ds = load_dataset(sorted(RHOBAN.glob("*.json")))
    grid = [bm.resample(tr) for tr in ds.trajectories]
    for traj, want in ref08.items():
        bench = gr.BAM_LOSO["rhoban-xl330"][("trajectory", traj)]["BAM published M3"]
        assert bench == pytest.approx(want, abs=6e-4), traj  # ref 08 rounds to 1 mrad
        mae = np.mean([np.mean(np.abs(bam_reference_rollout(tr, BAM_M3) - tr.qpos[:, 0]))
                       for tr in grid if tr.meta["trajectory"] == traj])
        assert mae == pytest.approx(bench, abs=5e-5), traj


@pytest.mark.skipif(not PHAM.is_dir(), reason=f"measured data not found at {ROOT}")
def test_bench_bam_numbers_on_the_pham_trajectory_folds_are_bams_published_m3():
    # 08-bam-reference-errors.md section 2, breakdown table: published M3 on Pham XL330 per
    # trajectory (all gains) 0.017 / 0.014 / 0.041 / 0.015 rad, rounded to 1 mrad there: the
    # bench's typed values, and BAM's rollout written out here on each fold's 3 logs
    gr = _bench_module()
    ds = load_dataset(sorted(PHAM.glob("*.json")))
    grid = [bm.resample(tr) for tr in ds.trajectories]
    for traj, want in zip(gr.TRAJ, (0.017, 0.014, 0.041, 0.015), strict=True):
        bench = gr.BAM_LOSO["pham-xl330"][("trajectory", traj)]["BAM published M3"]
        assert bench == want, traj
        mae = np.mean([np.mean(np.abs(bam_reference_rollout(tr, BAM_M3) - tr.qpos[:, 0]))
                       for tr in grid if tr.meta["trajectory"] == traj])
        assert mae == pytest.approx(want, abs=6e-4), traj


MX = ROOT / "rhoban-bam-mx-atomic"


@pytest.mark.skipif(not MX.is_dir(), reason=f"measured data not found at {ROOT}")
def test_mx_component_measurements_against_the_catalogue():
    # The authors' own fits of these files (Rhoban/bam README at c50ae40, shared/data/measured/
    # README.md): V = H kp |error| with H = 2.391 (MX-64) and 2.363 (MX-106) V per (P rad) at
    # 15 V, i.e. duty per (kp rad) 2.391 / 15 = 0.159 and 0.158 (BAM's error_gain 0.158).
    gr = _bench_module()
    m = gr.mx_checks(ROOT)
    assert m["error_gain"]["mx64"]["measured"] == pytest.approx(2.391 / 15, rel=0.02)
    assert m["error_gain"]["mx106"]["measured"] == pytest.approx(2.363 / 15, rel=0.02)
    for mx in ("mx64", "mx106"):
        # the catalogue's no-load speed per volt within 10 % of the measured free-running speed
        sp = m["speed"][mx]
        assert sp["catalogue rad/s/V"] == pytest.approx(sp["measured rad/s/V"], rel=0.10)
        # the passive fall (torque off) ends 15 degrees past hanging, held by the gearbox
        # (README: -1.83 rad from the horizontal); the datasheet model has no such friction
        # and swings: it is worse than "the arm hangs at 0" from the first sample
        f = m["fall"][mx]
        assert f["q = 0 (hanging)"] < f["nominal"]


@pytest.mark.skipif(not STS3250.is_dir(), reason=f"measured data not found at {ROOT}")
def test_gap_identify_command_scores_a_held_out_log(tmp_path, capsys):
    import json

    from lowcostdex.cli import main

    files = sorted(STS3250.glob("*.json"))
    held = [f for f in files if json.loads(f.read_text())["trajectory"] == "sin_sin"]
    out = tmp_path / "id.json"
    assert main(["gap", "identify", "--log", str(STS3250), "--holdout", *map(str, held),
                 "--restarts", "1", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "held out" in text
    # one setup: nothing validates the family choice, and the command says so
    assert "why: no header field" in text and "nothing validates the fit" in text
    def strict(word):  # Infinity / NaN are not JSON (jq, JavaScript and most readers refuse)
        raise AssertionError(f"{word} in gap identify --json output")

    res = json.loads(out.read_text(), parse_constant=strict)
    assert list(res["held_out"]) == [held[0].name] and len(res["fitted"]) == 3
    # the sin_sin log's q = goal_position error from its raw samples: the identified model,
    # fitted on the other three trajectories, must beat it by half (measured 2026-11-26: 12.2 vs
    # 54.6 mrad) and beat the datasheet model
    raw = json.loads(held[0].read_text())["entries"]
    goal_err = np.mean([abs(e["goal_position"] - e["position"]) for e in raw])
    assert res["held_out"][held[0].name] < 0.5 * goal_err
    assert res["held_out"][held[0].name] < res["nominal"][held[0].name]
    # the verdict (issue 11 item 5): one held-out log, better than the nominal model on it
    assert "verdict: identified model better on 1 of 1 held-out logs" in text
    assert res["verdict"]["reliable"] and res["verdict"]["gain_ci95"] is None


@pytest.mark.skipif(not STS3250.is_dir(), reason=f"measured data not found at {ROOT}")
def test_a_fit_worse_than_the_nominal_model_on_its_held_out_log_says_no_reliable_gain():
    from lowcostdex.gap.identify import IdentifyConfig, identify, servo_structure

    # STS3250, sin_time_square held out (the fastest trajectory; fitted on the other three):
    # measured 2026-11-27 identified 51.3 mrad against the nominal model's 44.2 (bench/RESULTS.md
    # gap-stall7). The verdict must follow the two replays' errors on that log, not the fit's
    # training cost, and say "no reliable gain" whenever the identified model is the worse one
    ds = bm.grid_dataset(load_dataset(sorted(STS3250.glob("*.json")), timestep=bm.BAM_DT))
    kinds = [tr.meta["trajectory"] for tr in ds.trajectories]
    test = [kinds.index("sin_time_square")]
    train = [i for i in range(len(kinds)) if i not in test]
    res = identify(ds, train, test, IdentifyConfig(effects=servo_structure(ds)))
    worse = res.mean(test) >= res.mean(test, identified=False)
    assert res.verdict["reliable"] is (not worse), (res.verdict, res.mean(test))
    assert res.verdict["text"].startswith("no reliable gain") is worse


@pytest.mark.skipif(not RHOBAN.is_dir(), reason=f"measured data not found at {ROOT}")
def test_rhoban_xl330_torque_off_swings_give_bams_published_armature_not_the_catalogues():
    from lowcostdex.gap.torque_off import swing_fit

    ds, lift = lift_logs(RHOBAN)
    fit = swing_fit(ds, lift)
    assert len(fit.logs) == 4  # kp 100, 200, 400, 800: 0.49 kg at 0.10 m, let go
    # BAM's six published XL330 fits (Rhoban/bam@1b5a1ce bam/params/xl330, m1-m6): armature
    # 0.00181-0.00192 kg m^2; the catalogue's XL330-M288 says 0.0003 (6x low). Measured
    # 2026-11-28 (gap-real12): 0.00189, Coulomb 0.0053 N m, viscous 0.0095 N m s/rad
    assert 0.00181 * 0.95 <= fit.armature <= 0.00192 * 1.05
    assert fit.catalogue_armature == pytest.approx(0.0003)
    assert max(fit.mae) < 0.04  # [rad] per swing: the written-out pendulum explains them



@pytest.mark.skipif(not (RHOBAN.is_dir() and PHAM.is_dir()),
                    reason=f"measured data not found at {ROOT}")
def test_the_armature_seed_reads_bams_armature_off_rhobans_swings_and_nothing_off_phams():
    from lowcostdex.gap.torque_off import armature_seed

    # Rhoban's 0.49 kg arm swings with the torque off: the seed is BAM's six published XL330
    # armatures (0.00181-0.00192 kg m^2, Rhoban/bam@1b5a1ce bam/params/xl330), 6x the catalogue
    seed = armature_seed(*lift_logs(RHOBAN))
    assert seed is not None and 0.00181 * 0.95 <= seed.armature <= 0.00192 * 1.05
    # Pham's 4 g arm stays where the torque went off (friction holds 4 mN m of gravity): its
    # 2 mrad "swings" say nothing of the armature, so no seed
    assert armature_seed(*lift_logs(PHAM)) is None


@pytest.mark.skipif(not RHOBAN.is_dir(), reason=f"measured data not found at {ROOT}")
def test_rhobans_torque_off_swings_want_the_gears_own_law_not_their_load_friction():
    # The XL330 catalogue's torque-off law (MotorSpec.backdriven: BAM's published XL330 M1
    # Coulomb 0.0182 N m + viscous 0.0059 N m s/rad, one law with no load share) against BAM's
    # published M3, whose gearbox keeps its load friction back-driven (0.264 |tau_g| + 0.0023 +
    # 0.0169 qd; Rhoban/bam params/xl330/m3.json), both at BAM's published armature 0.0019 kg
    # m^2, on the four real torque-off swings of Rhoban's lift_and_drop logs (a pendulum written
    # out: gap.torque_off.simulate). Measured 2026-11-28: catalogue 35.1 / 28.2 / 39.7 / 32.5
    # mrad, M3's law 30.6 / 63.6 / 69.2 / 113.6, no friction 176-432, the swings' own best
    # Coulomb + viscous 28.9 / 29.0 / 33.1 / 29.8 (bench/RESULTS.md gap-real15)
    from lowcostdex.gap.torque_off import swings
    from lowcostdex.sim import servo

    ds, lift = lift_logs(RHOBAN)
    sws = swings(ds, lift)
    assert len(sws) == 4
    c, b = servo.motor_spec("XL330-M288").backdriven

    def mae(p):
        return swing_maes(sws, p)

    own, load, none = mae([0.0019, c, b, 0.0]), mae([0.0019, 0.0023, 0.0169, 0.264]), mae(
        [0.0019, 0.0, 0.0, 0.0])
    assert np.max(own) < 0.045
    assert np.mean(own) < 0.6 * np.mean(load) and np.sum(own < load) >= 3
    assert np.all(own < 0.3 * none)


@pytest.mark.slow  # one Rhoban identification (about 1 min of CPU)
@pytest.mark.skipif(not RHOBAN.is_dir(), reason=f"measured data not found at {ROOT}")
def test_rhoban_lift_and_drop_held_out_with_the_catalogue_torque_off_law_beats_bam_m3():
    from lowcostdex.gap.identify import IdentifyConfig, identify, servo_structure

    # lift_and_drop held out: no training log has the torque off, so the swing's friction is the
    # servo catalogue's own torque-off law (gap.identify_logs.backdriven_plan). BAM's published
    # M3 on the same logs: 0.052 rad (08-bam-reference-errors.md); before the law 0.0640 (the
    # gear friction back-driven whole), measured 2026-11-28 with it 0.041 (RESULTS gap-real15),
    # 0.042 with it as the joint's whole back-driven friction (joint 0; RESULTS gap-real17)
    ds = bm.grid_dataset(load_dataset(sorted(RHOBAN.glob("*.json")), timestep=bm.BAM_DT))
    kinds = [tr.meta["trajectory"] for tr in ds.trajectories]
    test = [i for i, k in enumerate(kinds) if k == "lift_and_drop"]
    train = [i for i in range(len(kinds)) if i not in test]
    res = identify(ds, train, test, IdentifyConfig(effects=servo_structure(ds), nthread=1))
    assert res.mean(test) < 0.052, (res.mean(test), res.params())
    assert res.params()["backdriven_friction"]["gear"] == [0.0]
    assert res.params()["backdriven_friction"]["joint"] == [0.0]


@pytest.mark.skipif(not (RHOBAN.is_dir() and STS3250.is_dir()),
                    reason=f"measured data not found at {ROOT}")
def test_the_torque_off_law_is_fitted_where_training_swings_and_the_catalogues_elsewhere():
    from lowcostdex.gap.identify import servo_structure
    from lowcostdex.gap.identify_logs import BACKDRIVEN, BACKDRIVEN_PARAMS, backdriven_plan

    def load(folder):
        ds, lift = lift_logs(folder)
        return ds, lift, [i for i in range(len(ds.trajectories)) if i not in lift]

    ds, lift, rest = load(RHOBAN)
    effects = servo_structure(ds)
    assert BACKDRIVEN in effects  # its lift_and_drop logs turn the torque off
    # torque-off swings in training: Coulomb and viscous free, the gear's own level and the
    # joint's own friction kept
    assert backdriven_plan(ds, lift + rest, effects, "fit") == (
        frozenset({(BACKDRIVEN, "gear"), (BACKDRIVEN, "joint")}), None)
    # none: nothing to fit it on, the XL330 catalogue's law (BAM's published M1) after the fit
    held, after = backdriven_plan(ds, rest, effects, "fit")
    assert held == BACKDRIVEN_PARAMS and after == {"coulomb": 0.0182, "viscous": 0.0059,
                                                   "gear": 0.0, "joint": 0.0}
    assert backdriven_plan(ds, rest, effects, "null") == (BACKDRIVEN_PARAMS, None)
    assert backdriven_plan(ds, rest, tuple(e for e in effects if e != BACKDRIVEN), "fit") == (
        frozenset(), None)
    # the STS3250 has no catalogue law: held at its null (the gear friction back-driven whole)
    ds, lift, rest = load(STS3250)
    assert backdriven_plan(ds, rest, servo_structure(ds), "fit") == (BACKDRIVEN_PARAMS, None)
    # Pham's XL330 carries 4 g (0.004 N m of gravity, below the law's 0.0182 N m): its load
    # cannot back-drive the gears, no law is set (with it its lift_and_drop fold 3.4 -> 8.3 mrad)
    if PHAM.is_dir():
        ds, lift, rest = load(PHAM)
        assert backdriven_plan(ds, rest, servo_structure(ds), "fit") == (BACKDRIVEN_PARAMS, None)
        assert backdriven_plan(ds, lift + rest, servo_structure(ds), "fit")[1] is None
