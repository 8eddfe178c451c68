"""Gap analysis benchmark: hidden-effect detection accuracy, false discoveries, wall clock.

For every canonical effect, magnitude level and rig, synthetic logs are generated from the nominal
model plus the hidden effect (quantized 4096 ticks/rev, read noise, timestamp jitter, drifting
temperature and sagging supply channels) and the analyzer, given only the nominal model and the
logs, must name the effect first and bring the held-out error near the floor (1.5x the larger of
the read-noise floor and the true model's own replay error). Effect-free
data must give "no significant discrepancy". The last part times one analysis of a single 60 s,
200 Hz log.

    python bench/gap_sweep.py                      # full sweep (about an hour on 2 loaded cores)
    python bench/gap_sweep.py --rigs bench --levels 0.5 --clean 3 --no-timing   # quick look

Targets (issue 6): detection >= 95 %, false discoveries 0, one 60 s log analysed in <= 60 s.
Prints a table per case and the ratios; ``--json`` writes the raw results.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from lowcostdex.gap.analyze import GapConfig, analyze
from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.generate import HIDDEN, LogSettings, generate
from lowcostdex.gap.replay import Replayer

PAIRS = (("latency", "coulomb_friction"), ("backlash", "gain_error"),
         ("position_offset", "viscous_damping"))


def run_case(rig: str, hidden: list[str], seed: int, level: float | None, n_logs: int,
             duration: float) -> dict:
    rng = np.random.default_rng(seed)
    syn = generate(rig, hidden, rng, n_logs=n_logs, duration=duration, level=level)
    ds = Dataset({"model": syn.xml}, syn.trajectories)
    t0 = time.perf_counter()
    res = analyze(ds, GapConfig(seed=seed))
    wall = time.perf_counter() - t0
    found = [c.effect for c in res.causes]
    floor = max(syn.settings.floor, _truth_rmse(ds, syn, res))
    if hidden:
        named = found[:len(hidden)] == hidden if len(hidden) == 1 else set(found) >= set(hidden)
        exact = set(found) == set(hidden)
    else:
        named = exact = not found
    near_floor = res.extended["heldout_rmse"] <= 1.5 * floor
    return {"rig": rig, "hidden": hidden, "seed": seed, "level": level, "found": found,
            "named": named, "exact": exact, "near_floor": bool(near_floor),
            "truth": {e.name: {p: v.tolist() for p, v in e.values.items()} for e in syn.hidden},
            "fitted": {c.effect: {p: d["value"] for p, d in c.params.items()}
                       for c in res.causes},
            "baseline_rmse": res.baseline["heldout_rmse"],
            "extended_rmse": res.extended["heldout_rmse"], "floor": floor, "wall_s": wall,
            "stop": res.stop_reason}


TIMING_CASES = (("bench", "latency"), ("bench", "stribeck_friction"), ("finger", "latency"))


def _truth_rmse(ds: Dataset, syn, res) -> float:
    """Held-out RMSE of the true model replayed like the extended one (the replay floor)."""
    if not syn.hidden:
        return 0.0
    test = [res.episodes[i] for i in res.split.test]
    pred = Replayer(ds, [e.name for e in syn.hidden]).run(test, [syn.hidden])[0][0]
    r = np.concatenate([ds.trajectories[w.traj].qpos[w.start:w.stop] - p
                        for w, p in zip(test, pred, strict=True)])
    return float(np.sqrt(np.mean(r * r)))


def timing_case(rig: str = "bench", effect: str = "latency", seed: int = 0) -> dict:
    """One 60 s log at 200 Hz with a hidden effect, analysed end to end."""
    rng = np.random.default_rng(seed)
    syn = generate(rig, [effect], rng, n_logs=1, duration=60.0,
                   settings=LogSettings(rate=200.0))
    t0 = time.perf_counter()
    ds = Dataset({"model": syn.xml}, syn.trajectories)
    res = analyze(ds, GapConfig(seed=seed))
    return {"rig": rig, "hidden": effect, "wall_s": time.perf_counter() - t0,
            "found": [c.effect for c in res.causes],
            "samples": len(syn.trajectories[0]), "timing": res.timing,
            "baseline_rmse": res.baseline["heldout_rmse"],
            "extended_rmse": res.extended["heldout_rmse"], "floor": syn.settings.floor}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rigs", nargs="+", default=["bench", "finger"])
    ap.add_argument("--effects", nargs="+", default=list(HIDDEN))
    ap.add_argument("--levels", nargs="+", type=float, default=[0.0, 0.5, 1.0],
                    help="magnitudes as fractions of each effect's plausible range")
    ap.add_argument("--clean", type=int, default=10, help="effect-free data sets per rig")
    ap.add_argument("--pairs", action="store_true", help="also hide two effects at once")
    ap.add_argument("--logs", type=int, default=3)
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--no-timing", action="store_true")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    results = []
    seed = args.seed
    for rig in args.rigs:
        for eff in args.effects:
            for level in args.levels:
                seed += 1
                r = run_case(rig, [eff], seed, level, args.logs, args.duration)
                results.append(r)
                _print(r)
        for _ in range(args.clean):
            seed += 1
            r = run_case(rig, [], seed, None, args.logs, args.duration)
            results.append(r)
            _print(r)
        if args.pairs:
            for pair in PAIRS:
                seed += 1
                r = run_case(rig, list(pair), seed, 0.5, args.logs, args.duration)
                results.append(r)
                _print(r)
    single = [r for r in results if len(r["hidden"]) == 1]
    clean = [r for r in results if not r["hidden"]]
    pairs = [r for r in results if len(r["hidden"]) == 2]
    out = {"machine": f"{platform.node()} {platform.processor() or platform.machine()}, "
                      f"{os.cpu_count()} CPUs", "date": time.strftime("%Y-%m-%d"),
           "results": results}
    if single:
        acc = np.mean([r["named"] for r in single])
        exact = np.mean([r["exact"] for r in single])
        floor = np.mean([r["near_floor"] for r in single])
        print(f"\ndetection: {100 * acc:.1f} % named first ({sum(r['named'] for r in single)}/"
              f"{len(single)}), {100 * exact:.1f} % with no extra effect, "
              f"{100 * floor:.1f} % within 1.5x the noise floor (target >= 95 %)")
        for rig in args.rigs:
            sub = [r for r in single if r["rig"] == rig]
            if sub:
                print(f"  {rig}: {sum(r['named'] for r in sub)}/{len(sub)}")
        out["detection"] = float(acc)
    if clean:
        fd = sum(bool(r["found"]) for r in clean)
        print(f"false discoveries on effect-free data: {fd}/{len(clean)} (target 0)")
        out["false_discoveries"] = fd
    if pairs:
        print(f"two hidden effects: {sum(r['exact'] for r in pairs)}/{len(pairs)} both found, "
              "nothing else")
    walls = [r["wall_s"] for r in results]
    if walls:
        print(f"analysis wall clock per data set: median {np.median(walls):.1f} s, "
              f"max {np.max(walls):.1f} s ({args.logs} logs x {args.duration:g} s at 100 Hz)")
    if not args.no_timing:
        out["timing_60s_200hz"] = []
        for rig, eff in TIMING_CASES:
            t = timing_case(rig, eff)
            out["timing_60s_200hz"].append(t)
            print(f"one 60 s, 200 Hz log, {rig} with hidden {eff} ({t['samples']} samples): "
                  f"{t['wall_s']:.1f} s wall (target <= 60 s); found {t['found']}; held-out "
                  f"RMSE {1e3 * t['baseline_rmse']:.2f} -> {1e3 * t['extended_rmse']:.3f} mrad "
                  f"(floor {1e3 * t['floor']:.3f})", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1, default=float)
    return 0


def _print(r: dict) -> None:
    tag = "OK " if r["named"] else "MISS"
    lvl = "-" if r["level"] is None else f"{r['level']:.1f}"
    print(f"{tag} {r['rig']:6s} {'+'.join(r['hidden']) or 'none':34s} level {lvl} "
          f"found {r['found']} rmse {1e3 * r['baseline_rmse']:.2f} -> "
          f"{1e3 * r['extended_rmse']:.3f} mrad (floor {1e3 * r['floor']:.3f}) "
          f"{r['wall_s']:.1f} s", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
