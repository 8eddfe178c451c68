"""What Plant.step's argument check costs per call, beside raw MuJoCo (issue 13's leftover).

On the D'Claw valve model (no effects): us of process time per call, best of ``--repeats`` blocks
of ``--calls`` calls, for
  - raw ``mujoco.mj_step(model, data, nstep)`` with ``data.ctrl`` written (the floor);
  - ``Plant.step(goal, nstep)`` (the public call: goal shape / finiteness and nstep checked);
  - ``Plant.step_unchecked(goal, nstep)`` when the code has it (the replay's and envs' path);
  - the same three for a ``BatchPlant`` of ``--nsim`` simulations (raw: ``Batch.step``);
  - the emulated D'Claw's ``PlantDrive.step`` (its physics step behind the wire; compare two
    commits: the unchecked step is its only change).
Process time (CPU seconds), not wall time: the machine is shared.

  OMP_NUM_THREADS=1 nice -n 5 python bench/plant_step_check.py [--nstep 1 20] [--repeats 7]
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import time

import mujoco
import numpy as np


def best_us(fn, calls: int, repeats: int) -> float:
    """Best mean process-time us per call of ``fn`` over ``repeats`` blocks of ``calls``."""
    best = np.inf
    for _ in range(repeats):
        t0 = time.process_time()
        for _ in range(calls):
            fn()
        best = min(best, (time.process_time() - t0) / calls * 1e6)
    return best


def _calls(model, nstep: int, nsim: int, rng: np.random.Generator) -> list:
    """(name, call) pairs to time: raw MuJoCo, then the plants' checked and unchecked steps."""
    from mujoco import batch as mjbatch

    from lowcostdex.sim.plant import BatchPlant, Plant

    goal = rng.uniform(-0.3, 0.3, model.nu)
    data = mujoco.MjData(model)

    def raw():
        data.ctrl[:] = goal
        mujoco.mj_step(model, data, nstep=nstep)

    plant = Plant(model)
    rows = [("raw mj_step", raw), ("Plant.step", lambda: plant.step(goal, nstep))]
    if hasattr(plant, "step_unchecked"):
        rows.append(("Plant.step_unchecked", lambda: plant.step_unchecked(goal, nstep)))
    batch = BatchPlant(model, nsim, nthread=1)
    goals = rng.uniform(-0.3, 0.3, (nsim, model.nu))
    raw_batch = mjbatch.Batch(model, nsim, nthread=1)
    raw_ctrl = raw_batch.bind("ctrl")

    def raw_b():
        raw_ctrl[:] = goals
        raw_batch.step(nstep=nstep)

    rows += [(f"raw Batch.step x{nsim}", raw_b),
             (f"BatchPlant.step x{nsim}", lambda: batch.step(goals, nstep))]
    if hasattr(batch, "step_unchecked"):
        rows.append((f"BatchPlant.step_unchecked x{nsim}",
                     lambda: batch.step_unchecked(goals, nstep)))
    if nstep == 1:  # the emulated robot's physics step (one substep per call)
        from lowcostdex.hardware.emulated.chain import emulated_dclaw

        drive = emulated_dclaw().drive
        rows.append(("emulated D'Claw PlantDrive.step", drive.step))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nstep", type=int, nargs="+", default=[1, 20])
    ap.add_argument("--nsim", type=int, default=32)
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()

    from lowcostdex.hands import dclaw_spec
    from lowcostdex.sim.models.dclaw import build_dclaw

    model = build_dclaw("valve", dclaw_spec("XH430-W350")).compile()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    print(f"# {platform.node()} commit {commit} mujoco {mujoco.__version__} nu {model.nu} "
          f"timestep {model.opt.timestep} calls {args.calls} best of {args.repeats}")
    rng = np.random.default_rng(0)
    print("what                          nstep   us/call   minus raw")
    for nstep in args.nstep:
        rows = _calls(model, nstep, args.nsim, rng)
        floor = {}
        for name, fn in rows:
            calls = max(args.calls // (nstep * (args.nsim if "x" in name else 1)) * 4, 50)
            us = best_us(fn, calls, args.repeats)
            key = "batch" if "Batch" in name else "drive" if "Drive" in name else "one"
            floor.setdefault(key, us)
            print(f"{name:30s} {nstep:5d} {us:9.2f} {us - floor[key]:+10.2f}")


if __name__ == "__main__":
    main()
