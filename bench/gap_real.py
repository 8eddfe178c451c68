"""Gap analysis on real servo logs (BAM pendulum benches), compared with BAM's own models.

Reads the measured logs (never copied into the repository) from a folder given by --data or the
environment variable LOWCOSTDEX_MEASURED_DATA (default ../shared/data/measured next to the
repository); exits cleanly when it is absent. For each set it maps the BAM JSON logs onto the servo
bench, runs the full analysis with BAM's train / held-out split, and prints what the nominal model
gets wrong, the causes named, and held-out MAE before/after next to BAM's numbers from
../shared/reference/08-bam-reference-errors.md (same logs, same error measure: mean over held-out
logs of the per-log position MAE, open loop from the first measured state).

    python bench/gap_real.py --out /tmp/gap_real          # all sets (about 10 min on 2 cores)
    python bench/gap_real.py --sets rhoban-xl330          # one set
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from lowcostdex.sim.gap.analyze import GapConfig, analyze
from lowcostdex.sim.gap.dataset import load_dataset
from lowcostdex.sim.gap.report import summary, write_report

# name -> (folder, held-out kp values, BAM reference on the held-out logs [rad, mean per-log MAE])
SETS = {
    "rhoban-xl330": ("rhoban-bam-xl330", (200, 800), {
        "published M1": 0.0980, "published M3 (best published)": 0.0875,
        "published M6": 0.0929, "BAM-fitted M1 (train kp 100, 400)": 0.0836,
        "BAM-fitted M6 (train kp 100, 400)": 0.0599}),
    "sts3032": ("qua-robotics-bam-sts3032", (8,), {
        "published STS3215 M1, zero-shot": 0.2279, "BAM-fitted M1 (train kp 32)": 0.0425,
        "BAM-fitted M4 (train kp 32)": 0.0297}),
    "pham-xl330": ("pham-tuan-binh-bam-xl330", (400,), {
        "published M1 (all 12 logs)": 0.0259, "published M3 (all 12 logs)": 0.0218}),
    "sts3250": ("rhoban-bam-feetech-sts3250", None, {
        "published STS3215 M1, zero-shot (all 4 logs)": 0.0695}),
}


def data_root(arg: str | None) -> Path:
    if arg:
        return Path(arg)
    env = os.environ.get("LOWCOSTDEX_MEASURED_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "measured"


def run_set(name: str, root: Path, out: Path | None, max_effects: int, seed: int) -> dict:
    folder, held_kp, reference = SETS[name]
    files = sorted((root / folder).glob("*.json"))
    ds = load_dataset(files)
    test = None
    if held_kp is not None:
        test = tuple(i for i, tr in enumerate(ds.trajectories) if int(tr.meta["kp"]) in held_kp)
    cfg = GapConfig(test_logs=test, max_effects=max_effects, seed=seed)
    t0 = time.perf_counter()
    res = analyze(ds, cfg)
    wall = time.perf_counter() - t0
    if out is not None:
        write_report(res, out / name)
    test_eps = [res.episodes[i] for i in res.split.test]
    per_log = {"nominal": float(np.mean(res.baseline["per_episode_mae"])),
               "extended": float(np.mean(res.extended["per_episode_mae"]))}
    diag = {j: {k: d[k] for k in ("rmse", "bias", "lag_s", "corr_sign_velocity",
                                  "corr_position", "hysteresis")}
            for j, d in res.diagnostics.items()}
    return {"set": name, "logs": len(files), "test_logs": len(test_eps), "wall_s": wall,
            "verdict": res.verdict, "stop": res.stop_reason,
            "causes": [{"effect": c.effect,
                        "params": {p: d["value"] for p, d in c.params.items()},
                        "heldout_rmse_after": c.heldout_rmse_after, "flags": c.flags}
                       for c in res.causes],
            "heldout_mae_per_log": per_log, "gain": res.gain.to_dict(),
            "diagnostics": diag, "reference": reference, "summary": summary(res)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None, help="measured-data folder")
    ap.add_argument("--sets", nargs="+", default=list(SETS), choices=list(SETS))
    ap.add_argument("--out", default=None, help="write each set's full report here")
    ap.add_argument("--max-effects", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    root = data_root(args.data)
    if not root.is_dir():
        print(f"measured data not found at {root}; set LOWCOSTDEX_MEASURED_DATA or --data "
              "(skipping)")
        return 0
    out = Path(args.out) if args.out else None
    results = []
    for name in args.sets:
        if not (root / SETS[name][0]).is_dir():
            print(f"{name}: folder {SETS[name][0]} missing, skipped")
            continue
        r = run_set(name, root, out, args.max_effects, args.seed)
        results.append(r)
        _print(r)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=float))
    return 0


def _print(r: dict) -> None:
    m = r["heldout_mae_per_log"]
    print(f"\n=== {r['set']}: {r['logs']} logs, {r['test_logs']} held out; "
          f"{r['wall_s']:.0f} s ===")
    print(r["summary"])
    print(f"held-out MAE (mean per log): nominal {1e3 * m['nominal']:.1f} mrad -> extended "
          f"{1e3 * m['extended']:.1f} mrad")
    for label, v in r["reference"].items():
        print(f"   BAM {label}: {1e3 * v:.1f} mrad")


if __name__ == "__main__":
    raise SystemExit(main())
