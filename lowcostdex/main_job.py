"""``lowcostdex main``: the whole story in one command, on the emulated D'Claw by default.

Stages write into one output folder and a short Markdown report links their PNG plots. The
stages grow with the project; each is a function ``stage(ctx) -> dict`` whose result lands in
``results.json`` and the report.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class Context:
    """What every stage sees.

    Attributes:
      out: output folder.
      size: "smoke" (CI), "default" (~15 min on 2 cores) or "long".
      seed: master seed.
      port: serial port of a real robot, or None for the emulated D'Claw.
      results: results of earlier stages by name.
    """

    out: Path
    size: str = "default"
    seed: int = 0
    port: str | None = None
    results: dict[str, dict[str, Any]] = field(default_factory=dict)

    def budget(self, smoke: int, default: int, long: int) -> int:
        return {"smoke": smoke, "default": default, "long": long}[self.size]


def stage_sim_rollouts(ctx: Context) -> dict[str, Any]:
    """Roll out the scripted valve-turning motion in simulation and plot the valve angle."""
    import gymnasium as gym
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    import lowcostdex  # noqa: F401
    from lowcostdex.sim.envs import goal_to_action

    env = gym.make("lowcostdex/DClawTurnValve-v0")
    u = env.unwrapped
    teacher = _teacher(u)
    episodes = ctx.budget(2, 5, 20)
    curves, successes = [], []
    for ep in range(episodes):
        obs, info = env.reset(seed=ctx.seed + ep)
        teacher.reset(u)
        angles = [float(u.data.qpos[u.task.obj_qpos])]
        done = False
        while not done:
            action = goal_to_action(teacher(u.data.qpos, u.goal), u.task.hand_low,
                                    u.task.hand_high)
            obs, reward, term, trunc, info = env.step(action)
            angles.append(float(u.data.qpos[u.task.obj_qpos]))
            done = term or trunc
        curves.append(angles)
        successes.append(info["success"])
    fig, ax = plt.subplots(figsize=(6, 3.5))
    t = np.arange(len(curves[0])) * u.control_period
    for c in curves:
        ax.plot(t, np.degrees(c), alpha=0.7)
    ax.axhline(180, color="k", ls="--", lw=1, label="goal")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("valve angle [deg]")
    ax.set_title("Scripted valve turning (sim)")
    ax.legend()
    fig.tight_layout()
    path = ctx.out / "sim_rollouts.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    env.close()
    return {"episodes": episodes, "success_rate": float(np.mean(successes)),
            "final_angle_deg": [float(np.degrees(c[-1])) for c in curves],
            "plot": path.name, "policy": "scripted teacher (lowcostdex.sim.scripted)"}


def _teacher(env: Any) -> Any:
    from lowcostdex.sim.scripted import ValveTurnTeacher

    return ValveTurnTeacher()


STAGES: tuple[tuple[str, Callable[[Context], dict[str, Any]]], ...] = (
    ("sim_rollouts", stage_sim_rollouts),
)


def run(ctx: Context) -> Path:
    """Run every stage, write results.json and report.md into ``ctx.out``; return the report."""
    from rich.console import Console

    console = Console()
    ctx.out.mkdir(parents=True, exist_ok=True)
    for name, fn in STAGES:
        t0 = time.perf_counter()
        with console.status(f"[bold]{name}[/bold] ..."):
            result = fn(ctx)
        result["seconds"] = round(time.perf_counter() - t0, 1)
        ctx.results[name] = result
        console.print(f"[green]done[/green] {name} ({result['seconds']} s)")
    (ctx.out / "results.json").write_text(json.dumps(ctx.results, indent=2))
    report = ctx.out / "report.md"
    report.write_text(_report(ctx))
    return report


def _report(ctx: Context) -> str:
    lines = ["# lowcostdex main job", "", f"size: {ctx.size}, seed: {ctx.seed}", ""]
    for name, res in ctx.results.items():
        lines += [f"## {name.replace('_', ' ')}", ""]
        for k, v in res.items():
            if k != "plot":
                lines.append(f"- {k}: {v}")
        if "plot" in res:
            lines += ["", f"![{name}]({res['plot']})"]
        lines.append("")
    return "\n".join(lines)


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("main", help="run the main job end to end (emulated D'Claw by default)")
    p.add_argument("--out", type=Path, default=Path("runs/main"), help="output folder")
    p.add_argument("--size", choices=("smoke", "default", "long"), default="default",
                   help="budget: smoke (CI), default (~15 min on 2 cores), long")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--port", default=None, help="serial port of a real D'Claw (default: emulated)")
    p.set_defaults(func=_main)


def _main(args: argparse.Namespace) -> int:
    ctx = Context(out=args.out, size=args.size, seed=args.seed, port=args.port)
    report = run(ctx)
    print(f"REPORT {report.resolve()}")
    return 0
