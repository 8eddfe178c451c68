"""How systematic is a replay's misfit? The statistics an "anything to explain?" gate could use,
on the truth simulators' clean cases and on the cases a gate would have to open for.

``lowcostdex gap analyze`` seeks no cause while the model's train + select RMSE is within
``GapConfig.explain_above`` (3) noise floors. Two sim3 plays sit under it (fin_backlash080_dist,
fin_pair_latency080_abd_backlash050_prox after its latency), so a gate on how *systematic* the
residual is (smooth in time, in every log) rather than how large was asked for. This prints, per
case and joint, on the train + select episodes of the analysis' own split at the step it would
use (``stepsize.refine``), the replay's RMS, the RMS of a 9-sample moving mean (white noise at
the floor gives 1/3) and the per-episode RMS range, all in noise floors; optionally with fixed
effects applied (a fitted cause, a catalogue backlash at some width). No fitting: seconds per
case.

    nice -n 10 python bench/gap_gate_stats.py                      # the default set
    python bench/gap_gate_stats.py --case gap_truth_sim3:fin_backlash080_dist \\
        --effects '[["backlash", {"width": [0, 0, 0.08], "sensor": [0, 0, 0]}]]'
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import tempfile

import numpy as np

TESTS = pathlib.Path(__file__).resolve().parents[1] / "tests"

DEFAULT = ("gap_truth_sim3:fin_backlash080_dist", "gap_truth_sim3:fin_clean_noisy",
           "gap_truth_sim3:fin_clean_jitter_posonly", "gap_truth_sim3:srv_clean",
           "gap_truth_sim2:clean_pendulum", "gap_truth_sim2:clean_pendulum_fine_step",
           "gap_truth_sim2:clean_arm2_posonly", "gap_truth_sim2:clean_turntable_below_noise",
           "gap_truth_sim2:clean_mounting_vertical", "gap_truth_sim4:clean_velocity",
           "gap_truth_sim4:clean_motor_posonly")


def case_stats(sim_name: str, case_name: str, effects: list, root: pathlib.Path) -> dict:
    """Per joint {rms, lp9, ep_min, ep_max} in noise floors, and the whole set's RMS."""
    from lowcostdex.gap import stepsize
    from lowcostdex.gap.dataset import episodes, load_dataset, split_episodes
    from lowcostdex.gap.diagnostics import noise_floor
    from lowcostdex.gap.replay import Replayer
    from lowcostdex.gap.results import GapConfig
    from lowcostdex.sim.effects import AppliedEffect

    if str(TESTS) not in sys.path:
        sys.path.insert(0, str(TESTS))
    sim = __import__(sim_name)
    files = sim.write_case(sim.CASE_BY_NAME[case_name], root / sim_name / case_name)
    ds = load_dataset(files["logs"], model=files["model"])
    cfg = GapConfig(seed=0, nthread=1)
    eps = episodes(ds, cfg.chunk)
    split = split_episodes(ds, eps, np.random.default_rng(cfg.seed), cfg.test_logs)
    used = [eps[i] for i in split.train + split.select]
    ds, _ = stepsize.refine(ds, used, cfg)
    floor = noise_floor(ds.trajectories)
    col = [AppliedEffect(n, ds.effect_joints, {k: np.asarray(v) for k, v in p.items()})
           for n, p in effects]
    (pred,), _ = Replayer(ds, [n for n, _ in effects], nthread=1).run(used, [col])
    res = [ds.trajectories[w.traj].qpos[w.start:w.stop] - p
           for w, p in zip(used, pred, strict=True)]
    out = {"dt": ds.timestep, "rms_all": math.sqrt(np.mean(np.concatenate(res) ** 2)
                                                   / np.mean(floor ** 2)), "joints": {}}
    for j, name in enumerate(ds.joints):
        rs = [r[:, j] for r in res]
        r = np.concatenate(rs)
        lp = np.concatenate([np.convolve(x, np.ones(9) / 9, mode="valid") for x in rs])
        ep = [math.sqrt(np.mean(x * x)) / floor[j] for x in rs]
        out["joints"][name] = {"floor_mrad": 1e3 * floor[j],
                               "rms": math.sqrt(np.mean(r * r)) / floor[j],
                               "lp9": math.sqrt(np.mean(lp * lp)) / floor[j],
                               "ep_min": min(ep), "ep_max": max(ep)}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", nargs="*", default=list(DEFAULT), help="sim_module:case_name")
    ap.add_argument("--effects", default="[]", help="JSON [[effect, {param: per-joint}], ...]")
    ap.add_argument("--json", help="write the numbers here")
    a = ap.parse_args(argv)
    effects = [tuple(e) for e in json.loads(a.effects)]
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for spec in a.case:
            sim_name, case_name = spec.split(":")
            s = rows[spec] = case_stats(sim_name, case_name, effects, pathlib.Path(tmp))
            print(f"{spec}  step {s['dt'] * 1e3:g} ms  all joints {s['rms_all']:.2f} floors",
                  flush=True)
            for j, v in s["joints"].items():
                print(f"  {j:>8}  floor {v['floor_mrad']:.3f} mrad  rms {v['rms']:.2f}  "
                      f"lp9 {v['lp9']:.2f}  episodes {v['ep_min']:.2f}-{v['ep_max']:.2f}")
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
