"""Saturation matching of a goal switch inside a physics step, for ``gap.replay``.

A goal written a fraction ``a`` into a physics step drives a position servo with the old goal
for ``a`` of it and the new one for the rest. In the linear range the step's mean goal (what the
replay's ctrl holds) gives the same impulse; when the new goal saturates the force (a large
step), the mean goal saturates it for the whole step, a systematic lead that a torque limit
would then "explain". ``match`` gives such a servo the mean *force* of the old and new goals
instead, from the simulation's state and its (effect-modified) kp, kv and force range at the
step's start.

Its own module: it runs on every physics step of a replay that holds a goal switch, on the
``Replayer``'s run state only; the gains and force ranges it reads are gathered once per run
when nothing rewrites them between steps (no exogenous or live effect, no torque-enable
channel): the same values as reading them at each step.
"""

from __future__ import annotations

import numpy as np

from lowcostdex.sim.effects.base import clip as _clip


def match(run: dict, k: int, goal: np.ndarray) -> None:
    """Where a position servo saturates in step ``k`` holding a goal switch, replace its goal
    in ``goal`` (nsim, nu) by the one giving the mean force of the old and new goals, in place.

    Servos with an actuator delay keep the mean goal (they act on it later, from another
    state); a servo with an update period samples one goal at its update (nothing to match).
    """
    cols, acts, qadr, dadr, gear = run["servos"]
    if not len(cols) or run["plant"].servo_clock.every:
        return
    if "switches" not in run:
        _gather(run)
    if not run["switches"][k]:
        return
    plant = run["plant"]
    held = run["held"]
    if held is not None:  # the step's rows of the switches gathered for the run
        i, j = held["at"][k], held["at"][k + 1]
        sims, a, before, after, kp, kv, lo, hi, ok = (x[i:j] for x in held["rows"])
    else:
        sims = np.flatnonzero(run["switching"][k])
        a, before, after = (run[x][sims, k] for x in ("split_servos", "before_servos",
                                                       "after_servos"))
        kp, kv, lo, hi, delayed = _fields(plant, acts, sims[:, None])
        ok = np.isfinite(a) & (kp > 0) & ~delayed
    si = sims[:, None]
    # actuator length and velocity (gear times the joint's); force in actuator units
    q, qd = gear * plant.qpos[si, qadr], gear * plant.qvel[si, dadr]
    kvqd = kv * qd
    f_old = _clip(kp * (before - q) - kvqd, lo, hi)
    f_new = _clip(kp * (after - q) - kvqd, lo, hi)
    f_mean = a * f_old + (1 - a) * f_new
    # (where kp <= 0 it stays NaN: such a servo is not ``ok``)
    c = q + np.divide(f_mean + kvqd, kp, out=np.full(kp.shape, np.nan), where=kp > 0)
    # a delayed servo reads this ctrl later, in another state: it keeps the mean goal (not ok)
    live = np.isfinite(c) & ok
    cur = goal[si, acts]
    goal[si, acts] = np.where(live, c, cur)


def _gather(run: dict) -> None:
    """The run's steps holding a switch for some simulation's servo, once per run; when nothing
    rewrites the servos' gains and force ranges while the run steps (no measured channel, no
    torque-enable channel, no live effect), every switch's row too (``run["held"]``)."""
    cols, acts = run["servos"][:2]
    plant = run["plant"]
    split = run["split"][:, :, cols]  # (nsim, K, n servos)
    fin = np.isfinite(split)
    run["switches"] = np.any(fin, axis=(0, 2))
    # per step: the simulations switching and their servos' split, goals before / after
    run["switching"] = np.any(fin, axis=2).T  # (K, nsim)
    run["split_servos"] = split
    run["before_servos"] = run["before"][:, :, cols]
    run["after_servos"] = run["after"][:, :, cols]
    run["held"] = None
    if run["chans"] or run["te"] is not None or plant.live:
        return
    ks, sims = np.nonzero(run["switching"])  # by step, then simulation
    a = split[sims, ks]
    kp, kv, lo, hi, delayed = (x[sims] for x in _fields(plant, acts, slice(None)))
    rows = (sims, a, run["before_servos"][sims, ks], run["after_servos"][sims, ks],
            kp, kv, lo, hi, np.isfinite(a) & (kp > 0) & ~delayed)
    run["held"] = dict(rows=rows, at=np.searchsorted(ks, np.arange(len(run["switches"]) + 1)))
    for x in ("split_servos", "before_servos", "after_servos"):  # (in the rows now)
        del run[x]


def _fields(plant, acts: np.ndarray, rows) -> tuple[np.ndarray, ...]:
    """(kp, kv, force range low, high, delayed) of actuators ``acts`` in simulations ``rows``:
    (nsim, n servos) each, as the plant's model fields hold them now."""
    kp = plant.array("actuator_gainprm")[rows, acts, 0]
    kv = -plant.array("actuator_biasprm")[rows, acts, 2]
    rng_ = plant.array("actuator_forcerange")[rows, acts]
    lim = plant.array("actuator_forcelimited")[rows, acts] > 0
    lo, hi = np.where(lim, rng_[..., 0], -np.inf), np.where(lim, rng_[..., 1], np.inf)
    return kp, kv, lo, hi, plant.array("actuator_delay")[rows, acts] > 0
