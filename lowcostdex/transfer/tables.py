"""The transfer loop's results: per-condition summaries with 95 % Wilson intervals, the final
valve error (median with a distribution-free interval, per seed) and success at a looser
tolerance beside them, the Markdown tables (own robot, final error, paired against nominal on the
same episodes, cross-robot), the per-cell
records of ``transfer.json``, the figure and what the analysis named beside the truth.

Success at the task's tolerance flips when a policy's final error sits at the tolerance (a
policy ending 0.099 rad and one ending 0.101 rad count 50/50 and 0/50); the median final error
moves by 0.002 rad for them, and success at ``LOOSE_TOL`` says whether they all end near.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from lowcostdex.transfer.config import CONDITIONS, LOOSE_TOL, PER_ROBOT


def _cell(successes: int, n: int) -> str:
    from lowcostdex.stats import wilson_interval

    if n == 0:
        return "-"
    lo, hi = wilson_interval(successes, n)
    return f"{successes / n:.2f} [{lo:.2f}, {hi:.2f}]"


def loose_successes(errors: list[float], tol: float = LOOSE_TOL) -> int:
    """Episodes whose final error [rad] is below ``tol``."""
    return int(sum(float(e) < tol for e in errors))


def error_cell(rs: list[dict[str, Any]], tol: float = LOOSE_TOL) -> dict[str, Any] | None:
    """The final valve errors [rad] of some rows pooled: median with its 95 % interval from
    order statistics (``lowcostdex.stats.median_interval``, over the pooled episodes: like the
    Wilson intervals of the success rates, it assumes independent episodes, which the episodes
    of one deterministic policy are not), the median of each seed's episodes (seeds are the
    independent units) and the successes at ``tol``; None without episodes."""
    from lowcostdex.stats import median_interval

    errors = [float(e) for r in rs for e in r["final_error"]]
    if not errors:
        return None
    median, low, high, coverage = median_interval(errors)
    seeds = sorted({r["seed"] for r in rs})
    per_seed = [float(np.median([e for r in rs if r["seed"] == k for e in r["final_error"]]))
                for k in seeds]
    return {"median": median, "low": low, "high": high, "coverage": coverage,
            "per_seed": per_seed, "seeds": seeds, "loose": (loose_successes(errors, tol),
                                                            len(errors))}


def own_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows of policies on the robot they were made for (or, for nominal and randomized, made
    for none): the main table."""
    return [r for r in rows if r["policy_robot"] in (None, r["robot"])]


def summarize(rows: list[dict[str, Any]], robots: list[str]) -> dict[str, dict[str, Any]]:
    """Per condition (rows of one algo): pooled successes per robot (over seeds), on robots, in
    training sims; only each policy on the robot it was made for. ``covered``: the robots
    with a policy of the condition (``--made-for`` leaves the others out of its mean)."""
    out: dict[str, dict[str, Any]] = {}
    for cond in CONDITIONS:
        rs = [r for r in own_rows(rows) if r["condition"] == cond]
        if not rs:
            continue
        per_robot = {}
        for name in robots:
            cell = [r for r in rs if r["robot"] == name]
            per_robot[name] = (sum(r["success"] for r in cell), sum(r["episodes"] for r in cell))
        robot_k = sum(k for k, _ in per_robot.values())
        robot_n = sum(n for _, n in per_robot.values())
        # each policy's own-sim evaluation once (a nominal policy has one row per robot)
        sims = list({(r["policy"], r["seed"]): r for r in rs}.values())
        sim_k = sum(r["sim_success"] for r in sims)
        sim_n = sum(r["sim_episodes"] for r in sims)
        identical = all(len(set(r["sim_final_error"])) == 1 for r in sims)
        # in the training sim from the training starts (--start-range; None: not evaluated)
        starts = [r for r in sims if r.get("sim_starts_episodes")]
        errors = [e for r in rs for e in r["final_error"]]
        # the independent units: a deterministic policy on a robot repeats nearly one episode
        works = sum(2 * r["success"] >= r["episodes"] > 0 for r in rs)
        errs = {name: error_cell([r for r in rs if r["robot"] == name]) for name in robots}
        out[cond] = {"per_robot": per_robot, "robots": (robot_k, robot_n), "sim": (sim_k, sim_n),
                     "errors": errs, "errors_robots": error_cell(rs),
                     "covered": [name for name in robots if per_robot[name][1]],
                     "pairs": (works, len(rs)),
                     "sim_identical": identical, "policies": len(sims),
                     "sim_starts": (sum(r["sim_starts_success"] for r in starts),
                                    sum(r["sim_starts_episodes"] for r in starts))
                     if starts else None,
                     "drop": sim_k / sim_n - robot_k / robot_n,
                     "median_final_error": float(np.median(errors)) if errors else math.nan,
                     "train_wall_seconds": float(np.mean([r["train_wall_seconds"]
                                                          for r in sims]))}
    return out


def table_markdown(summary: dict[str, dict[str, Any]], robots: list[str]) -> str:
    """One line per condition. With ``--start-range`` a column says how the policies do in
    their training sim from the starts they trained on (the task's starts are a point in
    them: a policy may succeed there and on no other start)."""
    starts = any(s.get("sim_starts") for s in summary.values())
    head = ["condition", *[f"robot {r}" for r in robots], "mean on robots",
            "policy-robot pairs that work (>= half the episodes)",
            "in training sim" + (" from the task's start" if starts else "")
            + " (on_robot: the robot)",
            *(["in training sim from its training starts"] if starts else []),
            "sim-to-robot drop", "median final error [rad]", "training wall [s]"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for cond, s in summary.items():
        cells = [_cell(*s["per_robot"][r]) for r in robots]
        sim = _cell(*s["sim"])
        if s["sim_identical"]:  # a deterministic policy from a fixed start in a fixed sim
            k, n = s["sim"]
            sim = f"{k / n:.2f} (one deterministic episode per policy, x{s['policies']})"
        extra = [_cell(*s["sim_starts"]) if s.get("sim_starts") else "-"] if starts else []
        covered = s.get("covered", robots)
        only = "" if len(covered) == len(robots) else f" ({', '.join(covered)} only)"
        pairs = "{} of {}".format(*s["pairs"]) if "pairs" in s else "-"
        lines.append("| " + " | ".join([cond, *cells, _cell(*s["robots"]) + only, pairs, sim,
                                        *extra,
                                        f"{s['drop']:+.2f}{only}",
                                        f"{s['median_final_error']:.2f}",
                                        f"{s['train_wall_seconds']:.0f}"]) + " |")
    return "\n".join(lines)


def _error_text(c: dict[str, Any] | None) -> str:
    if c is None:
        return "-"
    seeds = ", ".join(f"{m:.3f}" for m in c["per_seed"])
    return f"{c['median']:.3f} [{c['low']:.3f}, {c['high']:.3f}]; per seed {seeds}"


def errors_markdown(summary: dict[str, dict[str, Any]], robots: list[str],
                    tol: float = LOOSE_TOL) -> str:
    """One line per condition: the final valve error on each robot (median [95 % interval
    over the pooled episodes]; the median of each seed's episodes) and the success rate at
    ``tol`` per robot and pooled: measures that do not flip when policies end near the task's
    tolerance."""
    head = ["condition", *[f"final error on robot {r} [rad]" for r in robots],
            *[f"robot {r} < {tol:g} rad" for r in robots], f"mean on robots < {tol:g} rad"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for cond, s in summary.items():
        errs = s["errors"]
        loose = [errs[r]["loose"] if errs[r] else (0, 0) for r in robots]
        pooled = (sum(k for k, _ in loose), sum(n for _, n in loose))
        lines.append("| " + " | ".join([cond, *[_error_text(errs[r]) for r in robots],
                                        *[_cell(*c) for c in loose], _cell(*pooled)]) + " |")
    return "\n".join(lines)


def _p(p: float) -> str:
    return f"{p:.2g}"  # two significant digits: 0.062, 0.0047, 1


def paired_markdown(rows: list[dict[str, Any]], robots: list[str], baseline: str = "nominal"
                    ) -> str:
    """Each condition against ``baseline`` on the same evaluation episodes (every cell plays
    the episode seeds ``EVAL_SEED``): per robot and seed, each policy on the robot it was made
    for (rows of one algo). Episodes only the condition solved / only the baseline solved with
    the exact one-sided McNemar p that the condition solves more (``stats.paired_test``; "-"
    for cells recorded without per-episode successes), the final error's medians with the
    one-sided Wilcoxon signed-rank p that the condition ends nearer the goal
    (``stats.paired_errors``); then per robot and condition the seeds as the units: in how many
    seeds the condition's median final error is below the baseline's, with the one-sided sign
    test p (Binomial(n, 1/2)). A loss reads as more episodes "only baseline" and p near 1.
    Empty when no baseline policy shares a robot and seed with another condition."""
    from scipy.stats import binomtest

    from lowcostdex.stats import paired_errors, paired_test

    own = own_rows(rows)
    base = {(r["robot"], r["seed"]): r for r in own if r["condition"] == baseline}
    head = ["robot", "seed", "condition", f"successes ({baseline} -> condition)",
            f"episodes only the condition / only {baseline} solved", "McNemar p (one-sided)",
            f"median final error [rad] ({baseline} -> condition)", "Wilcoxon p (one-sided)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    units: dict[tuple[str, str], list[bool]] = {}
    for name in robots:
        for cond in CONDITIONS:
            if cond == baseline:
                continue
            for r in sorted((r for r in own if r["condition"] == cond and r["robot"] == name),
                            key=lambda r: r["seed"]):
                b = base.get((name, r["seed"]))
                if b is None or len(b["final_error"]) != len(r["final_error"]):
                    continue
                before = {"solved": b.get("solved"), "final_goal_errors": b["final_error"]}
                after = {"solved": r.get("solved"), "final_goal_errors": r["final_error"]}
                mc, wx = paired_test(before, after), paired_errors(before, after)
                units.setdefault((name, cond), []).append(
                    float(np.median(r["final_error"])) < float(np.median(b["final_error"])))
                lines.append("| " + " | ".join([
                    name, str(r["seed"]), cond,
                    f"{b['success']} -> {r['success']} of {r['episodes']}",
                    "-" if mc is None else f"{mc[0]} / {mc[1]}",
                    "-" if mc is None else _p(mc[2]),
                    "-" if wx is None else f"{wx[0]:.3f} -> {wx[1]:.3f}",
                    "-" if wx is None else _p(wx[2])]) + " |")
    if not units:
        return ""
    lines.append("")
    for (name, cond), nearer in units.items():
        k, n = sum(nearer), len(nearer)
        p = binomtest(k, n, 0.5, alternative="greater").pvalue
        lines.append(f"- robot {name}, {cond}: nearer the goal than {baseline} (median final "
                     f"error) in {k} of {n} seed(s), sign test p = {_p(float(p))}")
    return "\n".join(lines)


def cells_json(summaries: dict[str, dict[str, dict[str, Any]]], robots: list[str],
               tol: float = LOOSE_TOL) -> list[dict[str, Any]]:
    """``transfer.json``'s ``cells``: per algorithm, condition and robot (policies on the robot
    they were made for, seeds pooled) the success at the task's tolerance and at ``tol`` and
    the final error's median with its interval and per-seed medians [rad]."""
    out = []
    for algo, summary in summaries.items():
        for cond, s in summary.items():
            for name in robots:
                c = s["errors"][name]
                if c is None:
                    continue
                k, n = s["per_robot"][name]
                out.append({"algo": algo, "condition": cond, "robot": name, "success": k,
                            "episodes": n, "loose_tolerance": tol, "success_loose": c["loose"][0],
                            "final_error_median": round(c["median"], 5),
                            "final_error_interval": [round(c["low"], 5), round(c["high"], 5)],
                            "interval_coverage": round(c["coverage"], 4),
                            "final_error_median_per_seed": [round(m, 5) for m in c["per_seed"]],
                            "seeds": c["seeds"]})
    return out


def _mean(values: list[Any], fmt: str) -> str:
    """The mean of ``values`` formatted, or "-" when any is missing (runs made before it was
    recorded)."""
    if not values or any(v is None for v in values):
        return "-"
    return format(float(np.mean([float(v) for v in values])), fmt)


def identification_cost(ident: dict[str, Any]) -> dict[str, float | None]:
    """One robot's identification summed over its fingers and its valve-log fit (when it has
    one): robot time [s] (the logs), wall of recording and of the analysis / fit [s], CPU of
    the analysis / fit [s] (None where not recorded)."""
    fingers = list(ident["fingers"].values())
    cpu = [f.get("analysis_cpu_seconds") for f in fingers]
    valve = ident.get("valve_fit")
    if valve is not None:  # the valve log and its fit, counted as identification
        fingers.append({"robot_seconds": valve["robot_seconds"],
                        "record_wall_seconds": valve["record_wall_seconds"],
                        "analysis_wall_seconds": valve["fit_wall_seconds"]})
        cpu.append(valve["fit_cpu_seconds"])
    return {"robot_seconds": float(sum(f["robot_seconds"] for f in fingers)),
            "record_wall_seconds": float(sum(f["record_wall_seconds"] for f in fingers)),
            "analysis_wall_seconds": float(sum(f["analysis_wall_seconds"] for f in fingers)),
            "analysis_cpu_seconds": None if None in cpu else float(sum(cpu))}


def cost_markdown(rows: list[dict[str, Any]], idents: dict[str, dict[str, Any]]) -> str:
    """What a policy of each condition cost, per robot it was made for (rows of one algo; each
    policy once, seeds averaged): samples, robot time [h] (on_robot: its training on the robot;
    identified conditions: the identification logs, recorded once per robot and shared by both
    identified conditions and every seed), identification wall (recording + analysis) and
    analysis CPU per robot, training wall and CPU per policy, and the wall from nothing to the
    first policy (identification + training). Wall times grow with a shared machine's load;
    "-": not recorded (runs made before it was, or no identification in this run)."""
    head = ["condition", "made for", "policies", "samples per policy",
            "robot time per policy [h]", "identification per robot: robot time [s]",
            "identification wall: recording + analysis [s]", "analysis CPU [s]",
            "training wall per policy [s]", "training CPU per policy [s]",
            "wall to the first policy [s]"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for cond in CONDITIONS:
        rs = [r for r in own_rows(rows) if r["condition"] == cond]
        for made_for in sorted({r["policy_robot"] for r in rs}, key=lambda x: x or ""):
            policies = list({(r["policy"], r["seed"]): r for r in rs
                             if r["policy_robot"] == made_for}.values())
            ident = (identification_cost(idents[made_for])
                     if cond in ("identified", "identified_randomized") and made_for in idents
                     else None)
            train_wall = float(np.mean([p["train_wall_seconds"] for p in policies]))
            if cond == "on_robot":
                robot_h = _mean([p.get("robot_hours") for p in policies], ".2f")
            elif ident is not None:
                robot_h = f"{ident['robot_seconds'] / 3600:.3f} (identification)"
            elif cond in ("identified", "identified_randomized"):
                robot_h = "-"
            else:
                robot_h = "0"
            if ident is None:
                id_cells = ["-", "-", "-"]
                first = train_wall if cond not in ("identified", "identified_randomized") \
                    else None
            else:
                wall = ident["record_wall_seconds"] + ident["analysis_wall_seconds"]
                cpu = ident["analysis_cpu_seconds"]
                id_cells = [f"{ident['robot_seconds']:.0f}",
                            f"{ident['record_wall_seconds']:.0f} + "
                            f"{ident['analysis_wall_seconds']:.0f}",
                            "-" if cpu is None else f"{cpu:.0f}"]
                first = wall + train_wall
            lines.append("| " + " | ".join([
                cond, made_for or "-", str(len(policies)),
                _mean([p.get("samples") for p in policies], ".0f"), robot_h, *id_cells,
                f"{train_wall:.0f}", _mean([p.get("train_cpu_seconds") for p in policies], ".0f"),
                "-" if first is None else f"{first:.0f}"]) + " |")
    return "\n".join(lines)


def extended_lines(rows: list[dict[str, Any]]) -> list[str]:
    """The policies of ``rows`` (one algo) that trained on under the EXTEND rule (below the
    success target in their own sim at the end of the size's budget; ``config.EXTEND``): one
    line each, from what to what and at what CPU; none: no lines."""
    done = {(r["policy"], r["seed"]): r for r in rows if r.get("extended")}
    if not done:
        return []

    def part(x: Any, fmt: str) -> str:
        return "-" if x is None else format(x, fmt)

    lines = [f"Trained on under the EXTEND rule (below the success target in their own sim at "
             f"the end of the budget; samples above include it): {len(done)} "
             f"polic{'y' if len(done) == 1 else 'ies'}", ""]
    for (policy, seed), r in sorted(done.items()):
        e = r["extended"]
        it = e.get("iteration")
        lines.append(
            f"- {policy} seed {seed}: own sim {part(e.get('eval_success_rate'), '.2f')} after "
            f"{part(None if it is None else it + 1, 'd')} iterations -> "
            f"{part(e.get('final_eval_success_rate'), '.2f')} after {e['to_iterations']} "
            f"({r['samples']} samples); extension CPU "
            f"{part(e.get('extension_cpu_seconds'), '.0f')} s")
    return [*lines, ""]


def cross_markdown(rows: list[dict[str, Any]], robots: list[str]) -> str:
    """Per-robot policies (rows: made for robot X) on every robot (columns), pooled over seeds,
    beside the nominal policy on the same robot: does robot A's model help on robot B?"""
    head = ["condition", "made for", *[f"on robot {r}" for r in robots]]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def pooled(rs: list[dict[str, Any]]) -> str:
        return _cell(sum(r["success"] for r in rs), sum(r["episodes"] for r in rs))

    nominal = [r for r in rows if r["condition"] == "nominal"]
    if nominal:
        lines.append("| " + " | ".join(["nominal", "-", *[
            pooled([r for r in nominal if r["robot"] == y]) for y in robots]]) + " |")
    for cond in PER_ROBOT:
        for x in robots:
            rs = [r for r in rows if r["condition"] == cond and r["policy_robot"] == x]
            if not rs:
                continue
            cells = []
            for y in robots:
                c = pooled([r for r in rs if r["robot"] == y])
                cells.append(f"**{c}**" if x == y else c)
            lines.append("| " + " | ".join([cond, x, *cells]) + " |")
    if len(lines) == 2:
        return ""
    off = {}
    for cond in PER_ROBOT:
        rs = [r for r in rows if r["condition"] == cond and r["policy_robot"] is not None]
        other = [r for r in rs if r["policy_robot"] != r["robot"]]
        own = [r for r in rs if r["policy_robot"] == r["robot"]]
        if other:
            off[cond] = (pooled(own), pooled(other))
    summary = "; ".join(f"{c}: own robot {a}, other robots {b}" for c, (a, b) in off.items())
    return "\n".join(lines) + ("\n\nPooled: " + summary if summary else "")


def plot(summaries: dict[str, dict[str, dict[str, Any]]], robots: list[str], path: Path,
         title: str) -> Any:
    """Per algorithm, success rates (top) and final valve errors (bottom: median with its
    interval, each seed's median, the task's tolerance and ``LOOSE_TOL``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lowcostdex.stats import wilson_interval

    columns = [*robots, "mean"]
    fig, axes = plt.subplots(2, len(summaries), figsize=(7 * len(summaries) + 2.5, 8.5),
                             squeeze=False)
    colors = {"nominal": "#888888", "randomized": "#4c72b0", "identified": "#dd8452",
              "identified_randomized": "#55a868", "on_robot": "#c44e52"}
    for ax, (algo, summary) in zip(axes[0], summaries.items(), strict=True):
        width = 0.8 / max(1, len(summary))
        for i, (cond, s) in enumerate(summary.items()):
            # no mean bar for a condition with policies for some robots only (--made-for)
            whole = len(s.get("covered", robots)) == len(robots)
            cells = [s["per_robot"][r] for r in robots] + [s["robots"] if whole else (0, 0)]
            rate = np.array([k / n if n else np.nan for k, n in cells])
            ci = np.array([wilson_interval(k, n) if n else (np.nan, np.nan) for k, n in cells])
            x = np.arange(len(columns)) + (i - (len(summary) - 1) / 2) * width
            ax.bar(x, rate, width, color=colors[cond],
                   label=f"{cond} (training env {s['sim'][0] / s['sim'][1]:.2f})",
                   yerr=[rate - ci[:, 0], ci[:, 1] - rate], capsize=3)
            ax.plot(x[-1:], [s["sim"][0] / s["sim"][1]], marker="_", markersize=14, color="k",
                    linestyle="None", label="success in the training env" if i == 0 else None)
            if s.get("sim_starts"):  # --start-range: from the starts it trained on
                k, n = s["sim_starts"]
                ax.plot(x[-1:], [k / n], marker="x", markersize=7, color="k", linestyle="None",
                        label="... from its training starts" if i == 0 else None)
        ax.set_xticks(np.arange(len(columns)))
        ax.set_xticklabels([f"robot {r}" for r in robots] + ["mean over robots"])
        ax.set_xlabel("robot (policies on the robot they were made for)")
        ax.set_ylabel("success rate (95 % Wilson interval)")
        ax.set_ylim(0, 1.05)
        ax.set_title(f"{algo.upper()}: {title}", fontsize=9)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
    for ax, (algo, summary) in zip(axes[1], summaries.items(), strict=True):
        _plot_errors(ax, algo, summary, robots, colors)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return fig


def _plot_errors(ax: Any, algo: str, summary: dict[str, dict[str, Any]], robots: list[str],
                 colors: dict[str, str]) -> None:
    from lowcostdex.sim.envs.dclaw_tasks import TurnConfig

    floor = 1e-4  # [rad] a log axis: errors below it (rounded to 0) are drawn at it
    width = 0.8 / max(1, len(summary))
    for i, (cond, s) in enumerate(summary.items()):
        for j, name in enumerate(robots):
            c = s["errors"][name]
            if c is None:
                continue
            x = j + (i - (len(summary) - 1) / 2) * width
            m, lo, hi = (max(floor, v) for v in (c["median"], c["low"], c["high"]))
            ax.errorbar([x], [m], yerr=[[m - lo], [hi - m]], color=colors[cond], marker="o",
                        markersize=6, capsize=3, linestyle="None",
                        label=f"{cond}: median [95 % interval]" if j == 0 else None)
            ax.plot([x] * len(c["per_seed"]), [max(floor, v) for v in c["per_seed"]],
                    marker=".", markersize=4, color="k", linestyle="None",
                    label="median of one seed" if i == 0 and j == 0 else None)
    tol = TurnConfig().success_tol
    ax.axhline(tol, color="k", linewidth=0.8, label=f"task tolerance {tol:g} rad")
    ax.axhline(LOOSE_TOL, color="k", linewidth=0.8, linestyle="--",
               label=f"looser tolerance {LOOSE_TOL:g} rad")
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(robots)))
    ax.set_xticklabels([f"robot {r}" for r in robots])
    ax.set_xlim(-0.6, len(robots) - 0.4)
    ax.set_xlabel("robot (policies on the robot they were made for)")
    ax.set_ylabel("final valve error [rad], log scale")
    ax.set_title(f"{algo.upper()}: final valve error on the robot", fontsize=9)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)


def named_vs_truth(idents: dict[str, dict[str, Any]]) -> list[str]:
    """Per robot and finger: the catalogue effects it carries (hidden robots) vs the ones the
    analysis named."""
    from lowcostdex.sim.effects import effect

    lines = ["| robot | finger | carries (catalogue) | named by gap analyze | held-out RMSE "
             "before -> after [mrad] |", "|---|---|---|---|---|"]
    for name, ident in idents.items():
        for finger, f in ident["fingers"].items():
            carried = []
            for e in ident["truth"].get("effects", ()):
                cls = effect(e["effect"])
                idx = [k for k, j in enumerate(e["joints"]) if j.startswith(finger + "_")]
                for p, values in e["params"].items():
                    if any(not np.isclose(values[k], cls.param(p).null) for k in idx):
                        carried.append(e["effect"])
                        break
            truth = (", ".join(carried) or "-") if "effects" in ident["truth"] else "unknown"
            named = [c["effect"] for c in f["causes"]]
            lines.append(f"| {name} | {finger} | {truth} | {', '.join(named) or '-'} | "
                         f"{f['baseline_rmse_mrad']:.2f} -> {f['extended_rmse_mrad']:.2f} |")
    return lines
