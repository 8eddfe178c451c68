"""Auto-reset on the emulated D'Claw: lowcostdex's staged, verified reset vs ROBEL's sequence.

Both procedures run through the same Robot (safety gate, guards) on the same seeded tangles:

* "motion": ``reset_test.tangle`` - the fingers driven by random goals (inside the policy's
  limits) at each other and at the valve, then limp half of the time (as after exploration,
  a thermal pause or a power cut);
* "placed": the fingers put at random inside their limits (middle and bottom joints inward)
  with the motors limp and left to settle under gravity and contacts - harder, with fingers
  wedged against each other (some of these hooks could not arise from motion).

Prints, per procedure and tangle kind, the success rate, the reset time (robot-clock seconds,
i.e. what a real robot would spend), the mean true finger error after a successful reset
(device side, degrees) and the ratio of successes. Run:

    python bench/reset.py [--trials 30] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from lowcostdex.hands import dclaw_spec
from lowcostdex.hardware.emulated.chain import emulated_dclaw
from lowcostdex.hardware.robot.backend import default_effects, make_dynamixel_bus
from lowcostdex.hardware.robot.reset_dclaw import DClawReset
from lowcostdex.hardware.robot.reset_robel import RobelReset
from lowcostdex.hardware.robot.reset_trials import reset_trials, tangle
from lowcostdex.hardware.robot.robot import Robot
from lowcostdex.sim.envs.dclaw_tasks import RESET_POSE


def placed_tangler(chain):
    m = chain.plant.model
    hand = dclaw_spec()
    adr = np.array([m.jnt_qposadr[m.joint(n).id] for n in hand.joint_names])
    low = np.array([j.low for j in hand.joints])
    high = np.array([j.high for j in hand.joints])

    def place(robot, rng):
        robot.torque(False)
        q = rng.uniform(low, high)
        q[1::3] = rng.uniform(0.3, high[1::3])
        q[2::3] = rng.uniform(0.0, high[2::3])
        d = chain.plant.data
        d.qpos[adr] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        robot.rest(0.5)

    return place


def run(procedure: str, kind: str, trials: int, seed: int) -> dict:
    hand = dclaw_spec()
    chain = emulated_dclaw("valve", hand=hand, effects=default_effects(hand.joint_names),
                           rng=np.random.default_rng(seed))
    robot = Robot(hand, make_dynamixel_bus(hand, chain.port(), chain.plant.model))
    m = chain.plant.model
    adr = np.array([m.jnt_qposadr[m.joint(n).id] for n in hand.joint_names])
    errors = []  # true (device-side) finger error after each successful reset [rad]

    def measure(k, ok, duration):
        if ok:
            errors.append(np.max(np.abs(chain.plant.data.qpos[adr] - RESET_POSE)))

    wall = time.perf_counter()
    with robot:
        reset = (DClawReset if procedure == "lowcostdex" else RobelReset)(robot)
        tangler = tangle if kind == "motion" else placed_tangler(chain)
        stats = reset_trials(robot, reset, RESET_POSE, trials, np.random.default_rng(seed),
                             tangler=tangler, on_trial=measure)
    out = stats.summary()
    out["wall"] = time.perf_counter() - wall
    out["error_deg"] = float(np.degrees(np.mean(errors))) if errors else float("nan")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(f"{'tangles':8s} {'procedure':11s} {'success':>9s} {'mean s':>7s} {'median s':>9s} "
          f"{'max s':>7s} {'retried':>8s} {'err deg':>8s} {'wall s':>7s}")
    for kind in ("motion", "placed"):
        rows = {}
        for procedure in ("robel", "lowcostdex"):
            r = run(procedure, kind, args.trials, args.seed)
            rows[procedure] = r
            print(f"{kind:8s} {procedure:11s} {r['successes']:4d}/{r['trials']:<4d} "
                  f"{r['time_mean']:7.2f} {r['time_median']:9.2f} {r['time_max']:7.2f} "
                  f"{r['retried']:8d} {r['error_deg']:8.2f} {r['wall']:7.1f}", flush=True)
        base = max(rows["robel"]["success_rate"], 1e-9)
        print(f"{kind:8s} success ratio lowcostdex / robel = "
              f"{rows['lowcostdex']['success_rate'] / base:.2f}")


if __name__ == "__main__":
    main()
