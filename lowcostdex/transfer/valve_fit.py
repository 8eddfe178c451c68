"""The transfer loop's valve-log fit (issue 14, transfer15-17): what the identified conditions'
D'Claw geometry and valve are.

The robot (valve on) plays ``Size.valve_episodes`` valve episodes made from the folder's
playback demonstrations and its valve encoder is logged: episode k is the k-th playback's goals
played as design ``DESIGNS[k % 5]`` (as recorded, at double speed then held, at half speed,
stopping for 3 steps after every 5, twice in a row). The playbacks are near-duplicates (goals
within 0.005 of each other): fitted to one motion at one speed, the model turned the valve
0.04-0.07 rad too far on the policies' last push on robot C (transfer16); fitted to the varied
episodes it predicts that push within 0.02-0.05 rad short, with a valve that is NOT C's (dry
friction 4.6 x C's: it stands for what the model lacks), and (c) seed 1 on C went from 0/50 to
50/50 (transfer17, bench/RESULTS.md). Then, in the identified model (the nominal D'Claw plus
the servo effects ``gap analyze`` named, held fixed: ``condition_randomize("identified")``),
one finger base's mounting tilt is fitted JOINTLY with the valve hinge's dry
friction, damping and inertia and each finger's link lengths (``tilt_joint.fit_tilt_jointly``:
a tilt grid, bounded Gauss-Newton, profile intervals paired across the episodes), once for each
finger of ``Size.valve_fingers``. The fit with the lowest cost becomes the ``model_edit``
(``sim.models.dclaw_edit.DClawEdit``) the identified conditions train and are evaluated in;
``pick_finger`` says beside it whether the log names that finger's tilt (a single finger's fit
always finds some tilt: the lengths and a wrong finger's tilt trade against each other, see
bench/RESULTS.md transfer15). Nothing here reads a hidden robot's definition: the robot is only
driven through its ``env_kwargs`` (the emulated bus).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from lowcostdex.sim.models.dclaw_edit import FINGERS, DClawEdit

# the fitted parameters x: the tilt (rotation vector about the base's x, y) first
NAMES = ("tilt_x [rad]", "tilt_y [rad]", "valve frictionloss + [N m]", "valve damping x",
         "valve inertia x", *(f"{f} link length x" for f in FINGERS))
X0 = (0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0)
LOWER = (-0.12, -0.12, 0.0, 0.3, 0.4, 0.9, 0.9, 0.9)
UPPER = (0.12, 0.12, 0.05, 3.0, 2.5, 1.1, 1.1, 1.1)
STEP = (2e-3, 2e-3, 1e-3, 0.05, 0.05, 0.005, 0.005, 0.005)
VALVE_PAD = 0.3  # (d): valve ranges at least +-30 % of the fitted friction and damping
GRID = 9  # tilt grid points per axis over +-0.1 rad (``fit_tilt_jointly``'s global start)
STEP_SECONDS = 0.1  # the valve task's control period [s]
# how the k-th valve episode plays its playback's goals (``design``), cycling
DESIGNS = ("playback", "fast", "slow", "stop_and_go", "twice")


def edit_from_params(finger: str, x: Any) -> DClawEdit:
    """The model edit of parameters ``x`` (``NAMES``) with the tilt on ``finger``'s base."""
    x = np.asarray(x, float)
    return DClawEdit(base_tilt={finger: (float(x[0]), float(x[1]))},
                     link_length={f: float(v) for f, v in zip(FINGERS, x[5:8], strict=True)},
                     valve_frictionloss=float(x[2]), valve_damping=float(x[3]),
                     valve_inertia=float(x[4]))


def playback_goals(demos: Path, n: int) -> list[tuple[int, np.ndarray]]:
    """The reset seed and actions of the first ``n`` playback demonstrations (one per seed)."""
    import h5py

    with h5py.File(demos, "r") as f:
        seen: set[int] = set()
        eps = []
        for k in sorted(f, key=lambda k: int(k.split("_")[1])):
            e = f[k]
            if e.attrs["source"] == "playback" and int(e.attrs["seed"]) not in seen:
                seen.add(int(e.attrs["seed"]))
                eps.append((int(e.attrs["seed"]), e["actions"][()]))
    return eps[:n]


def design(actions: np.ndarray, name: str) -> np.ndarray:
    """A playback's goals (steps, 9) played another way (``DESIGNS``): "playback" as recorded;
    "fast" every other goal, then the last one held to the same length; "slow" at half speed
    (goals interpolated linearly, twice the steps); "stop_and_go" each 5th goal held 3 more
    steps; "twice" the whole sequence again from where the first pass left the valve."""
    from lowcostdex.errors import check_choice

    check_choice("valve episode design", name, DESIGNS)
    a = np.asarray(actions, float)
    if name == "fast":
        half = a[::2]
        return np.concatenate([half, np.repeat(half[-1:], len(a) - len(half), axis=0)])
    if name == "slow":
        t = np.arange(2 * len(a)) / 2  # (the last goal held one step more)
        return np.stack([np.interp(t, np.arange(len(a)), a[:, j]) for j in range(a.shape[1])],
                        axis=1)
    if name == "stop_and_go":
        return np.repeat(a, np.where(np.arange(len(a)) % 5 == 4, 4, 1), axis=0)
    if name == "twice":
        return np.concatenate([a, a])
    return a


def valve_episodes(demos: Path, n: int, varied: bool = True) -> list[tuple[int, np.ndarray]]:
    """The valve log's ``n`` episodes (reset seed, goals): the first ``n`` playbacks, the k-th
    played as ``DESIGNS[k % 5]`` (``varied``) or as recorded."""
    eps = playback_goals(demos, n)
    if not varied:
        return eps
    return [(seed, design(a, DESIGNS[k % len(DESIGNS)])) for k, (seed, a) in enumerate(eps)]


def valve_trace(env_id: str, env_kwargs: dict[str, Any], eps: list[tuple[int, np.ndarray]]
                ) -> np.ndarray:
    """The valve encoder [rad, unwrapped] of the episodes played (their reset seed, then their
    actions) in ``gym.make(env_id, **env_kwargs)``: the robot, or a simulation."""
    import gymnasium as gym

    import lowcostdex.sim  # noqa: F401  (registers the ids)

    env = gym.make(env_id, **env_kwargs)
    out = []
    try:
        for seed, actions in eps:
            env.reset(seed=seed)
            for a in actions:
                env.step(a)
                out.append(env.unwrapped.backend.observed_qpos()[9])  # the valve's encoder
    finally:
        env.close()
    return np.unwrap(np.asarray(out, float))


def episode_sse(trace: np.ndarray, observed: np.ndarray, lengths: list[int]) -> list[float]:
    """Squared valve error summed per episode [rad^2]."""
    edges = np.cumsum([0, *lengths])
    d2 = (np.asarray(trace) - observed) ** 2
    return [float(d2[a:b].sum()) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def pick_finger(rows: list[dict[str, Any]]) -> str:
    """Which finger's tilt the log names: among the fingers whose fit names a tilt, the one with
    the lowest cost when the episodes show it better than every other named finger's fit (paired
    one-sided t test across episodes, 5 %); "none", or "ambiguous: ..." naming the ties."""
    from scipy.stats import ttest_rel

    named = [r for r in rows if r["named"]]
    if not named:
        return "none"
    best = min(named, key=lambda r: sum(r["episode_sse"]))
    ties = [r["finger"] for r in named if r is not best and ttest_rel(
        best["episode_sse"], r["episode_sse"], alternative="less").pvalue > 0.05]
    return best["finger"] if not ties else f"ambiguous: {best['finger']} or {', '.join(ties)}"


def fit_valve_log(robot_kwargs: dict[str, Any], env_id: str, task_kwargs: dict[str, Any],
                  demos: Path, randomize: Any, episodes: int,
                  fingers: tuple[str, ...] = FINGERS, fit: dict[str, Any] | None = None,
                  varied: bool = True) -> dict[str, Any]:
    """Record the valve log on the robot (``robot_kwargs``: its ``env_kwargs()``) and fit the
    geometry / valve edit in the identified model ``randomize`` (None: nominal). ``fit``:
    ``fit_tilt_jointly`` overrides (``grid`` as a number of points per axis); ``varied``: the
    episodes' ``DESIGNS`` (False: every playback as recorded, transfer16's log). JSON out."""
    from lowcostdex.transfer.tilt_joint import fit_tilt_jointly

    eps = valve_episodes(demos, episodes, varied)
    if len(eps) < 2:
        raise ValueError(f"the valve-log fit needs >= 2 playback demonstrations in {demos}; "
                         f"found {len(eps)}")
    t0 = time.perf_counter()
    observed = valve_trace(env_id, {**task_kwargs, **robot_kwargs}, eps)
    record_wall = time.perf_counter() - t0
    lengths = [len(a) for _, a in eps]
    groups = np.repeat(np.arange(len(eps)), lengths)
    sim = {**task_kwargs, **({} if randomize is None else {"randomize": randomize})}
    options = dict(fit or {})
    grid = np.linspace(-0.1, 0.1, int(options.pop("grid", GRID)))
    rows = []
    t1 = time.perf_counter()
    for finger in fingers:
        c0 = time.process_time()
        result = fit_tilt_jointly(
            lambda x, f=finger: valve_trace(env_id, {
                **sim, "model_edit": edit_from_params(f, x).to_dict()}, eps),
            observed, X0, LOWER, UPPER, STEP, grid=grid, groups=groups, **options)
        fitted = valve_trace(env_id, {**sim, "model_edit": edit_from_params(
            finger, result.values).to_dict()}, eps)
        rows.append({"finger": finger, "values": result.values.tolist(),
                     "intervals": result.intervals.tolist(), "named": result.named,
                     "rms_start_mrad": 1e3 * result.rms_start,
                     "rms_fit_mrad": 1e3 * result.rms_fit,
                     "episode_sse": episode_sse(fitted, observed, lengths),
                     "evaluations": result.evaluations,
                     "cpu_seconds": round(time.process_time() - c0, 1)})
    used = min(rows, key=lambda r: sum(r["episode_sse"]))
    return {"episodes": len(eps), "robot_seconds": round(STEP_SECONDS * sum(lengths), 1),
            "designs": [DESIGNS[k % len(DESIGNS)] if varied else "playback"
                        for k in range(len(eps))],
            "identified": randomize is not None, "names": list(NAMES), "fits": rows,
            "named_finger": pick_finger(rows), "used_finger": used["finger"],
            "model_edit": edit_from_params(used["finger"], used["values"]).to_dict(),
            "record_wall_seconds": round(record_wall, 1),
            "fit_wall_seconds": round(time.perf_counter() - t1, 1),
            "fit_cpu_seconds": round(sum(r["cpu_seconds"] for r in rows), 1)}


def valve_ranges(fit: dict[str, Any]) -> dict[str, tuple[float, float]]:
    """Condition (d)'s per-episode ranges of the valve's added dry friction [N m] and damping
    factor: the used fit's 95 % intervals, at least +-``VALVE_PAD`` of each fitted value."""
    row = next(r for r in fit["fits"] if r["finger"] == fit["used_finger"])
    out = {}
    for name, k in (("valve_frictionloss", 2), ("valve_damping", 3)):
        v, (lo, hi) = row["values"][k], row["intervals"][k]
        lo = lo if np.isfinite(lo) else v
        hi = hi if np.isfinite(hi) else v
        out[name] = (float(max(LOWER[k], min(lo, v * (1 - VALVE_PAD)))),
                     float(min(UPPER[k], max(hi, v * (1 + VALVE_PAD)))))
    return out


def randomized_valve(randomize: dict[str, Any] | None, fit: dict[str, Any],
                     nominal_damping: float) -> tuple[dict[str, Any], dict[str, Any]]:
    """Condition (d) with the valve randomized per episode around its fit: the ``randomize``
    (a ``DomainRandomization.to_dict()`` over the hand joints, or None) and the ``model_edit``
    to train in. The edit holds the valve at the low end of ``valve_ranges``; the
    randomization adds ``coulomb_friction`` and ``viscous_damping`` on the valve joint, drawn up
    to the high end (the catalogue adds friction only, so the edit starts at the low end); the
    hand joints keep their ranges, the valve every other effect's null. ``nominal_damping``:
    the nominal model's valve damping [N m s/rad] (the edit's damping is a factor on it)."""
    from lowcostdex.sim.effects import DomainRandomization, effect

    ranges = valve_ranges(fit)
    (fl_lo, fl_hi), (d_lo, d_hi) = ranges["valve_frictionloss"], ranges["valve_damping"]
    edit = {**fit["model_edit"], "valve_frictionloss": fl_lo, "valve_damping": d_lo}
    base = DomainRandomization.from_dict(randomize) if randomize else DomainRandomization((), ())
    n = len(base.joints)
    valve = {"coulomb_friction": {"frictionloss": fl_hi - fl_lo},
             "viscous_damping": {"damping": nominal_damping * (d_hi - d_lo)}}
    effects = tuple(dict.fromkeys((*base.effects, *valve)))
    out: dict[str, dict[str, tuple[list[float], list[float]]]] = {}
    for name in effects:
        given = base.ranges.get(name, {})
        out[name] = {}
        for p in effect(name).params:
            if name in base.effects:  # the hand joints' ranges as they were
                lo, hi = given.get(p.name, p.dr)
            else:  # an effect only the valve carries: off on the hand joints
                lo = hi = p.null
            lo, hi = (np.broadcast_to(np.asarray(x, float), (n,)).tolist() for x in (lo, hi))
            top = valve.get(name, {}).get(p.name)
            lo.append(p.null)
            hi.append(p.null if top is None else p.null + top)
            out[name][p.name] = (lo, hi)
    dr = DomainRandomization(effects, (*base.joints, "valve"), out)
    return dr.to_dict(), DClawEdit.from_dict(edit).to_dict()


def describe(fit: dict[str, Any]) -> str:
    """One line: the edit the identified conditions use, and what the log names."""
    e = fit["model_edit"]
    tilt = next(iter(e["base_tilt"].items()))
    lengths = "/".join(f"{e['link_length'][f]:.3f}" for f in FINGERS)
    best = next(r for r in fit["fits"] if r["finger"] == fit["used_finger"])
    return (f"{fit['used_finger']} base tilt ({tilt[1][0]:.3f}, {tilt[1][1]:.3f}) rad, valve "
            f"frictionloss +{e['valve_frictionloss']:.4f} N m, damping x"
            f"{e['valve_damping']:.2f}, inertia x{e['valve_inertia']:.2f}, link lengths "
            f"ff/mf/th x{lengths}; valve RMS {best['rms_start_mrad']:.1f} -> "
            f"{best['rms_fit_mrad']:.1f} mrad over {fit['episodes']} episodes "
            f"({fit['robot_seconds']:g} s); tilt named: {fit['named_finger']}; fit CPU "
            f"{fit['fit_cpu_seconds']:g} s")
