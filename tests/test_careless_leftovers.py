"""Issue 12's leftovers after the careless sessions: each mistake a clean refusal or a correct
run, its truth outside the code under test (the files on disk, exit codes, values written out
here, the emulated motors' side).

- ``train --resume`` with ``--n-iter`` below the iterations done trained nothing, rewrote
  config.json to the smaller budget and printed the old outcome as if it had run;
- ``calibrate --spec X --out X`` replaced the spec it started from;
- a failed velocity, voltage or temperature read dropped its whole row (and cut the log where
  the goal changed across it), though the position - what the replay needs - was read;
- a read-only ``--out`` (as root permissions do not stop a write: a path under a file instead);
- Allegro (python-can virtual bus) and hardware-backend hand specs get the D'Claw's checks.
"""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from test_bad_inputs import bench_model, csv_text, servo_log, with_velocity

from lowcostdex.cli import USER_ERROR, main

POINTMASS = "lowcostdex_test/PointMass-v0"
TINY = ("--n-traj", "2", "--eval-every", "1", "--eval-episodes", "1", "--hidden", "8",
        "--no-progress")


@pytest.fixture(autouse=True)
def _pointmass_registered():
    if POINTMASS not in gym.registry:
        gym.register(POINTMASS, entry_point="pointmass:PointMass", max_episode_steps=30)


def snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


def one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("[progress]")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# ------------------------------------------------------------------------------------------------
# train --resume --n-iter below what the run has done


def test_resume_with_fewer_iterations_than_done_is_refused_and_the_run_left_as_it_is(
        tmp_path, capsys):
    """A run of 3 iterations (checkpoints after iterations 0..2 on disk, 3 metric rows) resumed
    with --n-iter 2: it trained nothing and rewrote config.json to n_iter 2 while its
    checkpoints say 3. Now exit 2, one line naming both numbers, every file byte for byte
    as it was. The same --n-iter 3 (a finished run resumed, e.g. after a crash in its last
    writes) runs and says there is nothing to train; --n-iter 4 trains one more iteration."""
    out = tmp_path / "run"
    argv = ["train", "npg", "--env", POINTMASS, "--out", str(out), *TINY]
    assert main([*argv, "--n-iter", "3"]) == 0
    assert sorted(p.name for p in (out / "checkpoints").glob("ckpt_*.pt"))[-1] == "ckpt_000002.pt"
    before = snapshot(tmp_path)
    capsys.readouterr()
    for n_iter in ("2", "1"):
        assert main([*argv, "--n-iter", n_iter, "--resume"]) == USER_ERROR
        line = one_error_line(capsys.readouterr().err)
        assert line == (f"lowcostdex train npg: error: cannot resume {out} with n_iter={n_iter} "
                        "(--n-iter): the run has done 3 iterations already (checkpoint after "
                        "iteration 2); give --n-iter above 3 to train more. The run is left as "
                        "it is"), line
        assert snapshot(tmp_path) == before
    assert main([*argv, "--n-iter", "3", "--resume"]) == 0
    err = capsys.readouterr().err
    assert (f"lowcostdex train npg: note: the run in {out} had done its 3 iterations (--n-iter "
            "3): nothing was trained, its final outputs were written again; give --n-iter above "
            "3 to train more") in err, err
    assert len((out / "metrics.csv").read_text().splitlines()) == 1 + 3
    assert main([*argv, "--n-iter", "4", "--resume"]) == 0
    assert "note:" not in capsys.readouterr().err
    assert len((out / "metrics.csv").read_text().splitlines()) == 1 + 4
    assert json.loads((out / "config.json").read_text())["n_iter"] == 4


def test_resume_below_the_iterations_done_is_refused_for_ppo_too(tmp_path, capsys):
    """The refusal is in the run folder's check every trainer calls (PPO on the valve here)."""
    out = tmp_path / "run"
    argv = ["train", "ppo", "--out", str(out), "--num-envs", "2",
            "--num-minibatches", "1", "--update-epochs", "1", "--hidden", "8",
            "--eval-every", "1", "--eval-episodes", "1", "--threads", "1", "--no-progress"]
    assert main([*argv, "--n-iter", "2"]) == 0
    before = snapshot(tmp_path)
    capsys.readouterr()
    assert main([*argv, "--n-iter", "1", "--resume"]) == USER_ERROR
    assert "the run has done 2 iterations already" in one_error_line(capsys.readouterr().err)
    assert snapshot(tmp_path) == before


# ------------------------------------------------------------------------------------------------
# calibrate --spec X --out X


def test_calibrate_onto_its_own_spec_is_refused_and_a_new_name_works(tmp_path, capsys,
                                                                      monkeypatch):
    from lowcostdex.hands import dclaw_spec

    monkeypatch.chdir(tmp_path)
    spec = tmp_path / "spec.json"
    spec.write_text(dclaw_spec().to_json())
    (tmp_path / "link.json").symlink_to(spec)
    before = snapshot(tmp_path)
    for out in ("spec.json", str(spec), "./spec.json", "link.json"):
        code = main(["calibrate", "--spec", "spec.json", "--out", out, "--port", "emulated",
                     "--yes"])
        assert code == USER_ERROR
        line = one_error_line(capsys.readouterr().err)
        assert (f"--out {out} is the --spec file itself: calibrating would replace the spec it "
                "starts from") in line, line
        assert snapshot(tmp_path) == before
    assert main(["calibrate", "--spec", "spec.json", "--out", "new.json", "--port", "emulated",
                 "--yes"]) == 0
    assert spec.read_bytes() == before["spec.json"]
    assert json.loads((tmp_path / "new.json").read_text())["name"] == "dclaw"


# ------------------------------------------------------------------------------------------------
# failed optional reads in a log: the row stays


def _channels_log() -> dict[str, np.ndarray]:
    """The bench log with the servo's velocity, supply voltage (12 V sagging 0.1 V per A of
    current) and temperature (35 deg C rising 1 deg C per 2 s, 1 deg C steps), as an X-series
    servo's Present registers give them."""
    cols = with_velocity(servo_log())
    cols["voltage:arm"] = np.round(12.0 - 0.1 * np.abs(cols["current:arm"]), 1)
    cols["temperature:arm"] = np.floor(35.0 + cols["time"] / 2.0)
    return cols


def _load(tmp_path: Path, cols: dict[str, np.ndarray]):
    from lowcostdex.gap.dataset import load_dataset

    (tmp_path / "bench.xml").write_text(bench_model())
    (tmp_path / "log.csv").write_text(csv_text(cols))
    return load_dataset([tmp_path / "log.csv"], model=tmp_path / "bench.xml")


def test_a_failed_optional_read_keeps_its_row_and_short_gaps_are_interpolated(tmp_path):
    """Velocity missing in row 300, voltage in rows 410-411, temperature in row 799 (the last):
    all 800 rows are kept with the clean log's time, goal and position; the missing values are
    the straight line between the readings either side (rows are 10 ms apart: the mean of the
    two neighbours for one row, 1/3 and 2/3 of the way for two), the last held; one note per
    channel names the rows. Before: the rows were dropped and the log cut in two at row 300
    (the goal changes at every row)."""
    clean = _channels_log()
    cols = {k: v.copy() for k, v in clean.items()}
    cols["qvel:arm"][300] = np.nan
    cols["voltage:arm"][410:412] = np.nan
    cols["temperature:arm"][799] = np.nan
    ds = _load(tmp_path, cols)
    (tr,) = ds.trajectories
    assert len(tr.time) == 800
    for k, key in (("time", "time"), ("goal", "goal:arm"), ("qpos", "qpos:arm")):
        got = getattr(tr, k).ravel()
        assert np.allclose(got, clean[key], atol=1e-6), k  # the CSV keeps 6 decimals
    v = clean["qvel:arm"]
    assert tr.qvel[300, 0] == pytest.approx((v[299] + v[301]) / 2, abs=1e-6)
    u = clean["voltage:arm"]
    assert tr.channels["voltage"][410:412, 0] == pytest.approx(
        [u[409] + (u[412] - u[409]) / 3, u[409] + 2 * (u[412] - u[409]) / 3], abs=1e-6)
    assert tr.channels["temperature"][799, 0] == clean["temperature:arm"][798]
    assert np.array_equal(np.delete(tr.qvel[:, 0], 300), np.delete(v, 300).round(6))
    assert ds.notes == [
        "log.csv: 1 qvel reading(s) missing in 1 row(s) (first: row 300, 0-based; qvel:arm): "
        "interpolated between the readings either side, the rows kept",
        "log.csv: 2 voltage reading(s) missing in 2 row(s) (first: row 410, 0-based; "
        "voltage:arm): interpolated between the readings either side, the rows kept",
        "log.csv: 1 temperature reading(s) missing in 1 row(s) (first: row 799, 0-based; "
        "temperature:arm): interpolated between the readings either side, the rows kept"]


def test_a_long_velocity_gap_costs_the_velocity_channel_not_the_rows(tmp_path):
    """Velocity missing in 10 rows in a row (100 ms: too long to draw a line through a servo's
    response): the rows are kept and the velocity of the whole log is what the data set gives
    a log without velocities (the same log with the qvel column deleted); a temperature gap
    that long costs the temperature channel. A failed POSITION read still drops its row."""
    clean = _channels_log()
    cols = {k: v.copy() for k, v in clean.items()}
    cols["qvel:arm"][500:510] = np.nan
    cols["temperature:arm"][100:110] = np.nan
    ds = _load(tmp_path, cols)
    (tr,) = ds.trajectories
    assert len(tr.time) == 800 and "temperature" not in tr.channels
    assert "voltage" in tr.channels
    without = {k: v for k, v in clean.items() if k not in ("qvel:arm", "temperature:arm")}
    (ref,) = _load(tmp_path, without).trajectories
    assert np.array_equal(tr.qvel, ref.qvel)
    assert ds.notes == [
        "log.csv: qvel readings are missing in 10 row(s) (first: row 500, 0-based), 10 rows in "
        "a row at most: the qvel channel is left out and the rows kept (its velocities are "
        "estimated from the positions, as for a log without them)",
        "log.csv: temperature readings are missing in 10 row(s) (first: row 100, 0-based), 10 "
        "rows in a row at most: the temperature channel is left out and the rows kept (effects "
        "that need it cannot be fitted)"]
    cols = {k: v.copy() for k, v in clean.items()}
    cols["qpos:arm"][200] = np.nan
    cols["qvel:arm"][200] = np.nan
    assert [len(t) for t in _load(tmp_path, cols).trajectories] == [200, 599]
