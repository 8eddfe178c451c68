"""Gap analysis of a user's own MJCF: a two-joint finger on plain ``position`` actuators.

    python demos/gap_own_mjcf.py                    # writes runs/gap_own_mjcf/, ~2-5 min on 2 cores
                                                    # (again: the earlier run moves into previous/)
    python demos/gap_own_mjcf.py --out my_report --seed 3

The model is the kind a user writes for a LEAP-style hand: ``position`` actuators (kp 3 N m/rad,
force range +-0.5 N m), joint damping 0.2 N m s/rad and a frictionloss of 0.02 N m that is a rough
guess. The "robot" that records the logs is that same MJCF with what the guess got wrong, written
here in plain MuJoCo (nothing from the analyzer): the joints' dry friction is 0.06 N m (3x the
guess) and every goal reaches the motors 30 ms after the host sent it (a USB/serial round trip).
The readings are quantised to a 4096-tick encoder (1.5 mrad) with 0.5 mrad of noise, sampled at
100 Hz, six logs of steps and chirps. Then, exactly as on logs from a real robot:

    lowcostdex gap analyze --model model.xml --log logs/*.csv --out report/

The report names the causes with their fitted values and 95 % intervals and the held-out error
before and after; the demo prints them beside the truth it hid.
"""

from __future__ import annotations

import argparse
import json
import pathlib

import mujoco
import numpy as np

from lowcostdex.argtypes import SEED
from lowcostdex.argtypes import path as path_option
from lowcostdex.cli import main as cli_main
from lowcostdex.cli import run_script
from lowcostdex.outdir import MARKER, PREVIOUS, archive, read_marker, write_marker

MODEL = """<mujoco model="user_finger">
  <compiler angle="radian"/>
  <option timestep="{dt}" gravity="0 0 -9.81"/>
  <default><joint damping="0.2" frictionloss="{friction}" armature="0.002"/></default>
  <worldbody>
    <body name="proximal" pos="0 0 0.2">
      <joint name="mcp" type="hinge" axis="0 1 0" range="-1.6 1.6"/>
      <geom type="capsule" fromto="0 0 0 0.05 0 0" size="0.01" mass="0.05"/>
      <body name="distal" pos="0.05 0 0">
        <joint name="pip" type="hinge" axis="0 1 0" range="-1.6 1.6"/>
        <geom type="capsule" fromto="0 0 0 0.04 0 0" size="0.009" mass="0.03"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="mcp" joint="mcp" kp="3" forcerange="-0.5 0.5" ctrlrange="-1.5 1.5"/>
    <position name="pip" joint="pip" kp="3" forcerange="-0.5 0.5" ctrlrange="-1.5 1.5"/>
  </actuator>
</mujoco>
"""
GUESS_FRICTION = 0.02  # [N m] the model's frictionloss (the user's rough guess)
TRUE_FRICTION = 0.06  # [N m] the robot's dry friction
TRUE_LATENCY = 0.030  # [s] goal transport delay on the robot
RATE = 100.0  # [Hz] log rate
TICK = 2 * np.pi / 4096  # [rad] encoder resolution
NOISE = 0.0005  # [rad] reading noise (standard deviation)


def goals(style: str, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Goal trajectory (T, 2) [rad]: random steps every 0.4-1.2 s, or a 0.2-3 Hz chirp."""
    if style == "steps":
        g = np.zeros((t.size, 2))
        k, level = 0, rng.uniform(-1.0, 1.0, 2)
        while k < t.size:
            n = int(rng.uniform(0.4, 1.2) * RATE)
            g[k:k + n] = level
            k, level = k + n, rng.uniform(-1.0, 1.0, 2)
        return g
    f = 0.2 + (3.0 - 0.2) * t / t[-1]
    phase = 2 * np.pi * np.cumsum(f) / RATE
    return np.column_stack([0.8 * np.sin(phase), 0.6 * np.sin(1.3 * phase + 0.5)])


def record(t: np.ndarray, g: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The robot: the MJCF at 0.5 ms with the true friction; each goal acts TRUE_LATENCY after
    the host sent it. Returns quantised, noisy readings (T, 2) [rad] at the log rows."""
    m = mujoco.MjModel.from_xml_string(MODEL.format(dt=0.0005, friction=TRUE_FRICTION))
    d = mujoco.MjData(m)
    q = np.zeros_like(g)
    for k, tk in enumerate(t):
        while d.time < tk - 1e-9:
            sent = np.searchsorted(t, d.time - TRUE_LATENCY, side="right") - 1
            d.ctrl[:] = g[max(sent, 0)] if sent >= 0 else 0.0
            mujoco.mj_step(m, d)
        q[k] = d.qpos
    q = q + rng.normal(0.0, NOISE, q.shape)
    return np.round(q / TICK) * TICK


COMMAND = "demos/gap_own_mjcf.py"  # the output folder's marker (lowcostdex.outdir)
FILES = {"model.xml", "logs", "report"}  # what a run writes


def _own(out: pathlib.Path) -> bool:
    """Whether ``out`` holds this demo's earlier output: its marker, or (written before the
    marker was) exactly its files with the report's own marker; a run again into it stopped
    at "not empty"."""
    names = {p.name for p in out.iterdir()} - {PREVIOUS}
    if (read_marker(out) or {}).get("command") == COMMAND:
        return names <= FILES | {MARKER}
    return names == FILES and (read_marker(out / "report") or {}).get("command") == "gap analyze"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=path_option, default="runs/gap_own_mjcf",
                        help="folder to write (new, empty, or an earlier run of this demo: "
                             "moved into previous/)")
    parser.add_argument("--seed", type=SEED, default=0)
    args = parser.parse_args()
    out = pathlib.Path(args.out)
    if out.exists() and not out.is_dir():
        parser.error(f"--out {out} is a file; give a new folder")
    if out.exists() and any(out.iterdir()):
        if not _own(out):
            parser.error(f"--out {out} is not empty (files this demo did not write); give a "
                         "new folder")
        kept = archive(out, [p.name for p in out.iterdir()])  # run again: the last run kept
        print(f"{out} holds an earlier run of this demo: moved into {kept}")
    rng = np.random.default_rng(args.seed)
    (out / "logs").mkdir(parents=True)
    write_marker(out, COMMAND, {"seed": args.seed})
    model = out / "model.xml"
    model.write_text(MODEL.format(dt=0.002, friction=GUESS_FRICTION))
    logs = []
    for i, style in enumerate(["steps", "chirp"] * 3):
        t = np.arange(0.0, 15.0, 1.0 / RATE)
        g = goals(style, t, rng)
        q = record(t, g, rng)
        path = out / "logs" / f"log{i}.csv"
        np.savetxt(path, np.column_stack([t, g, q]), delimiter=",", comments="", fmt="%.9g",
                   header="time,goal:mcp,goal:pip,qpos:mcp,qpos:pip")
        logs.append(str(path))
    code = cli_main(["gap", "analyze", "--model", str(model), "--log", *logs,
                     "--out", str(out / "report"), "--seed", str(args.seed)])
    if code:
        raise SystemExit(code)
    report = json.loads((out / "report" / "report.json").read_text())
    print(f"hidden on the robot: dry friction {TRUE_FRICTION} N m (the model says "
          f"{GUESS_FRICTION}: {TRUE_FRICTION - GUESS_FRICTION:.2f} N m missing), goals "
          f"{TRUE_LATENCY * 1e3:.0f} ms late")
    for c in report["causes"]:
        for name, p in c["params"].items():
            for joint, v, (lo, hi) in zip(c["joints"], p["value"], p["interval"], strict=True):
                print(f"  named {c['effect']} on {joint}: {name} {float(v):.4g} {p['unit']} "
                      f"(95 % {float(lo):.4g} .. {float(hi):.4g})")


if __name__ == "__main__":
    run_script(main)  # a user's mistake is one line and exit code 2, not a traceback
