"""The hidden actuator state a replay window starts from: servos whose activation has dynamics.

A user's MJCF may drive a joint through an actuator with an activation (``Replayer`` carries it
into every window, multiple shooting included):

* ``timeconst`` (filter, filterexact): a ``position`` servo following its goal through a
  first-order filter; at a window's start the filter holds what the goals before it left
  (from the first goal, a servo at rest holding it);
* ``intvelocity`` (integrator): the goal is a velocity [rad/s] integrated into the setpoint;
  at a window's start the setpoint is the integral of the goals that arrived before it since
  the log's start, where the servo held its first reading against the static load. That anchor
  is a hidden state the log does not carry; its read error offsets the whole replay of the
  log, and ``Activations.anchor`` profiles it out per log (least squares).

Without this the activation started each window at 0 (an ``intvelocity`` bench replayed at
694 mrad, a ``timeconst`` one at 24 mrad; both 0.6 now, floor 0.535).
* a dcmotor servo whose firmware slews its goal (``slewmax``: a Feetech STS at its Running
  Speed, a Dynamixel Profile Velocity): at a window's start the slewed goal is where the goals
  before it, followed at the slew rate from the first goal (the servo at rest holding it), left
  it (``slewed``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import numpy as np

from lowcostdex.gap.dataset import Dataset, Window
from lowcostdex.sim import servo

Key = tuple[str, bool]  # (model key, structural variant)


class Activations:
    """Activation-carrying servos of a replay's model variants and their state at window starts.

    Args:
      ds: the data set.
      variants: compiled models by (model key, structural variant).
      act_idx: model actuator id of each logged actuator, by variant.
    """

    def __init__(self, ds: Dataset, variants: dict[Key, mujoco.MjModel],
                 act_idx: dict[Key, np.ndarray]):
        self.ds, self.variants, self.act_idx = ds, variants, act_idx

    def integrators(self, key: Key) -> list[tuple[int, int, int]]:
        """Integrating position servos (``intvelocity``: the goal is a velocity, the setpoint
        the actuator's activation) among the logged actuators: (column in the log's actuator
        list, model actuator id, activation address)."""
        return self._with_dynamics(key, (mujoco.mjtDyn.mjDYN_INTEGRATOR,))

    def _with_dynamics(self, key: Key, kinds: tuple) -> list[tuple[int, int, int]]:
        """Position servos among the logged actuators whose activation has dynamics ``kinds``:
        (column in the log's actuator list, model actuator id, activation address)."""
        cache = self.__dict__.setdefault("_dyn_servos", {})
        if (key, kinds) not in cache:
            m = self.variants[key]
            cache[(key, kinds)] = [(col, int(a), int(m.actuator_actadr[a]))
                                   for col, a in enumerate(self.act_idx[key])
                                   if position_like(m, a) and m.actuator_actadr[a] >= 0
                                   and int(m.actuator_dyntype[a]) in {int(k) for k in kinds}]
        return cache[(key, kinds)]

    def _filtered(self, traj: int, col: int, tau: float) -> np.ndarray:
        """A first-order filter's state (time constant ``tau``, a ``position`` actuator's
        timeconst) when each goal of the trajectory arrives, before it acts; the filter starts
        at the first goal (a servo at rest holding it)."""
        cache = self.__dict__.setdefault("_filter_states", {})
        k = (traj, col, tau)
        if k not in cache:
            tr = self.ds.trajectories[traj]
            g, u = tr.goal[:, col], tr.goal_times
            decay = np.exp(-np.diff(u) / tau)
            out = np.empty(len(g))
            out[0] = g[0]
            for i in range(1, len(g)):
                out[i] = g[i - 1] + (out[i - 1] - g[i - 1]) * decay[i - 1]
            cache[k] = out
        return cache[k]

    def slews(self, key: Key) -> list[tuple[int, int, int]]:
        """Logged dcmotor servos whose goal is slewed: (column in the log's actuator list, model
        actuator id, address of the slewed goal in act)."""
        cache = self.__dict__.setdefault("_slew_servos", {})
        if key not in cache:
            ids, adr = servo.goal_slew_states(self.variants[key])
            where = dict(zip(ids.tolist(), adr.tolist(), strict=True))
            cache[key] = [(col, int(a), where[int(a)]) for col, a in enumerate(self.act_idx[key])
                          if int(a) in where]
        return cache[key]

    def slewed(self, traj: int, col: int, rate: float, x: float) -> float:
        """The firmware's slewed goal [rad] at time ``x`` [s] (goal arrival time): from the
        first goal, moving toward each goal in force at ``rate`` [rad/s] at most."""
        tr = self.ds.trajectories[traj]
        g, u = tr.goal[:, col], tr.goal_times
        i = int(np.searchsorted(u, x, side="right")) - 1
        if i < 0:
            return float(g[0])
        cache = self.__dict__.setdefault("_slew_states", {})
        k = (traj, col, rate)
        if k not in cache:  # the slewed goal when each goal arrives
            step = rate * np.diff(u)
            out = np.empty(len(g))
            out[0] = g[0]
            for j in range(1, len(g)):
                out[j] = out[j - 1] + min(max(g[j - 1] - out[j - 1], -step[j - 1]), step[j - 1])
            cache[k] = out
        state, d = cache[k][i], rate * (x - u[i])
        return float(state + min(max(g[i] - state, -d), d))

    def setpoints(self, key: Key, sims: list[tuple[int, int]],
                   windows: Sequence[Window], delays: np.ndarray, gains: np.ndarray,
                   dynprm: np.ndarray | None = None) -> np.ndarray | None:
        """(nsim, na) activations at each window's start: an integrating servo's setpoint is
        the integral of its velocity goals (arriving ``delays`` late) since the log's start,
        where it held the measured angle against the static load (kp (s - gear q) gear = the
        gravity torque of the nominal model, as a servo at rest; kp from ``gains``, the
        simulations' (nsim, nu, 10) actuator_gainprm), clipped to its activation range; a
        slewed goal is ``slewed`` at the simulation's slew rate (``dynprm``, the simulations'
        (nsim, nu, 10) actuator_dynprm; the model's when None). None when the model has none
        of these servos among the logged actuators."""
        ints = self.integrators(key)
        filters = self._with_dynamics(key, (mujoco.mjtDyn.mjDYN_FILTER,
                                            mujoco.mjtDyn.mjDYN_FILTEREXACT))
        slews = self.slews(key)
        if not ints and not filters and not slews:
            return None
        m = self.variants[key]
        out = np.zeros((len(sims), m.na))
        for col, a, adr in slews:
            for s, (_, wi) in enumerate(sims):
                w = windows[wi]
                rate = float((m.actuator_dynprm if dynprm is None else dynprm[s])[
                    a, servo.DYN_SLEWMAX])
                x = self.ds.trajectories[w.traj].time[w.start] - delays[s, col]
                out[s, adr] = self.slewed(w.traj, col, rate, x)
        for col, a, adr in filters:  # the filtered goal (a timeconst): from the goals before
            tau = float(m.actuator_dynprm[a, 0])
            for s, (_, wi) in enumerate(sims):
                w = windows[wi]
                tr = self.ds.trajectories[w.traj]
                x = tr.time[w.start] - delays[s, col]
                i = int(np.searchsorted(tr.goal_times, x, side="right")) - 1
                if i < 0 or tau <= 0:
                    out[s, adr] = tr.goal[0, col]
                    continue
                state = self._filtered(w.traj, col, tau)[i]
                out[s, adr] = tr.goal[i, col] + (state - tr.goal[i, col]) * math.exp(
                    -(x - tr.goal_times[i]) / tau)
        for col, a, adr in ints:
            jid = int(m.actuator_trnid[a, 0])
            name = m.joint(jid).name
            gear = float(m.actuator_gear[a, 0])
            for s, (_, wi) in enumerate(sims):
                w = windows[wi]
                tr = self.ds.trajectories[w.traj]
                kp = float(gains[s, a, 0])
                start = gear * tr.qpos[0, tr.joints.index(name)] + self.static_load(
                    w.traj, name) / (kp * gear)
                x = tr.time[w.start] - delays[s, col]  # goals that arrived before the window
                u = tr.goal_times
                if x <= u[0]:
                    setpoint = start
                else:
                    i = int(np.searchsorted(u, x, side="right")) - 1
                    done = float(np.sum(tr.goal[:i, col] * np.diff(u[:i + 1])))
                    setpoint = start + done + float(tr.goal[i, col]) * (x - u[i])
                if m.actuator_actlimited[a]:
                    lo, hi = m.actuator_actrange[a]
                    setpoint = min(max(setpoint, lo), hi)
                out[s, adr] = setpoint
        return out

    def anchor(self, windows: Sequence[Window], pred: list[list[np.ndarray]]) -> None:
        """Shift the predictions of joints driven by integrating servos by their mean residual
        over each log's scored samples, per column, in place.

        Such a servo's setpoint is a hidden state the log does not carry: it is anchored to the
        first reading (``setpoints``), whose read error (0.5 mrad here) then offsets the whole
        replay of the log; a joint at rest on a shifted setpoint is the same motion shifted
        (up to the load's change with the angle), so the anchor is profiled out per log by
        least squares. On clean logs the first-reading anchor left 1.1 mrad (floor 0.54)
        and a 1 mrad position offset or a 0.6 mrad backlash was named.
        """
        by_model: dict[str, list[int]] = {}
        for tr_model in {self.ds.trajectories[w.traj].model for w in windows}:
            m = self.variants[(tr_model, False)]
            by_model[tr_model] = [self.ds.joints.index(m.joint(int(m.actuator_trnid[a, 0])).name)
                                  for _, a, _ in self.integrators((tr_model, False))
                                  if m.joint(int(m.actuator_trnid[a, 0])).name in self.ds.joints]
        if not any(by_model.values()):
            return
        trajs: dict[int, list[int]] = {}
        for wi, w in enumerate(windows):
            trajs.setdefault(w.traj, []).append(wi)
        for col in pred:
            for t, wis in trajs.items():
                js = by_model[self.ds.trajectories[t].model]
                if not js or any(col[wi] is None for wi in wis):
                    continue
                q = self.ds.trajectories[t].qpos
                res = np.concatenate([(q[windows[wi].score_from:windows[wi].stop]
                                       - col[wi][windows[wi].score_from - windows[wi].start:])[:, js]
                                      for wi in wis])
                if len(res):
                    shift = res.mean(axis=0)
                    for wi in wis:
                        col[wi] = col[wi].copy()
                        col[wi][:, js] += shift

    def static_load(self, traj: int, joint: str) -> float:
        """Gravity (and other configuration-dependent) torque on ``joint`` at the trajectory's
        first measured position, at rest, in the nominal model [N m]."""
        cache = self.__dict__.setdefault("_loads", {})
        tr = self.ds.trajectories[traj]
        if traj not in cache:
            m = self.variants[(tr.model, False)]
            d = mujoco.MjData(m)
            for j, q in zip(tr.joints, tr.qpos[0], strict=True):
                d.qpos[m.jnt_qposadr[m.joint(j).id]] = q
            mujoco.mj_forward(m, d)
            cache[traj] = {j: float(d.qfrc_bias[m.jnt_dofadr[m.joint(j).id]])
                           for j in tr.joints}
        return cache[traj][joint]


def position_like(m: mujoco.MjModel, a: int) -> bool:
    """Whether actuator ``a`` is a fixed-gain position servo on a joint: force = kp (input -
    length) - kv velocity (``position``, a ``general`` written so, ``intvelocity`` on its
    activation), any gear."""
    kp = float(m.actuator_gainprm[a, 0])
    return bool(m.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
                and m.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_AFFINE
                and m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
                and kp > 0 and m.actuator_biasprm[a, 1] == -kp
                and m.actuator_biasprm[a, 0] == 0 and m.actuator_gear[a, 0] != 0)
