"""Logs stamped with the host's wall clock (``time.time()``, 1.7e9 s), as a user's logger writes
them: the velocities the analysis estimates from position-only rows, and the read-noise floor it
derives from them, must not depend on where the clock started.

Found on the LEAP-like finger (tests/gap_user_leap.py): the velocity estimate's running sums
squared the raw stamps (t * t ~ 3e18 keeps no digit of a 20 ms window), so every row of every
epoch-stamped log got qvel ~0, moving or not: multiple-shooting windows started the finger at
rest, and the noise floor (taken where goal and velocity are still) counted moving rows as
still (1.88 mrad against the 0.668 mrad the readings carry).

Truth from plain MuJoCo (the finger's own qvel) and the generator's noise constants.
"""

from __future__ import annotations

import pathlib
import sys

import mujoco
import numpy as np
import pytest

sys.path.insert(0, str(pathlib.Path(__file__).parent))
import gap_user_leap as leap  # noqa: E402

from lowcostdex.gap.logs import estimate_velocity  # noqa: E402


def _finger_log(seed: int, seconds: float = 6.0):
    """The user's finger (plain MuJoCo at 0.5 ms) on chirp goals, read at jittered 50 Hz rows:
    (row times from 0 [s], goals, quantised readings, MuJoCo's joint velocity at each row)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * leap.RATE)
    g = leap.goals("chirp", n, rng)
    m = mujoco.MjModel.from_xml_string(leap._xml(0.0005, leap.KP))
    d = mujoco.MjData(m)
    t = (np.arange(n) + rng.uniform(-leap.JITTER, leap.JITTER, n)) / leap.RATE
    t[0] = 0.0
    q, v = np.zeros((n, 4)), np.zeros((n, 4))
    for k in range(n):
        while d.time < t[k] - 1e-9:
            mujoco.mj_step(m, d)
        q[k], v[k] = d.qpos, d.qvel
        d.ctrl[:] = g[k]
    tick = 2 * np.pi / leap.TICKS
    return t, g, np.round(q / tick) * tick, v


def test_velocities_on_wall_clock_stamps_are_those_from_zero():
    t, g, q, v_true = _finger_log(seed=5)
    from_zero = estimate_velocity(t, q, goal=g)
    epoch = estimate_velocity(leap.EPOCH + t, q, goal=g)
    # the estimate's own error (a +-35 ms line through 50 Hz ticks) on this finger
    rms_true = np.sqrt(np.mean(v_true ** 2, axis=0))
    err_zero = np.sqrt(np.mean((from_zero - v_true) ** 2, axis=0))
    assert np.all(err_zero < 0.25 * rms_true), (err_zero, rms_true)
    # the same velocities from the wall clock (stamps resolve 2.4e-7 s at 1.7e9 s)
    np.testing.assert_allclose(epoch, from_zero, atol=1e-3 * float(rms_true.max()))


def test_the_noise_floor_of_the_users_epoch_stamped_logs_is_the_reading_noise(tmp_path):
    """The analysis's floor estimate on the user's folder (epoch stamps, no qvel column) is the
    generator's 0.5 mrad noise with 4096-tick quantisation (0.668 mrad), not the 1.9 mrad the
    still-everywhere velocities gave (the estimator's own spread, second differences of
    quantised readings trimmed of their top 2 %, is +-25 % on these 3 logs)."""
    from lowcostdex.gap import load_dataset
    from lowcostdex.gap.diagnostics import noise_floor

    leap.write_user_folder(tmp_path, seed=1, n_logs=3, seconds=8.0, gain=1.0, offset=0.0,
                           friction=3 * leap.FRICTION_GUESS, latency=0.030)
    ds = load_dataset(tmp_path / "logs", model=str(tmp_path / "leap_finger.xml"))
    assert ds.trajectories[0].time[0] == pytest.approx(leap.EPOCH)
    floor = noise_floor(ds.trajectories)
    assert np.all(np.abs(floor / leap.FLOOR - 1) < 0.3), (floor, leap.FLOOR)
    # and the rows move: the loaded velocities follow a plain central difference of the readings
    tr = ds.trajectories[1]  # a chirp
    fd = np.gradient(tr.qpos, tr.time - tr.time[0], axis=0)
    corr = [np.corrcoef(tr.qvel[:, j], fd[:, j])[0, 1] for j in range(4)]
    assert min(corr) > 0.9, corr
