"""Replay measured commands through a model with effects, many variants at once.

``Replayer.run(windows, columns)`` simulates every (column, window) pair, where a column is one
list of ``AppliedEffect`` (a candidate model with parameter values), in ``BatchPlant``s stepped
together at the physics timestep:

* commands are zero-order held in continuous time (never interpolated, sysid trap 4) and take
  effect at their instant (``goal_time``, else ``time``): the ctrl of each physics step is the
  mean of the goals in force during it, so a goal written 0.3 steps into a step drives the servo
  for 0.7 of it (position servos are linear in ctrl: the same impulse as switching mid-step;
  rounding to the nearest step instead biased replays of jittered logs by up to dt/2);
* a latency is a goal queue: each goal acts from its instant + the delay, with the step means
  and the saturation matching at the shifted instants, per actuator (``Replayer._shifted``);
  MuJoCo's native actuator delay is zeroed for these replays: its linear interpolation of ctrl
  between physics steps leads a saturating servo (a 53 ms latency on a force-limited bench was
  then named with a torque limit beside it);
* each window starts from the measured state at its first sample (multiple shooting when windows
  are short segments, open loop when a window is a whole episode); the servo's setpoint before the
  window is the goal in force just before it; a position offset and a sensor scale are removed
  from the measured initial state;
* backlash is replayed in both of its regimes and the one closer to the data is kept: a play
  hinge between the servo's motor side and its link (a model prepared with hidden dofs; the link
  starts at the measured angle, at a log's start leaning on the stop its static load pushes it
  to, ``Plant.reset``; inside a log, with the play angle and rate that a replay of the second
  before the window ends with, ``gap.play_state``) and the massless-motor play operator on the
  goal (no hidden dofs; the servo's setpoint before the window is the operator's state after
  the goals that preceded it, exact: the operator acts on commands only). Columns without
  backlash run on a model without the hidden dofs, so the nominal column stays the nominal model
  exactly;
* a servo update period (``Dataset.servo_period``) samples each position servo's law every
  period and holds its force between (``sim.servo.ServoClock``; no saturation matching then:
  the firmware reads one goal per update);
* measured channels (voltage, temperature, torque enable) are held like commands (``supply``:
  a log's highest voltage, the nominal of a drive without a servo's own);
* actuators of any gear (force matching in actuator units, peak forces reported at the joint)
  and servos that integrate a velocity goal (``intvelocity``): their setpoint (activation) at a
  window's start is the integral of the goals that arrived before it from the log's start, where
  the servo held its measured angle against the static load (``gap.activation``);
* predictions are the encoder readings (observation effects applied) interpolated linearly at the
  measured sample times;
* a column already replayed on the same windows is answered from memory (bitwise the same
  predictions: a simulation does not depend on the others in its batch).

Why one module (over 600 lines): the grid of a window's goals, their delayed copies, the
hidden state carried into a window and the memory of replayed columns all belong to the one
``Replayer`` state that steps the batches; the activations it carries are ``gap.activation``,
the saturation matching of a step's goal switch ``gap.saturation``. A simulation whose window
has ended is not advanced while longer windows of its batch finish (its records there are never
read).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_finite_array
from lowcostdex.gap import play_state, saturation
from lowcostdex.gap.activation import Activations, position_like
from lowcostdex.gap.dataset import Dataset, Window
from lowcostdex.sim.effects import CAUSES, EFFECTS, AppliedEffect, Targets
from lowcostdex.sim.effects.sensor_scale import reading_map
from lowcostdex.sim.plant import BatchPlant, prepare_spec

Column = Sequence[AppliedEffect]
_MEMO_BYTES = 64 * 2 ** 20  # predictions kept for repeated columns (``Replayer.run``)
_ORDER = {name: i for i, name in enumerate(EFFECTS)}


@dataclass
class _Grid:
    """One window laid on the physics grid."""

    n_steps: int
    goals: np.ndarray  # (K, na) goal held during grid step k
    rows: np.ndarray  # (K,) log row of the channels (current, voltage, ...) during grid step k
    frac: np.ndarray  # (n,) fractional grid position of each sample of the window
    prev_goal: np.ndarray  # (na,) goal in force just before the window
    split: np.ndarray  # (K,) fraction of step k before its one goal switch (NaN: none or several)
    before: np.ndarray  # (K, na) goal before that switch
    after: np.ndarray  # (K, na) goal after it


class Replayer:
    """Batched replay of a data set's windows under candidate effect sets.

    Args:
      ds: the data set.
      effect_names: effects that may appear in columns (structural room is made for them, e.g.
        latency history buffers; the nominal behaviour is unchanged).
      nthread: batch threads (0: all CPUs).
    """

    def __init__(self, ds: Dataset, effect_names: Sequence[str] = (), nthread: int = 0):
        _check_goals(ds)  # once here: the inner loop steps its plants unchecked
        self.ds = ds
        self.nthread = nthread
        # models without the structural effects (``models``, the nominal dynamics) and, when
        # some are candidates, with them too: variant key (model key, structural?)
        self.models: dict[str, mujoco.MjModel] = {}
        self._variants: dict[tuple[str, bool], mujoco.MjModel] = {}
        probe = [AppliedEffect(n, ds.effect_joints) for n in effect_names]
        plain = [e for e in probe if not e.cls.structural]
        for key, xml in ds.models.items():
            for structural, effs in ((False, plain), (True, probe)):
                if structural and len(effs) == len(plain):
                    continue
                spec = mujoco.MjSpec.from_string(xml)
                prepare_spec(spec, effs, hidden_dofs=structural)
                self._variants[(key, structural)] = spec.compile()
            self.models[key] = self._variants[(key, False)]
        m0 = self.models[ds.trajectories[0].model]
        self.dt = float(m0.opt.timestep)
        self._plants: dict[tuple, BatchPlant] = {}
        self._grids: dict[Window, _Grid] = {}
        self._act_idx = {k: np.array([m.actuator(a).id for a in ds.actuators])
                         for k, m in self._variants.items()}
        self._jnt_qpos = {k: np.array([m.jnt_qposadr[m.joint(j).id] for j in ds.joints])
                          for k, m in self._variants.items()}
        self._jnt_dof = {k: np.array([m.jnt_dofadr[m.joint(j).id] for j in ds.joints])
                         for k, m in self._variants.items()}
        self._act_of_joint = {}
        for k, m in self._variants.items():
            targets = Targets.resolve(m, ds.effect_joints)
            cols = {int(a): i for i, a in enumerate(self._act_idx[k])}
            self._act_of_joint[k] = {j: cols[int(a)] for j, a in
                                     zip(ds.effect_joints, targets.actuators, strict=True)}
        self._acts = Activations(ds, self._variants, self._act_idx)
        self.steps_run = 0  # simulated sim-steps (for throughput reports)
        # predictions already replayed: (windows, column) -> per-window predictions (``run``)
        self._memo: OrderedDict[tuple, list[np.ndarray]] = OrderedDict()
        self._memo_bytes = 0
        self.memo_hits = 0
        self.preroll = play_state.PREROLL  # s replayed before a window for its play state

    # ------------------------------------------------------------------------------------------
    def grid(self, w: Window) -> _Grid:
        """The window's commands and sample times on the physics grid (cached)."""
        g = self._grids.get(w)
        if g is None:
            tr = self.ds.trajectories[w.traj]
            t = tr.time[w.start:w.stop] - tr.time[w.start]
            frac = t / self.dt
            n_steps = int(np.ceil(frac[-1])) + 1
            # goals switch on the grid when they took effect (``goal_time``, else at ``time``);
            # before the window's first switch the goal in force before the window holds: the
            # previous row's, at a log's start (when goals arrive after the first read) the
            # measured position, which a servo at rest holds (actuators are named after the
            # joints they drive)
            switch = np.round((tr.goal_times[w.start:w.stop] - tr.time[w.start]) / self.dt)
            sel = np.searchsorted(switch, np.arange(n_steps), side="right") - 1  # >= -1
            if w.start > 0:
                prev = tr.goal[w.start - 1]
            elif switch[0] > 0:
                prev = self._rest_goal(w.traj)
            else:
                prev = tr.goal[0]
            u = (tr.goal_times[w.start:w.stop] - tr.time[w.start]) / self.dt
            goals = _step_means(u, tr.goal[w.start:w.stop], prev, n_steps)
            split, before, after = _single_switches(u, tr.goal[w.start:w.stop], prev, n_steps)
            rows = np.maximum(w.start + sel, 0)
            g = _Grid(n_steps, goals, rows, frac, prev, split, before, after)
            self._grids[w] = g
        return g

    def _rest_goal(self, traj: int) -> np.ndarray:
        """(na,) the goal in force before log ``traj``'s first goal arrived: the one that holds
        the first reading at rest (actuators named after their joints): a fixed-gain position
        servo's goal holds it against the static load (gear q + load / (kp gear), the nominal
        model's gravity torque, as ``Activations.setpoints`` for integrating servos; a servo
        that settled at the first goal then stays put until that goal arrives, and so does
        one that held another goal), a velocity actuator or a motor the command whose force
        holds that load at the first measured speed (a motor's: load / (gain gear); gap-sim13:
        a velocity-mode head replayed each log's first 50 ms at its position in rad/s, 33 mrad
        off; 0.8 now), other servos the measured position, an
        integrating servo's velocity goal 0; without joint-named actuators the first goal."""
        tr = self.ds.trajectories[traj]
        if not set(tr.actuators) <= set(tr.joints):
            return tr.goal[0]
        m = self.models[tr.model]
        acts = self._act_idx[(tr.model, False)]
        prev = tr.qpos[0, [tr.joints.index(a) for a in tr.actuators]] * m.actuator_gear[acts, 0]
        for col, a in enumerate(acts):
            if position_like(m, int(a)) and m.actuator_dyntype[a] == mujoco.mjtDyn.mjDYN_NONE:
                kp, gear = float(m.actuator_gainprm[a, 0]), float(m.actuator_gear[a, 0])
                joint = m.joint(int(m.actuator_trnid[a, 0])).name
                if joint in tr.joints:
                    prev[col] += self._acts.static_load(traj, joint) / (kp * gear)
            elif (m.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
                  and m.actuator_dyntype[a] == mujoco.mjtDyn.mjDYN_NONE
                  and m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
                  and m.actuator_biasprm[a, 1] == 0 and m.actuator_gainprm[a, 0] != 0):
                # a velocity actuator's rate or a motor's force (no position term): the
                # command whose force holds the static load at the first measured speed
                # (gear kv (ctrl - gear qdot) = load; was the position itself)
                joint = m.joint(int(m.actuator_trnid[a, 0])).name
                gear = float(m.actuator_gear[a, 0])
                if joint in tr.joints:
                    qd = float(tr.qvel[0, tr.joints.index(joint)])
                    prev[col] = (self._acts.static_load(traj, joint) / gear - float(
                        m.actuator_biasprm[a, 2]) * gear * qd) / float(m.actuator_gainprm[a, 0])
                else:
                    prev[col] = 0.0
        for col, _, _ in self._acts.integrators((tr.model, False)):
            prev[col] = 0.0  # an integrating servo at rest: velocity goal 0
        return prev

    def _position_servos(self, key: tuple[str, bool]
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Fixed-gain position servos acting on their ctrl directly (no activation dynamics)
        among the logged actuators: (their columns in the log's actuator list, model actuator
        ids, qpos and dof addresses of the joints they drive, gears)."""
        cache = self.__dict__.setdefault("_pos_servos", {})
        if key not in cache:
            m = self._variants[key]
            cols, acts, qadr, dadr, gear = [], [], [], [], []
            for col, a in enumerate(self._act_idx[key]):
                if (position_like(m, a)
                        and m.actuator_dyntype[a] == mujoco.mjtDyn.mjDYN_NONE):
                    jid = int(m.actuator_trnid[a, 0])
                    cols.append(col)
                    acts.append(int(a))
                    qadr.append(int(m.jnt_qposadr[jid]))
                    dadr.append(int(m.jnt_dofadr[jid]))
                    gear.append(float(m.actuator_gear[a, 0]))
            cache[key] = (np.array(cols, int), np.array(acts, int),
                          np.array(qadr, int), np.array(dadr, int), np.array(gear, float))
        return cache[key]

    # ------------------------------------------------------------------------------------------
    def run(self, windows: Sequence[Window], columns: Sequence[Column],
            force_peak: bool = False, goal_shift: float = 0.0
            ) -> tuple[list[list[np.ndarray]], np.ndarray | None]:
        """Simulate every (column, window) pair.

        Args:
          windows: windows to replay.
          columns: candidate effect sets (each a list of AppliedEffect on the data set's joints).
          force_peak: also return the peak |actuator force| x |gear| (the torque at the
            joint) per column and actuator.
          goal_shift: every goal arrives this much later [s] (on top of a column's latency):
          a probe of how much the predictions depend on a change far below what a log's
          timestamps resolve (``analyze``'s replay chaos).
        Returns:
          (pred, peaks): pred[c][w] is (n_w, nj) predicted readings [rad] at the window's
          samples; peaks is (ncol, na) [N m] or None.
        """
        if (force_peak or goal_shift or not columns
                or not all(e.name in CAUSES for c in columns for e in c)):  # noise: rng
            return self._run(windows, columns, force_peak, goal_shift)
        # a column already replayed on these windows is not replayed again (a fit's restart
        # point, a scan's best grid value, the select split's predictions of the current
        # model): the same simulations give the same predictions
        wkey = tuple(windows)
        keys = [(wkey, _column_key(c)) for c in columns]
        todo: dict[tuple, int] = {}
        for c, key in enumerate(keys):
            if key not in self._memo and key not in todo:
                todo[key] = c
        fresh: dict[tuple, list[np.ndarray]] = {}
        if todo:
            fresh = dict(zip(todo, self._run(windows, [columns[c] for c in todo.values()])[0],
                             strict=True))
        self.memo_hits += len(columns) - len(todo)
        out = []
        for key in keys:
            if key not in fresh:
                self._memo.move_to_end(key)
            out.append(list(fresh[key] if key in fresh else self._memo[key]))
        for key, p in fresh.items():  # after reading: remembering may forget older columns
            self._remember(key, p)
        return out, None

    def _remember(self, key: tuple, pred: list[np.ndarray]) -> None:
        """Keep a column's predictions (least recently used ones go beyond ``_MEMO_BYTES``)."""
        for p in pred:
            p.setflags(write=False)  # shared by every later caller
        self._memo[key] = pred
        self._memo_bytes += sum(p.nbytes for p in pred)
        while self._memo_bytes > _MEMO_BYTES and len(self._memo) > 1:
            _, old = self._memo.popitem(last=False)
            self._memo_bytes -= sum(p.nbytes for p in old)

    def _run(self, windows: Sequence[Window], columns: Sequence[Column],
             force_peak: bool = False, goal_shift: float = 0.0
             ) -> tuple[list[list[np.ndarray]], np.ndarray | None]:
        # a column with a structural effect (backlash) runs twice: with its hidden dofs (the
        # play hinge) and without (the massless-motor play operator); the regime closer to the
        # data is kept (``_keep_closer``)
        n_col = len(columns)
        dual = [c for c, col in enumerate(columns) if any(e.cls.structural for e in col)]
        columns = list(columns) + [columns[c] for c in dual]
        groups: dict[tuple[str, bool, bool], list[tuple[int, int]]] = {}
        for c, col in enumerate(columns):
            fric = any(e.cls.substep(e.values) for e in col)
            structural = c < n_col and any(e.cls.structural for e in col)
            for wi, w in enumerate(windows):
                key = (self.ds.trajectories[w.traj].model, structural, fric)
                groups.setdefault(key, []).append((c, wi))
        pred: list[list[np.ndarray | None]] = [[None] * len(windows) for _ in columns]
        peaks = np.zeros((len(columns), len(self.ds.actuators))) if force_peak else None
        carried = play_state.carry(self, windows, columns, groups, goal_shift, self.preroll)
        runs = [self._setup(key, sims, windows, columns, goal_shift, carried)
                for key, sims in groups.items()]
        n_max = max(r["n_steps"] for r in runs)
        for k in range(n_max + 1):
            for r in runs:
                if k <= r["n_steps"]:
                    self._advance(r, k, force_peak)
        for r in runs:
            for s, (c, wi) in enumerate(r["sims"]):
                g = self.grid(windows[wi])
                q = r["record"][s]
                i0 = np.minimum(np.floor(g.frac).astype(int), r["n_steps"] - 1)
                a = (g.frac - i0)[:, None]
                pred[c][wi] = (1 - a) * q[i0] + a * q[i0 + 1]
                if force_peak:
                    peaks[c] = np.maximum(peaks[c], r["peak"][s])
        self._acts.anchor(windows, pred)
        for i, c in enumerate(dual):
            if self._closer(windows, pred[n_col + i], pred[c]):
                pred[c] = pred[n_col + i]
                if force_peak:
                    peaks[c] = peaks[n_col + i]
        if force_peak:
            peaks = peaks[:n_col]
        return pred[:n_col], peaks  # type: ignore[return-value]

    def _closer(self, windows: Sequence[Window], a: list[np.ndarray], b: list[np.ndarray]
                ) -> bool:
        """Whether predictions ``a`` fit the measured readings (scored samples) better than
        ``b`` (sum of squares)."""
        sse = np.zeros(2)
        for w, pa, pb in zip(windows, a, b, strict=True):
            q = self.ds.trajectories[w.traj].qpos[w.score_from:w.stop]
            k = w.score_from - w.start
            sse += [np.sum((pa[k:] - q) ** 2), np.sum((pb[k:] - q) ** 2)]
        return bool(sse[0] < sse[1])

    def _setup(self, key: tuple[str, bool, bool], sims: list[tuple[int, int]],
               windows: Sequence[Window], columns: Sequence[Column],
               goal_shift: float = 0.0, carried: dict | None = None) -> dict:
        model_key = key[:2]  # (model, structural variant)
        model = self._variants[model_key]
        union = _union([columns[c] for c, _ in sims])
        per_sim = [_fill(columns[c], union) for c, _ in sims]
        nsim = len(sims)
        pkey = (model_key, tuple(union), nsim)
        plant = self._plants.get(pkey)
        if plant is None:
            if len(self._plants) > 24:
                self._plants.clear()
            # small batches step faster on one thread than on a (loaded) pool
            nthread = 1 if nsim < 128 else self.nthread
            plant = BatchPlant(model, nsim, per_sim, nthread=nthread,
                               servo_period=self.ds.servo_period)
            self._plants[pkey] = plant
        else:
            plant.set_effects(per_sim)
        ds = self.ds
        act = self._act_idx[model_key]
        jq, jd = self._jnt_qpos[model_key], self._jnt_dof[model_key]
        grids = [self.grid(windows[wi]) for _, wi in sims]
        n_steps = max(g.n_steps for g in grids)
        qpos = np.tile(model.qpos0, (nsim, 1))
        qvel = np.zeros((nsim, model.nv))
        ctrl = np.zeros((nsim, model.nu))
        rows = np.zeros((nsim, n_steps), dtype=int)
        goals = np.zeros((nsim, n_steps, len(act)))
        split = np.full((nsim, n_steps, len(act)), np.nan)
        before, after = np.zeros_like(goals), np.zeros_like(goals)
        delays = self._delays(model_key, sims, columns) + max(goal_shift, 0.0)
        traj_of = np.array([windows[wi].traj for _, wi in sims])
        for s, ((c, wi), g) in enumerate(zip(sims, grids, strict=True)):
            w = windows[wi]
            tr = ds.trajectories[w.traj]
            off, gain = reading_map(columns[c], ds.joints)
            qpos[s, jq], qvel[s, jd] = (tr.qpos[w.start] - off) / gain, tr.qvel[w.start] / gain
            ctrl[s, act] = g.prev_goal
            rows[s, :g.n_steps], rows[s, g.n_steps:] = g.rows, g.rows[-1]
            if np.any(delays[s] > 0):
                g_goals, g_split, g_before, g_after = self._shifted(w, delays[s])
            else:
                g_goals, g_split, g_before, g_after = g.goals, g.split[:, None], g.before, g.after
            goals[s, :g.n_steps], goals[s, g.n_steps:] = g_goals, g_goals[-1]
            split[s, :g.n_steps] = g_split
            before[s, :g.n_steps], after[s, :g.n_steps] = g_before, g_after
        played = set() if key[1] else _init_backlash(ctrl, act, self._act_of_joint[model_key],
                                                      sims, windows, columns, ds)
        trs = ds.trajectories
        has_te = any("torque_enable" in tr.channels for tr in trs)
        te = None
        if has_te:
            te = np.stack([trs[t].channels["torque_enable"][gi] > 0.5
                           if "torque_enable" in trs[t].channels
                           else np.ones((len(gi), len(act)), bool)
                           for t, gi in zip(traj_of, rows, strict=True)])
            # the first step's torque state before the reset's forward pass (the actuator
            # forces the first step's friction reads): a plant reused from an earlier replay
            # still holds the torque state its last step had there
            self._set_torque(dict(plant=plant, act=act, te=te, n_steps=n_steps, torque=None), 0)
        plant.reset(qpos, qvel, ctrl, ctrl_history=self._history(model, ctrl, act, sims,
                                                                 windows, played),
                    act=self._acts.setpoints(model_key, sims, windows, delays,
                                             plant.array("actuator_gainprm"),
                                             plant.array("actuator_dynprm")
                                             if self._acts.slews(model_key) else None))
        have = [s for s, cw in enumerate(sims) if carried and cw in carried]
        if have:  # play states carried from the log before each window (``play_state``)
            arrs = [np.array([carried[sims[s]][i] for s in have]) for i in range(3)]
            play_state.place(plant, ds.effect_joints, *arrs, sims=np.array(have),
                             share=play_state.shares(columns, [sims[s][0] for s in have],
                                                     ds.effect_joints))
        shifted = np.flatnonzero(np.any(delays > 0, axis=1))
        if len(shifted):  # their goals arrive late on the grid: no native (interpolated) delay
            plant.array("actuator_delay")[np.ix_(shifted, act)] = 0.0
        # channels per simulation on the grid: (nsim, K, na), gathered once
        chans = {ch: np.stack([trs[t].channels[ch][gi] for t, gi in
                               zip(traj_of, rows, strict=True)])
                 for ch in plant.required_channels}
        if "voltage" in chans:  # a drive's nominal supply: the log's unloaded (highest) reading
            top = [np.max(trs[t].channels["voltage"], axis=0) for t in traj_of]
            chans["supply"] = np.stack([np.broadcast_to(v, rows.shape[1:] + v.shape) for v in top])
        run = dict(plant=plant, sims=sims, n_steps=n_steps, act=act, jq=jq, goals=goals,
                   split=split, before=before, after=after,
                   servos=self._position_servos(model_key),
                   gear=model.actuator_gear[act, 0],
                   chans=chans, te=te, full_goal=np.array(ctrl),
                   full_chans={ch: np.zeros_like(ctrl) for ch in chans},
                   record=np.empty((nsim, n_steps + 1, len(jq))),
                   peak=np.zeros((nsim, len(act))), torque=None,
                   own=np.array([g.n_steps for g in grids]), ids=None,
                   until=min(g.n_steps for g in grids))
        self._set_torque(run, 0)
        return run

    def _delays(self, key: tuple[str, bool], sims: list[tuple[int, int]],
                columns: Sequence[Column]) -> np.ndarray:
        """(nsim, na) goal latency of each logged actuator in each simulation [s] (0: none)."""
        out = np.zeros((len(sims), len(self.ds.actuators)))
        cache = self.__dict__.setdefault("_lat_cols", {})
        for s, (c, _) in enumerate(sims):
            for e in columns[c]:
                if e.name != "latency":
                    continue
                tk = (key, tuple(e.joints))
                if tk not in cache:
                    cache[tk] = [self._act_of_joint[key].get(j) for j in e.joints]
                seen = set()  # a tendon's servo: its first joint's delay (``Targets.owners``)
                for col, d in zip(cache[tk], e.values["delay"], strict=True):
                    if col is not None and col not in seen:
                        out[s, col] = max(float(d), 0.0)
                        seen.add(col)
        return out

    def _shifted(self, w: Window, delay: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The window's goals on the grid when each actuator's goals arrive ``delay`` [s] late.

        A latency is a goal queue: the goal written at t acts from t + delay, exactly (the
        step mean and the saturation matching as for undelayed goals), not through MuJoCo's
        actuator delay, whose linear interpolation of ctrl leads a saturating servo as a
        step-rounded goal did. Goals written before the window that arrive inside it act
        there. Until the log's first goal arrives the servo holds what it held when the log
        began: the measured position (``_rest_goal``, as for goals that take effect after
        the first read), not the first goal: a LEAP-like finger logged at 50 Hz with a 30 ms
        latency otherwise started every log moving 30 ms early (up to 70 mrad off; the true
        model replayed at 8.6 mrad RMSE where plain MuJoCo gives 1.6, and the fit took
        23-29 ms and a spurious inertia_error). Returns (goals (K, na), split (K, na),
        before (K, na), after (K, na)) as in ``_Grid``.
        """
        g = self.grid(w)
        tr = self.ds.trajectories[w.traj]
        n, na = g.n_steps, len(delay)
        goals = np.empty((n, na))
        split = np.full((n, na), np.nan)
        before, after = np.zeros((n, na)), np.zeros((n, na))
        rest = None
        for j in range(na):
            u_all = (tr.goal_times + delay[j] - tr.time[w.start]) / self.dt
            first = int(np.searchsorted(u_all, 0.0, side="right"))
            last = int(np.searchsorted(u_all, n, side="left"))
            if first == 0 and rest is None:
                rest = self._rest_goal(w.traj)
            prev = np.array([tr.goal[first - 1, j] if first > 0 else rest[j]])
            if last <= first:
                goals[:, j] = prev[0]
                continue
            u, vals = u_all[first:last], tr.goal[first:last, j:j + 1]
            goals[:, j] = _step_means(u, vals, prev, n)[:, 0]
            sp, bf, af = _single_switches(u, vals, prev, n)
            split[:, j], before[:, j], after[:, j] = sp, bf[:, 0], af[:, 0]
        return goals, split, before, after

    def _history(self, model: mujoco.MjModel, ctrl: np.ndarray, act: np.ndarray,
                 sims: list[tuple[int, int]], windows: Sequence[Window], played: set[int]
                 ) -> np.ndarray | None:
        """Past goals for the delay buffers: (nsim, n, nu), oldest first, ending at each
        window's start (so a latency replayed from mid-log sees the commands it would have)."""
        n = int(model.actuator_history[:, 0].max()) if model.nu else 0
        if n == 0:
            return None
        hist = np.repeat(ctrl[:, None, :], n, axis=1)
        offsets = (np.arange(n) - (n - 1)) * self.dt  # ..., -2 dt, -dt, 0
        for s, (_, wi) in enumerate(sims):
            w = windows[wi]
            if w.start == 0 or s in played:
                continue
            tr = self.ds.trajectories[w.traj]
            tau = tr.time[w.start] + offsets[:-1] + 0.5 * self.dt
            idx = np.clip(np.searchsorted(tr.goal_times, tau, side="right") - 1, 0, w.start - 1)
            hist[s, :-1][:, act] = tr.goal[idx]
        return hist

    def _set_torque(self, run: dict, k: int) -> None:
        if run["te"] is None:
            return
        plant, act = run["plant"], run["act"]
        on = run["te"][:, min(k, run["n_steps"] - 1)]  # (nsim, na)
        if run["torque"] is not None and np.array_equal(on, run["torque"]):
            return
        for j, a in enumerate(act):
            rows_on, rows_off = np.flatnonzero(on[:, j]), np.flatnonzero(~on[:, j])
            if len(rows_on):
                plant.set_torque_enabled([a], True, sims=rows_on)
            if len(rows_off):
                plant.set_torque_enabled([a], False, sims=rows_off)
        run["torque"] = on

    def _advance(self, run: dict, k: int, force_peak: bool) -> None:
        plant = run["plant"]
        run["record"][:, k] = plant.measured_qpos()[:, run["jq"]]
        if force_peak and k > 0:  # at the joint: gear x actuator force
            f = np.abs(plant.actuator_force[:, run["act"]] * run["gear"])
            np.maximum(run["peak"], f, out=run["peak"])
        if k == run["n_steps"]:
            return
        act = run["act"]
        goal = run["full_goal"]
        goal[:, act] = run["goals"][:, k]
        saturation.match(run, k, goal)
        channels = None
        if run["chans"]:
            channels = run["full_chans"]
            for ch, arr in run["chans"].items():
                channels[ch][:, act] = arr[:, k]
        if run["te"] is not None:
            self._set_torque(run, k)
        # a simulation past its window's last grid step is not advanced (its records there
        # are never read; its peak force is, so all advance when peaks are asked for)
        if k >= run["until"] and not force_peak:
            alive = run["own"] > k
            # (the batch checks the ids, ~3 us a call: worth it from two idle simulations on)
            run["ids"] = (np.flatnonzero(alive).astype(np.int32)
                          if len(alive) - np.count_nonzero(alive) >= 2 else None)
            run["until"] = int(run["own"][alive].min())
        ids = None if force_peak else run["ids"]
        plant.step_unchecked(goal, 1, channels, sims=ids)  # goals checked in __init__
        self.steps_run += plant.nsim if ids is None else len(ids)


def _check_goals(ds: object) -> None:
    """ConfigError unless ``ds`` is a Dataset whose goals are finite numbers below
    ``MAX_CONTROL`` (a NaN one would zero every control of its step in MuJoCo)."""
    if not isinstance(ds, Dataset):
        raise ConfigError(f"Replayer(ds) replays a lowcostdex.gap.Dataset (from load_dataset), "
                          f"not {type(ds).__name__}")
    for tr in ds.trajectories:
        check_finite_array(f"trajectory {tr.name!r}: goal", tr.goal, (np.shape(tr.goal),),
                           f"goals of the actuators {', '.join(tr.actuators)}")


def _step_means(u: np.ndarray, values: np.ndarray, before: np.ndarray, n_steps: int
                ) -> np.ndarray:
    """Mean of a zero-order-held signal over each physics step.

    Args:
      u: (n,) increasing switch instants in steps (>= 0): ``values[i]`` holds from ``u[i]``.
      values: (n, k) values.
      before: (k,) value before ``u[0]``.
      n_steps: steps [k, k + 1) to average, k = 0 .. n_steps - 1.
    Returns:
      (n_steps, k) step means.
    """
    u = np.asarray(u, float)
    v = np.asarray(values, float)
    before = np.asarray(before, float)
    # integral of the signal from 0 to each switch instant
    c = np.empty_like(v)
    c[0] = before * u[0]
    if len(u) > 1:
        c[1:] = c[0] + np.cumsum(v[:-1] * np.diff(u)[:, None], axis=0)
    x = np.arange(n_steps + 1, dtype=float)
    i = np.searchsorted(u, x, side="right") - 1
    ii = np.maximum(i, 0)
    integral = np.where((i >= 0)[:, None], c[ii] + v[ii] * (x - u[ii])[:, None],
                        before[None, :] * x[:, None])
    return np.diff(integral, axis=0)


def _single_switches(u: np.ndarray, values: np.ndarray, before: np.ndarray, n_steps: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps holding exactly one goal switch strictly inside them.

    Args: as ``_step_means``.
    Returns:
      (split (n_steps,) fraction of the step before the switch, NaN elsewhere; the goal before
      and after the switch, (n_steps, k) each).
    """
    u = np.asarray(u, float)
    v = np.asarray(values, float)
    split = np.full(n_steps, np.nan)
    old = np.zeros((n_steps, v.shape[1]))
    new = np.zeros((n_steps, v.shape[1]))
    k = np.floor(u).astype(int)
    frac = u - k
    one = (k >= 0) & (k < n_steps) & (frac > 0)
    one[1:] &= k[1:] != k[:-1]
    one[:-1] &= k[:-1] != k[1:]
    i = np.flatnonzero(one)
    split[k[i]] = frac[i]
    old[k[i]] = np.vstack([before[None, :], v])[i]
    new[k[i]] = v[i]
    return split, old, new


def _column_key(col: Column) -> tuple:
    """A hashable key of a column's effects and their exact values (order kept: effects act
    in the column's order)."""
    return tuple((e.name, tuple(e.joints),
                  tuple((k, np.asarray(v, float).tobytes()) for k, v in sorted(e.values.items())))
                 for e in col)


def _union(cols: Sequence[Column]) -> list[tuple[str, tuple[str, ...]]]:
    seen: dict[tuple[str, tuple[str, ...]], None] = {}
    for col in cols:
        for e in col:
            seen[(e.name, tuple(e.joints))] = None
    return sorted(seen, key=lambda x: (_ORDER[x[0]], x[1]))


def _fill(col: Column, union: Sequence[tuple[str, tuple[str, ...]]]) -> list[AppliedEffect]:
    have = {(e.name, tuple(e.joints)): e for e in col}
    return [have.get(u) or AppliedEffect(u[0], u[1]) for u in union]


def _init_backlash(ctrl: np.ndarray, act: np.ndarray, act_of_joint: dict[str, int],
                   sims: list[tuple[int, int]], windows: Sequence[Window],
                   columns: Sequence[Column], ds: Dataset) -> set[int]:
    """Set the setpoint before each window to the play state the preceding goals leave.

    Args:
      ctrl: (nsim, nu) setpoints to edit.
      act: model actuator index of each log actuator.
      act_of_joint: joint name -> index into the log's actuators of the servo driving it.
    Returns:
      the simulations whose setpoint was set from the play.
    """
    jobs: dict[int, list[tuple[int, int, list[int], np.ndarray]]] = {}
    for s, (c, wi) in enumerate(sims):
        w = windows[wi]
        for e in columns[c]:
            if e.name != "backlash" or w.start == 0 or not np.any(e.values["width"] > 0):
                continue
            cols = [act_of_joint[j] for j in e.joints]
            jobs.setdefault(w.traj, []).append((s, w.start, cols, np.asarray(e.values["width"])))
    for t, items in jobs.items():
        goals = ds.trajectories[t].goal
        na = goals.shape[1]
        half = np.zeros((len(items), na))
        starts = np.array([it[1] for it in items])
        for r, (_, _, cols, width) in enumerate(items):
            half[r, cols] = 0.5 * width
        state = np.tile(goals[0], (len(items), 1))
        change = np.flatnonzero(np.any(np.diff(goals[:starts.max()], axis=0) != 0, axis=1)) + 1
        for i in change:
            live = starts > i
            g = goals[i]
            state[live] = np.clip(state[live], g - half[live], g + half[live])
        for r, (s, _, cols, _) in enumerate(items):
            ctrl[s, act[cols]] = state[r, cols]
    return {s for items in jobs.values() for s, *_ in items}
