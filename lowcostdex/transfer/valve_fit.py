"""The transfer loop's valve-log fit (issue 14, transfer15/16): what the identified conditions'
D'Claw geometry and valve are.

The robot (valve on) plays the goals of the folder's first ``Size.valve_episodes`` playback
demonstrations (4 s each) and its valve encoder is logged. Then, in the identified model (the
nominal D'Claw plus the servo effects ``gap analyze`` named, held fixed: ``condition_randomize
("identified")``), one finger base's mounting tilt is fitted JOINTLY with the valve hinge's dry
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
GRID = 9  # tilt grid points per axis over +-0.1 rad (``fit_tilt_jointly``'s global start)
EPISODE_SECONDS = 4.0  # a valve episode's robot time (40 steps of 0.1 s)


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
                  fingers: tuple[str, ...] = FINGERS, fit: dict[str, Any] | None = None
                  ) -> dict[str, Any]:
    """Record the valve log on the robot (``robot_kwargs``: its ``env_kwargs()``) and fit the
    geometry / valve edit in the identified model ``randomize`` (None: nominal). ``fit``:
    ``fit_tilt_jointly`` overrides (``grid`` as a number of points per axis). JSON out."""
    from lowcostdex.transfer.tilt_joint import fit_tilt_jointly

    eps = playback_goals(demos, episodes)
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
    return {"episodes": len(eps), "robot_seconds": EPISODE_SECONDS * len(eps),
            "identified": randomize is not None, "names": list(NAMES), "fits": rows,
            "named_finger": pick_finger(rows), "used_finger": used["finger"],
            "model_edit": edit_from_params(used["finger"], used["values"]).to_dict(),
            "record_wall_seconds": round(record_wall, 1),
            "fit_wall_seconds": round(time.perf_counter() - t1, 1),
            "fit_cpu_seconds": round(sum(r["cpu_seconds"] for r in rows), 1)}


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
