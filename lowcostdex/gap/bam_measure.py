"""BAM's error measure on measured servo logs, computed with the project's plant.

BAM (Rhoban/bam, ``bam.process`` + ``bam.mae``; 08-bam-reference-errors.md section 1) scores an
actuator model on a set of pendulum logs like this:

1. every log is resampled onto a grid t = 0, dt, 2 dt, ... < (last timestamp), dt = 5 ms, by
   linear interpolation between the two raw samples around t (linear extrapolation from the
   first two samples before the first one); ``torque_enable`` is thresholded at 0.5;
2. the model is rolled out open loop from the first grid state (position, speed), the firmware
   P law recomputed from the *simulated* position and the grid's goal, the torque switched off
   where the grid says so (free fall included);
3. a log's error is the mean |q_sim - q_meas| over every grid sample; the set's error is the
   mean over logs of the per-log errors.

``resample`` does step 1 on a ``Trajectory``; ``grid_dataset`` does it for a whole data set (same
nominal models); ``per_log_mae`` does steps 2-3 through ``Replayer`` (our plant: the servo model of
``lowcostdex.sim.servo`` plus effects), one window per whole log, so a log's rollout is exactly
BAM's protocol with our physics in place of BAM's simulator.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lowcostdex.gap.dataset import Dataset, Window
from lowcostdex.gap.logs import LogError, Trajectory
from lowcostdex.sim.effects import AppliedEffect

BAM_DT = 0.005  # [s] bam.process default grid step


def _interp(t_raw: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """BAM's interpolation: for grid time t the segment [frame, frame + 1] with the first
    ``frame`` such that t <= t_raw[frame + 1] (extrapolating the first segment before the first
    sample), then linear interpolation on it. values: (T, n) -> (len(t), n)."""
    frame = np.clip(np.searchsorted(t_raw, t, side="left") - 1, 0, len(t_raw) - 2)
    t1, t2 = t_raw[frame], t_raw[frame + 1]
    a = ((t - t1) / (t2 - t1))[:, None]
    return values[frame] + (values[frame + 1] - values[frame]) * a


def grid_start(t_raw: np.ndarray) -> float:
    """Where the grid starts [s]: 0 (BAM's rule) when the first sample lies within two sample
    intervals of it (a whole log: the first read comes one bus period after the recording
    starts, 3.5 ms on Rhoban's XL330 logs, 21 ms at Pham's 35 ms); else the first sample itself.
    A piece cut after a time hole (``logs.split_at_gaps``) keeps its log's clock, and a grid
    from 0 extrapolated its first two samples back over the seconds before it: a Rhoban
    sin_time_square log holed at 2.7 s started its second piece at 7.7 rad and -136 rad/s and
    its nominal replay scored 1.04 rad (2026-11-27); a log stamped with wall-clock time
    (1.7e9 s) would have asked for a 3e11-sample grid."""
    lead = 2.0 * float(np.median(np.diff(t_raw)))
    return 0.0 if t_raw[0] <= lead else float(t_raw[0])


def resample(tr: Trajectory, dt: float = BAM_DT, release: float = 0.0) -> Trajectory:
    """A trajectory on BAM's grid (module doc, step 1); goals and channels resampled alike.
    The grid starts at 0 (or at the first sample, ``grid_start``). With ``release`` [s] > 0 the
    servo lets go that long after the torque-off command (``torque_off.release_delay``): each
    run of torque-off samples starts on the grid point nearest its first sample's time +
    ``release`` (BAM's rule, 0: where the interpolated flag drops below 0.5).

    Raises:
      LogError when the log has fewer than two samples or ends before ``dt``.
    """
    t_raw = np.asarray(tr.time, float)
    if len(t_raw) < 2 or t_raw[-1] <= dt:
        raise LogError(f"{tr.name}: too short for BAM's {dt * 1e3:g} ms grid")
    t = np.arange(grid_start(t_raw), t_raw[-1], dt)
    qvel = None if tr.qvel is None else _interp(t_raw, tr.qvel, t)
    channels = {k: _interp(t_raw, np.asarray(v, float), t) for k, v in tr.channels.items()}
    if "torque_enable" in channels:
        channels["torque_enable"] = (channels["torque_enable"] > 0.5).astype(float)
        if release > 0.0:
            _hold(channels["torque_enable"], np.asarray(tr.channels["torque_enable"]) > 0.5,
                  t_raw, t, release)
    out = Trajectory(name=tr.name, time=t, goal=_interp(t_raw, tr.goal, t),
                     qpos=_interp(t_raw, tr.qpos, t), actuators=tr.actuators, joints=tr.joints,
                     qvel=qvel, channels=channels, model=tr.model, meta=dict(tr.meta))
    return out


def _hold(grid_on: np.ndarray, raw_on: np.ndarray, t_raw: np.ndarray, t: np.ndarray,
          release: float) -> None:
    """Keep the torque on (in place, (len(t), n)) from the last sample before each raw
    torque-off run until the grid point nearest the run's first sample's time + ``release``
    (a log that starts with the torque off has nothing to release there)."""
    half = 0.5 * float(t[1] - t[0]) if len(t) > 1 else 0.0
    for j in range(raw_on.shape[1]):
        for k in np.flatnonzero(~raw_on[1:, j] & raw_on[:-1, j]) + 1:
            grid_on[(t >= t_raw[k - 1]) & (t < t_raw[k] + release - half), j] = 1.0


def grid_dataset(ds: Dataset, dt: float = BAM_DT, release: float = 0.0) -> Dataset:
    """The data set with every trajectory resampled onto BAM's grid (same nominal models);
    ``release`` as in ``resample``."""
    return Dataset(dict(ds.models), [resample(tr, dt, release) for tr in ds.trajectories],
                   list(ds.sources), list(ds.notes),  # the notes: repairs, gaps cut, defaults
                   ds.servo_period)


def whole_logs(ds: Dataset, logs: Sequence[int] | None = None) -> list[Window]:
    """One window per log (all of it, scored from its first sample)."""
    idx = range(len(ds.trajectories)) if logs is None else logs
    return [Window(int(k), 0, len(ds.trajectories[k]), 0) for k in idx]


def per_log_mae(replayer, windows: Sequence[Window],
                columns: Sequence[Sequence[AppliedEffect]]) -> np.ndarray:
    """BAM's per-log MAE [rad], shape (len(columns), len(windows)), one row per effect set.

    Args:
      replayer: a ``Replayer`` over a grid data set (``grid_dataset``) with room for the effects.
      windows: whole-log windows (``whole_logs``).
      columns: effect sets to score (an empty list is the nominal model).
    """
    pred, _ = replayer.run(windows, columns)
    ds = replayer.ds
    out = np.empty((len(columns), len(windows)))
    for c in range(len(columns)):
        for i, w in enumerate(windows):
            q = ds.trajectories[w.traj].qpos[w.start:w.stop]
            out[c, i] = float(np.mean(np.abs(pred[c][i] - q)))
    return out
