"""Real servo logs (BAM pendulum benches): our identified servo model against BAM's, BAM's measure.

Reads the measured logs (never copied into the repository) from --data, or the environment
variable LOWCOSTDEX_MEASURED_DATA (or LOWCOSTDEX_MEASURED), default ../shared/data/measured next
to the repository; exits cleanly when it is absent. For each set:

* the logs are resampled onto BAM's 5 ms grid (``lowcostdex.gap.bam_measure``, as
  ``bam.process`` does) and mapped onto the servo bench (header mass, length, arm mass, kp, vin),
  physics at BAM's 5 ms step;
* the servo structure (``identify.servo_structure``: motor constants, armature, Coulomb, viscous,
  gear friction with breakaway and back-driven share, mounting offset, measured supply voltage)
  is identified on the training gains with ``identify.identify`` (whole logs, open loop; three
  families: all free, the back-driven share held at 1, the motor constants nominal and the
  voltage term off; each from 3 jittered starts, fitted on the training logs but those at the
  smallest value of the first header field that varies among them (kp, else length, mass, ...),
  and the family and fit chosen on those held-back logs: the one with the fewest parameters
  unless another pays 2 %);
* the held-out gains are scored with BAM's measure (mean over logs of each log's position MAE,
  open loop from the first grid state, torque-off parts included), per trajectory and per kp,
  beside BAM's numbers on the same split, typed in from ../shared/reference/08-bam-reference-
  errors.md (Rhoban/bam@1b5a1ce, bam.mae; '-' where the reference gives no number).

    python bench/gap_real.py                       # all sets (a few minutes on 2 cores)
    python bench/gap_real.py --sets rhoban-xl330   # one set
    python bench/gap_real.py --effects gain_error velocity_limit ...   # another structure
    python bench/gap_real.py --analyze             # also the automatic effect selection
    python bench/gap_real.py --seeds 3             # also 3 runs from jittered starts (spread)
    python bench/gap_real.py --select train --restarts 1   # the family chosen on the training
                                                   # logs, one start (before 2026-11-26 07:00)
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from lowcostdex.gap import bam_measure as bm
from lowcostdex.gap.dataset import load_dataset
from lowcostdex.gap.identify import IdentifyConfig, breakdown, identify, servo_structure

TRAJ = ("lift_and_drop", "sin_sin", "sin_time_square", "up_and_down")

# BAM on the same held-out logs [rad], 08-bam-reference-errors.md: {label: (mean, {trajectory:
# value}, {kp: value})}; empty dicts where section 2-4 give no breakdown for this split.
SETS = {
    "rhoban-xl330": dict(
        folder="rhoban-bam-xl330", held_kp=(200, 800), bam={
            # section 3 (held out kp 200, 800)
            "BAM refit M6 (train kp 100, 400)": (0.0599, {}, {200: 0.029, 800: 0.091}),
            "BAM refit M1 (train kp 100, 400)": (0.0836, {}, {200: 0.064, 800: 0.103}),
            "BAM published M6": (0.0929, {}, {200: 0.062, 800: 0.124}),
            "BAM published M3 (best published)": (0.0875, {}, {}),
        }),
    "sts3032": dict(
        folder="qua-robotics-bam-sts3032", held_kp=(8,), bam={
            # section 4 (train kp 32, held out kp 8); per trajectory in TRAJ order
            "BAM refit M4 (train kp 32)": (0.0297, dict(zip(TRAJ, (0.039, 0.018, 0.044, 0.019),
                                                            strict=True)), {8: 0.0297}),
            "BAM refit M1 (train kp 32)": (0.0425, dict(zip(TRAJ, (0.040, 0.038, 0.046, 0.046),
                                                            strict=True)), {8: 0.0425}),
            "BAM STS3215 M1, zero-shot": (0.2279, {}, {8: 0.2279}),
        }),
    "pham-xl330": dict(
        folder="pham-tuan-binh-bam-xl330", held_kp=(400,), bam={
            # section 2 "per kp" column (published models, identified on Rhoban's own data:
            # out of sample for this set)
            "BAM published M3 (best)": (0.022, {}, {400: 0.022}),
            "BAM published M4": (0.022, {}, {400: 0.022}),
            "BAM published M1": (0.024, {}, {400: 0.024}),
        }),
}


def data_root(arg: str | None) -> Path:
    if arg:
        return Path(arg)
    env = os.environ.get("LOWCOSTDEX_MEASURED_DATA") or os.environ.get("LOWCOSTDEX_MEASURED")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "measured"


def run_set(name: str, root: Path, effects: tuple[str, ...] | None, analyze_too: bool,
            max_rounds: int, seeds: int = 0, jitter: float = 1e-3, select: str = "inner",
            restarts: int = 3) -> dict:
    spec = SETS[name]
    files = sorted((root / spec["folder"]).glob("*.json"))
    t0 = time.perf_counter()
    ds = bm.grid_dataset(load_dataset(files, timestep=bm.BAM_DT))
    kps = [int(tr.meta["kp"]) for tr in ds.trajectories]
    test = [i for i, k in enumerate(kps) if k in spec["held_kp"]]
    train = [i for i, k in enumerate(kps) if k not in spec["held_kp"]]
    structure = tuple(effects) if effects else servo_structure(ds)
    sel = dict(select=select, restarts=restarts)
    c0 = time.process_time()
    res = identify(ds, train, test, IdentifyConfig(effects=structure, max_rounds=max_rounds,
                                                   **sel))
    cpu = time.process_time() - c0
    wall = time.perf_counter() - t0
    out = {
        "set": name, "logs": len(files), "train_kp": sorted({kps[i] for i in train}),
        "test_kp": sorted(spec["held_kp"]), "structure": list(structure),
        "wall_s": wall, "fit_s": res.fit_seconds, "rounds": res.rounds, "identify_cpu_s": cpu,
        "selection": res.selection,
        "params": res.params(), "at_bound": res.at_bound, "family": res.family,
        "family_train_mae": res.family_train_mae,
        "ours": {
            "identified": _summary(ds, res.identified_mae, test),
            "nominal": _summary(ds, res.nominal_mae, test),
            "identified (train logs)": {"mean": res.mean(train)},
        },
        "ablation": res.ablation,
        "bam": {k: {"mean": v[0], "trajectory": v[1], "kp": v[2]} for k, v in
                spec["bam"].items()},
    }
    # the same identification from jittered starts: how much the held-out error depends on
    # where the least-squares path starts
    out["jittered"] = []
    for seed in range(1, seeds + 1):
        rj = identify(ds, train, test, IdentifyConfig(effects=structure, max_rounds=max_rounds,
                                                      jitter=jitter, seed=seed, **sel))
        out["jittered"].append({"seed": seed, "jitter": jitter, "held_out": rj.mean(test),
                                "train": rj.mean(train), "family": rj.family,
                                "chosen": rj.selection.get("chosen", rj.family),
                                "kp": breakdown(ds, rj.identified_mae, test, "kp"),
                                "trajectory": breakdown(ds, rj.identified_mae, test,
                                                        "trajectory"),
                                "fit_s": rj.fit_seconds})
    if analyze_too:
        from lowcostdex.gap.analyze import GapConfig, analyze

        a = analyze(ds, GapConfig(test_logs=tuple(test), max_effects=4, seed=0))
        per = {a.episodes[i].traj: v for i, v in zip(a.split.test,
                                                      a.extended["per_episode_mae"], strict=True)}
        out["ours"]["automatic selection"] = _summary(ds, per, test)
        out["analysis"] = {"verdict": a.verdict, "causes": [
            {"effect": c.effect, "params": {p: d["value"] for p, d in c.params.items()}}
            for c in a.causes]}
    return out


def _summary(ds, mae: dict[int, float], logs: list[int]) -> dict:
    return {"mean": float(np.mean([mae[i] for i in logs])),
            "trajectory": breakdown(ds, mae, logs, "trajectory"),
            "kp": breakdown(ds, mae, logs, "kp")}


def _fmt(v) -> str:
    return "-" if v is None else f"{1e3 * v:.1f}"


def table(r: dict) -> str:
    kps = r["test_kp"]
    head = ["model", "held-out", *TRAJ, *[f"kp {k}" for k in kps]]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    rows = [(f"ours: {k}", v) for k, v in r["ours"].items() if "trajectory" in v]
    rows += [(k, v) for k, v in r["bam"].items()]
    for label, v in rows:
        cells = [label, _fmt(v["mean"])]
        cells += [_fmt(v["trajectory"].get(t)) for t in TRAJ]
        cells += [_fmt(v["kp"].get(k)) for k in kps]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _print(r: dict) -> None:
    print(f"\n=== {r['set']}: {r['logs']} logs, train kp {r['train_kp']}, held out kp "
          f"{r['test_kp']}; fit {r['fit_s']:.0f} s ({r['rounds']} LM rounds), "
          f"{r['wall_s']:.0f} s in all, identify {r['identify_cpu_s']:.0f} s CPU ===")
    print("held-out MAE [mrad], BAM's measure (mean over logs of per-log MAE, 5 ms grid):")
    print(table(r))
    print(f"train logs: {1e3 * r['ours']['identified (train logs)']['mean']:.1f} mrad")
    print("identified:", ", ".join(
        f"{e} " + " ".join(f"{p}={v[0]:.4g}" for p, v in ps.items())
        for e, ps in r["params"].items()))
    if r["family_train_mae"]:
        print(f"family: {r['family']} (train logs: " + ", ".join(
            f"{k} {1e3 * v:.1f}" for k, v in r["family_train_mae"].items()) + " mrad)")
    sel = r["selection"]
    if sel:
        print(f"inner validation: fit {len(sel['fit_logs'])} training logs, validate on "
              f"{len(sel['val_logs'])} (split by {sel['field']}); chosen {sel['chosen']}; "
              "validation MAE [mrad]: " + ", ".join(f"{k} {1e3 * v:.1f}" for k, v in
                                                    sel["val_mae"].items()))
    if r["at_bound"]:
        print("at a search bound:", ", ".join(r["at_bound"]))
    print("held-out MAE without each effect (others kept) [mrad]:",
          ", ".join(f"{k} {1e3 * v:.1f}" for k, v in r["ablation"].items()))
    if r["jittered"]:
        print(f"jittered starts (x (1 + {r['jittered'][0]['jitter']:g} N(0, 1)), seeds 1-"
              f"{len(r['jittered'])}), held out [mrad]:")
        for j in r["jittered"]:
            print(f"  seed {j['seed']}: {1e3 * j['held_out']:.1f} (train {1e3 * j['train']:.1f}, "
                  f"{j['chosen']}; " + ", ".join(f"kp {k} {1e3 * v:.1f}" for k, v in
                                                 j["kp"].items()) + "; " +
                  ", ".join(f"{k} {1e3 * v:.1f}" for k, v in j["trajectory"].items()) + ")")
        vals = [1e3 * r["ours"]["identified"]["mean"]] + [1e3 * j["held_out"]
                                                           for j in r["jittered"]]
        print(f"  all {len(vals)} fits: median {np.median(vals):.1f}, range "
              f"{min(vals):.1f}-{max(vals):.1f}")
    if "analysis" in r:
        print("automatic selection:", r["analysis"]["verdict"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None, help="measured-data folder")
    ap.add_argument("--sets", nargs="+", default=list(SETS), choices=list(SETS))
    ap.add_argument("--effects", nargs="+", default=None,
                    help="structure to identify (default: identify.servo_structure)")
    ap.add_argument("--analyze", action="store_true",
                    help="also run the automatic effect selection (gap analyze) on the split")
    ap.add_argument("--max-rounds", type=int, default=30)
    ap.add_argument("--seeds", type=int, default=0,
                    help="also identify from N jittered starts (seeds 1..N) and print the spread")
    ap.add_argument("--jitter", type=float, default=1e-3,
                    help="relative spread of the jittered starts (IdentifyConfig.jitter)")
    ap.add_argument("--select", default="inner", choices=("inner", "train"),
                    help="family and fit chosen on an inner validation (default) or on the "
                    "training logs (IdentifyConfig.select)")
    ap.add_argument("--restarts", type=int, default=3,
                    help="jittered fits per family with --select inner")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    root = data_root(args.data)
    if not root.is_dir():
        print(f"measured data not found at {root}; set LOWCOSTDEX_MEASURED_DATA or --data "
              "(skipping)")
        return 0
    results = []
    for name in args.sets:
        if not (root / SETS[name]["folder"]).is_dir():
            print(f"{name}: folder {SETS[name]['folder']} missing, skipped")
            continue
        r = run_set(name, root, args.effects, args.analyze, args.max_rounds, args.seeds,
                    args.jitter, args.select, args.restarts)
        results.append(r)
        _print(r)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
