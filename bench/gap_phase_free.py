"""Would a score blind to a limit cycle's PHASE name sim11's velocity-loop play? (issue 11;
gap-sweep23, session 28). A measurement, no change to the analysis.

sim11 backlash_pan (a 40 mrad play in a velocity-mode pan servo under the host's 100 Hz
position loop) is a miss: the truth's loop hunts across the play at every hold, our plant hunts
as it does (gap-sim14), but open loop from the logged commands the replay's limit cycle is out
of phase with the logs', so the play's open-loop RMSE is worse than none and the replay keeps
the massless play operator (``Replayer._closer``). This script replays, per case, the nominal
model, the true effects and plays of 20 / 40 mrad (sensor 0 and 1) on 1 s segments (the
analysis's windows: 0.2 s burn-in) and on windows restarted from the measured state every 0.2 /
0.5 s, both as the replay keeps its regime and with the play's hinge regime forced, and prints
per column:

  - the open-loop RMSE [mrad] (what the analysis ranks by);
  - the HUNTING AMPLITUDE MISMATCH [mrad]: per 1 s segment, the RMS of the reading minus its
    centred 10-row moving average (the band above ~10 Hz at 100 Hz rows), the data's with the
    white read floor removed in quadrature (``diagnostics.noise_floor``), RMS over segments of
    (replay's - data's); no phase enters;
  - the SPECTRUM MISMATCH [mrad]: the same band's |FFT| replay vs data (floor removed per bin).

    OMP_NUM_THREADS=1 nice -n 5 python bench/gap_phase_free.py --keep /tmp/phase
    python bench/gap_phase_free.py --cases sim11:backlash_pan sim11:clean_pantilt
"""

from __future__ import annotations

import argparse
import pathlib
import sys
from collections.abc import Callable

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import redteam_harness as harness  # noqa: E402

from lowcostdex.gap import load_dataset  # noqa: E402
from lowcostdex.gap.dataset import Dataset, Window, episodes, segments  # noqa: E402
from lowcostdex.gap.diagnostics import noise_floor  # noqa: E402
from lowcostdex.gap.replay import Replayer  # noqa: E402
from lowcostdex.sim.effects import AppliedEffect  # noqa: E402

BAND_ROWS = 10  # moving-average length [rows] removed before the hunting amplitude


class HingeReplayer(Replayer):
    """A replay that keeps a play's hinge regime (never the massless operator)."""

    def _closer(self, windows, a, b) -> bool:  # noqa: ANN001 (the parent's signature)
        return False


def _on(value: float, joints: tuple[str, ...], k: int) -> np.ndarray:
    a = np.zeros(len(joints))
    a[k] = value
    return a


def play(joints: tuple[str, ...], k: int, width: float, sensor: float) -> AppliedEffect:
    """A play of ``width`` rad on joint ``k`` (``sensor``: the loop reads across it)."""
    return AppliedEffect("backlash", joints, {"width": _on(width, joints, k),
                                              "sensor": _on(sensor, joints, k),
                                              "read": np.ones(len(joints))})


def latency(joints: tuple[str, ...], delay: float) -> AppliedEffect:
    return AppliedEffect("latency", joints, {"delay": np.full(len(joints), delay)})


# case -> (truth set, joint scored, the true effects as columns)
Truth = Callable[[tuple[str, ...]], dict[str, list[AppliedEffect]]]
CASES: dict[str, tuple[str, str, int, Truth]] = {
    "sim11:backlash_pan": ("gap_truth_sim11", "backlash_pan", 0, lambda j: {
        "play 30 s1": [play(j, 0, 0.03, 1.0)], "play 60 s1": [play(j, 0, 0.06, 1.0)],
        "gain_error 0.94 / 1.007 (as named)": [AppliedEffect(
            "gain_error", j, {"scale": np.array([0.94, 1.007])})]}),
    "sim11:latency_backlash": ("gap_truth_sim11", "latency_backlash", 0, lambda j: {
        "latency 30 ms": [latency(j, 0.03)],
        "TRUTH latency 30 ms + play 40 s1": [latency(j, 0.03), play(j, 0, 0.04, 1.0)]}),
    "sim11:clean_pantilt": ("gap_truth_sim11", "clean_pantilt", 0, lambda j: {}),
    "sim11:friction_pan": ("gap_truth_sim11", "friction_pan", 0, lambda j: {
        "TRUTH coulomb 0.25": [AppliedEffect("coulomb_friction", j,
                                             {"frictionloss": _on(0.25, j, 0)})]}),
    "sim11:latency50": ("gap_truth_sim11", "latency50", 0, lambda j: {
        "TRUTH latency 50 ms": [latency(j, 0.05)]}),
    "sim2:clean_pendulum": ("gap_truth_sim2", "clean_pendulum", 0, lambda j: {}),
    "sim2:backlash_body_pendulum": ("gap_truth_sim2", "backlash_body_pendulum", 0, lambda j: {
        "TRUTH play 26.2 s0": [play(j, 0, 0.02618, 0.0)]}),
    "sim2:backlash_output_pendulum": ("gap_truth_sim2", "backlash_output_pendulum", 0,
                                      lambda j: {"TRUTH play 43.6 s1": [play(j, 0, 0.04363,
                                                                              1.0)]}),
    "sim5:backlash2deg_pendulum_500hz_us": ("gap_truth_sim5", "backlash2deg_pendulum_500hz_us",
                                            0, lambda j: {"TRUTH play 34.9 s1": [
                                                play(j, 0, 0.03491, 1.0)]}),
}


def band(x: np.ndarray, k: int = BAND_ROWS) -> np.ndarray:
    """``x`` minus its centred ``k``-row moving average (ends padded with the end values)."""
    pad = np.pad(x, (k // 2, k - 1 - k // 2), mode="edge")
    return x - np.convolve(pad, np.ones(k) / k, mode="valid")


def restarts(ds: Dataset, eps: list[Window], length: float) -> list[Window]:
    """Windows of ``length`` s back to back inside the episodes, each scored from its start."""
    out = []
    for ep in eps:
        t = ds.trajectories[ep.traj].time
        a = ep.start
        while a < ep.stop - 2:
            b = int(min(ep.stop, np.searchsorted(t, t[a] + length)))
            if b - a >= 3:
                out.append(Window(ep.traj, a, b, a))
            a = b
    return out


def scores(ds: Dataset, wins: list[Window], pred: list[np.ndarray], j: int, floor: float
           ) -> tuple[float, float, float]:
    """(open-loop RMSE, hunting amplitude mismatch, spectrum mismatch) [rad] on joint ``j``."""
    e2, n, amp, spec = 0.0, 0, [], []
    for w, p in zip(wins, pred, strict=True):
        q = ds.trajectories[w.traj].qpos[w.score_from:w.stop, j]
        y = p[w.score_from - w.start:, j]
        e2 += float(np.sum((q - y) ** 2))
        n += len(q)
        if len(q) < 2 * BAND_ROWS:
            continue
        bq, by = band(q), band(y)
        data_amp = np.sqrt(max(float(np.mean(bq ** 2)) - floor ** 2, 0.0))
        amp.append((np.sqrt(float(np.mean(by ** 2))) - data_amp) ** 2)
        fq, fy = np.abs(np.fft.rfft(bq)), np.abs(np.fft.rfft(by))
        white = floor * np.sqrt(len(q))  # a white floor's expected |FFT| per bin
        spec.append(float(np.mean((fy - np.sqrt(np.maximum(fq ** 2 - white ** 2, 0.0))) ** 2))
                    / len(q))
    return np.sqrt(e2 / n), float(np.sqrt(np.mean(amp))), float(np.sqrt(np.mean(spec)))


def measure(name: str, keep: pathlib.Path) -> str:
    """The markdown tables of case ``name`` (as replayed; the hinge regime forced)."""
    set_name, case, k, truth = CASES[name]
    sim = harness.truth_module(set_name)
    files = sim.write_case(sim.CASE_BY_NAME[case], keep / name.replace(":", "_"))
    args = list(files.get("args", []))
    units = {"angle_unit": args[args.index("--units") + 1]} if "--units" in args else {}
    if "--time-unit" in args:
        units["time_unit"] = args[args.index("--time-unit") + 1]
    ds = load_dataset(files["logs"], model=files["model"], **units)
    joints = tuple(ds.joints)
    floor = float(noise_floor(ds.trajectories)[k])
    cols = {"nominal": [], **truth(joints),
            **{f"play {1e3 * w:.0f} s{s:.0f}": [play(joints, k, w, s)]
               for w in (0.02, 0.04) for s in (0.0, 1.0)}}
    eps = episodes(ds)
    wsets = [segments(ds, eps, 1.0, 0.2), restarts(ds, eps, 0.2), restarts(ds, eps, 0.5)]
    names = sorted({e.name for c in cols.values() for e in c})
    out = []
    for regime, cls in (("as replayed", Replayer), ("hinge regime forced", HingeReplayer)):
        rep = cls(ds, names, nthread=1)
        rows = {c: [] for c in cols}
        for wins in wsets:
            for c, pr in zip(cols, rep.run(wins, list(cols.values()))[0], strict=True):
                rows[c].append(scores(ds, wins, pr, k, floor))
        out.append(f"\n{name} ({regime}; joint {ds.joints[k]}, read floor "
                   f"{1e3 * floor:.2f} mrad), mrad\n\n| column | RMSE 1 s segments | RMSE "
                   "0.2 s restarts | RMSE 0.5 s restarts | hunting amplitude mismatch | "
                   "spectrum mismatch |\n|---|---|---|---|---|---|")
        for c, r in rows.items():
            out.append(f"| {c} | {1e3 * r[0][0]:.2f} | {1e3 * r[1][0]:.2f} | "
                       f"{1e3 * r[2][0]:.2f} | {1e3 * r[0][1]:.2f} | {1e3 * r[0][2]:.2f} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES),
                    metavar="SET:CASE", help=f"default: all of {', '.join(CASES)}")
    ap.add_argument("--keep", default="/tmp/gap_phase_free", help="folder for the cases' logs")
    args = ap.parse_args(argv)
    for name in args.cases:
        print(measure(name, pathlib.Path(args.keep)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
