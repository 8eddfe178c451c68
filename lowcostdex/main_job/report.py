"""The main job's report: one summary line per stage, report.md and its HTML rendering."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lowcostdex.main_job.setup import Context
from lowcostdex.stats import paired_errors, paired_test


def stage_summary(name: str, r: dict[str, Any]) -> str:
    if name == "bus":
        return (f"{r['motors_found']} motors found, missing {r['motors_missing'] or 'none'}; "
                f"calibration moved offsets by {r.get('calibration_ticks', 0):.1f} ticks at most")
    if name == "demos":
        played = (f", {r['successful_playbacks']}/{r['playbacks']} successful playbacks"
                  if "playbacks" in r else "")
        return f"{r['successful']}/{r['episodes']} successful demonstrations{played} -> {r['file']}"
    if name == "train":
        def held(key: str) -> str:
            a = r.get(key, {})
            return (f"{a['eval_successes']}/{a['eval_episodes']}" if "eval_successes" in a
                    else "n/a")

        def samples(key: str) -> str:
            a = r[key]
            where = "in simulation" if a.get("trained_in") == "simulation" else "on the robot"
            return f"{a['samples']} training samples {where}"

        return (f"held-out success: DAPG {held('dapg')} ({samples('dapg')}), NPG "
                f"{held('npg')} ({samples('npg')}), the behaviour clone alone {held('bc')}, "
                "random actions "
                f"{held('random')}")
    if name == "gap":
        named = ", ".join(c["effect"] for c in r["causes"]) or "no cause"
        return (f"named: {named}; held-out RMSE {r['baseline_heldout_rmse_mrad']:.1f} -> "
                f"{r['extended_heldout_rmse_mrad']:.1f} mrad (floor {r['noise_floor_mrad']:.2f})")
    return f"done in {r['seconds']} s"


def markdown_report(ctx: Context) -> str:
    R = ctx.results
    lines = ["# lowcostdex: the main job", "",
             f"Robot: {'emulated D' + chr(39) + 'Claw' if ctx.emulated else ctx.port}; task "
             f"{ctx.task} (`{ctx.setup.env_id}`{_overrides(ctx)}); size {ctx.size}; seed "
             f"{ctx.seed}.", ""]
    if "bus" in R:
        b = R["bus"]
        lines += ["## 1. The robot on its bus", "",
                  f"{b['motors_found']} motors answered on {b['port']}; missing: "
                  f"{b['motors_missing'] or 'none'}.", "",
                  "| id | model | firmware | temperature [C] | voltage [V] | errors |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {m['id']} | {m['model']} | {m['firmware']} | {m['temperature']} | "
                  f"{m['voltage']} | {', '.join(m['errors']) or '-'} |" for m in b["motors"]]
        if "calibration_ticks" in b:
            lines += ["", f"Calibration (hand in its zero pose) changed the default offsets by at "
                          f"most {b['calibration_ticks']:.1f} encoder ticks; the spec is "
                          f"`{b['hand_spec']}`."]
        lines.append("")
    if "demos" in R:
        d = R["demos"]
        lines += ["## 2. Kinesthetic demonstrations", "",
                  f"{d['successful']} of {d['episodes']} demonstrations {ctx.setup.did} "
                  f"({d['steps']} steps, `{d['file']}`); recording took "
                  f"{d['robot_seconds_recording']} s and the auto-resets "
                  f"{d['robot_seconds_resets']} s of robot time.", ""]
        if "playbacks" in d:
            alpha = d["servo_response"]["alpha"]
            lines += [f"Before recording, {d['robot_seconds_servo_id']} s of random goals "
                      f"identified the servos' response (a servo covers {min(alpha):.2f}-"
                      f"{max(alpha):.2f} of a commanded step per control period); each step is "
                      "labelled with the goal that reproduces it. The robot then played each "
                      f"successful demonstration back with noisy goals: {d['playbacks']} "
                      f"playbacks, {d['successful_playbacks']} {ctx.setup.did} "
                      f"({d['robot_seconds_playbacks']} s). The behaviour clone learns from the "
                      "successful episodes of both.", ""]
    if "train" in R:
        t = R["train"]
        n_held = t.get("bc", {}).get("eval_episodes", "?")
        in_sim = t["dapg"].get("trained_in") == "simulation"
        lines += ["## 3. DAPG vs NPG" + (": DAPG trained in simulation, NPG on the robot, "
                                         "both judged on the robot" if in_sim else
                                         " on the robot"), ""]
        if in_sim:
            d = t["dapg"]
            lines += [f"DAPG trained in simulation: MuJoCo with the task's model, "
                      f"{d['iterations']} iterations of {d['episodes_per_iteration']} "
                      f"episodes ({d['samples']} samples, no robot time), each episode under "
                      "randomly drawn servo and model effects ("
                      + ", ".join(e.replace("_", " ") for e in d["randomized"])
                      + f"). {_validated_in_words(d)} NPG trained on the robot. Every "
                      "held-out episode below ran on the robot.", ""]
            if "clones" in t:
                lines += [_clones_words(t["clones"]), ""]
            if "streams" in t:
                lines += [_streams_words(t["streams"]), ""]
        lines += ["Validation: deterministic episodes (the policy's mean action) every "
                  f"{ctx.budget.eval_every or 'last'} iteration(s) during training "
                  f"({_validation_words(t, ctx.budget.eval_episodes)}; the behaviour clone's evaluation "
                  "before the first RL step counts as one of DAPG's). They choose each run's "
                  "policy (`train_*/policy.pt`): the best validated one, the clone itself when "
                  "no RL iterate beat it." + _dense_words(t.get("dapg", {})), "",
                  "Samples are the training episodes' env steps; the validation episodes' steps "
                  "are counted apart (both cost robot time on the robot; robot time includes "
                  "resets).", "",
                  "| | trained in | training samples | validation steps | robot time [min] | "
                  "training success (last) | validation success (last) | best validation "
                  "(iteration) | first validation >= 80 % at |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for algo in ("dapg", "npg"):
            a = t[algo]
            first = a.get("first_eval_crossing_samples")
            best_it = a.get("best_iteration")
            where = ("the clone" if best_it is not None and best_it < 0
                     else "-" if best_it is None else str(best_it))
            lines.append(
                f"| {algo.upper()} | {a.get('trained_in', 'robot')} | {a['samples']} | "
                f"{a.get('validation_samples') if a.get('validation_samples') is not None else '-'}"
                f" | {60 * a['robot_hours']:.1f} | "
                f"{a['final_training_success']:.2f} | "
                f"{a.get('last_validation_success', float('nan')):.2f} | "
                f"{a.get('best_eval_success', float('nan')):.2f} ({where}) | "
                f"{'not reached' if first is None else f'{first:.0f} samples'} |")
        lines += ["", f"Held-out: each policy on the same {n_held} episodes (reset seeds "
                      "disjoint from training and validation), mean action, success at the "
                      "last step, with a 95 % Wilson interval. " + _order_words(t), "",
                  "| policy | held-out success |", "|---|---|",
                  f"| uniformly random actions (measured) | {_rate(t.get('random', {}))} |",
                  f"| behaviour clone alone, before any RL | {_rate(t.get('bc', {}))} |",
                  f"| DAPG (clone + RL) | {_rate(t['dapg'])} |",
                  f"| NPG (RL from scratch) | {_rate(t['npg'])} |", "",
                  f"**What each stage added.** {_what_each_stage_added(t)}", "",
                  f"![learning curves]({t['plot']})", ""]
        demos_done = R.get("demos", {}).get("finished")
        if t.get("demos_finished") and demos_done and t["demos_finished"] != demos_done:
            lines += ["Note: the demonstrations were recorded again after this training ran; "
                      "these results come from the earlier demonstrations (kept in "
                      "`previous/`).", ""]
        if "rollout" in t:
            ro = t["rollout"]
            lines += [f"One deterministic rollout of the DAPG policy: final orientation error "
                      f"{ro['final_orientation_error_deg']} deg "
                      f"({'success' if ro['success'] else 'no success'}), beside a recorded "
                      "demonstration:", "", f"![flip rollout]({ro['plot']})", ""]
        lines += ["Run directories: `train_dapg/`, `train_npg/` (config, metrics.csv, "
                  "checkpoints, curves, summary.json; `lowcostdex train ... --resume` continues "
                  "them).", ""]
    if "gap" in R:
        g = R["gap"]
        lines += ["## 4. What the nominal simulation gets wrong", "",
                  f"{g['logs']} identification logs of {g['seconds_per_log']:.0f} s (one finger, "
                  f"50 Hz) replayed in the nominal model.", ""]
        if g.get("log_notes"):
            lines += ["What loading did to the logs: " + "; ".join(g["log_notes"]) + ".", ""]
        lines += [f"**Verdict:** {g['verdict']}", ""]
        if g["causes"]:
            lines += ["| named cause | joints | fitted parameters |", "|---|---|---|"]
            for c in g["causes"]:
                params = "; ".join(f"{k} = " + ", ".join(f"{v:.4g}" for v in vals)
                                   for k, vals in c["params"].items())
                lines.append(f"| {c['effect']} | {', '.join(c['joints'])} | {params} |")
        if g.get("truth"):
            truth = "; ".join(f"{e['effect']} ({', '.join(f'{k}={v:.4g}' for k, v in e['params'].items())})"
                              for e in g["truth"])
            lines += ["", f"What the emulated robot really carries: {truth}."]
        gain = g["gain"]
        lines += ["", f"Held-out RMSE: {g['baseline_heldout_rmse_mrad']:.2f} mrad (nominal) -> "
                      f"{g['extended_heldout_rmse_mrad']:.2f} mrad (extended); noise floor "
                      f"{g['noise_floor_mrad']:.2f} mrad. Full report: `{g['report']}`.", ""]
        if "interval" in gain:
            lines.insert(-1, f"Gain {1e3 * gain.get('absolute', float('nan')):.2f} mrad, 95 % "
                             f"interval {gain['interval']}.")
        lines += [f"![{p}]({p})" for p in g["plots"][:3]] + [""]
    if "report" in R:
        lines += ["## 5. Robot health", "", f"![robot health]({R['report']['plot']})", ""]
    lines += ["Stage timings [s]: " + ", ".join(f"{k} {v['seconds']}" for k, v in R.items()), ""]
    return "\n".join(lines)


def _clones_words(c: dict[str, Any]) -> str:
    """How DAPG's clone was chosen among several (``results["train"]["clones"]``)."""
    rows = c["candidates"]
    n = rows[0]["episodes"] if rows else 0
    chosen = next((r for r in rows if r["bc_seed"] == c["bc_seed"]), None)
    scores = ", ".join(f"{r['successes']}" for r in rows)
    return (f"The behaviour clone DAPG started from is the best of {len(rows)} clones fitted to "
            "the same demonstrations (each its own network initialisation and minibatch "
            f"order), judged on the same {n} episodes of the randomized simulation (their own "
            f"episode set, not DAPG's validation nor the held-out episodes): successes {scores} "
            f"of {n}; chosen: {chosen['successes'] if chosen else '?'} of {n} (BC seed "
            f"{c['bc_seed']}), ties broken by the median final |goal error|. This took "
            f"{c['seconds']} s ({c['cpu_seconds']} s of CPU) and no robot time. The clone "
            "row below is this chosen clone (not measured on the robot before the held-out "
            "episodes).")


def _validated_in_words(dapg: dict[str, Any]) -> str:
    """Which simulation validated DAPG's iterates and the clone, so chose DAPG's policy
    (``results["train"]["dapg"]["validated_in"]``, ``gapsim.validation_sim``)."""
    n = dapg.get("validation_episodes")
    v = dapg.get("validated_in")
    if not v or v.get("sim") != "gap-identified":
        why = f" ({v['why']})" if v else ""
        return (f"Its validation ({n} episodes), which chose DAPG's policy among its iterates "
                f"and the clone, ran in that randomized simulation{why}.")
    return (f"Its validation ({n} episodes), which chose DAPG's policy among its iterates and "
            f"the clone, ran in another simulation: {v['why']}. The gap stage measured these "
            "effects on the robot before training.")


def _dense_words(dapg: dict[str, Any]) -> str:
    """DAPG's validation schedule when it validated every late iterate."""
    dense, every = dapg.get("validation_dense_from"), dapg.get("validation_every")
    if dense is None:
        return ""
    return (f" DAPG's validation ran every {every} iterations and after every iteration from "
            f"iteration {dense} on (counted from 0): late iterates differ from one iteration "
            "to the next by several successes in 100 episodes, so each of them competes.")


def _streams_words(st: dict[str, Any]) -> str:
    """How DAPG's policy came from several runs (``results["train"]["streams"]``)."""
    runs, avg = st["runs"], st["average"]
    n = avg["eval_episodes"]
    told = ("It is DAPG's policy below." if st.get("chosen") == "average" else
            "It validated below the clone, so DAPG's policy below is the clone.")
    return (f"DAPG ran {len(runs)} times from that clone, each run with its own seed (its own "
            "randomization draws and training episodes; run directories "
            + ", ".join(f"`{r['dir']}/`" for r in runs) + "), and its policy is the average "
            "of the runs' last iterates' weights (`" + avg["file"] + "`): one run's gain on "
            "the robot moves with its randomization draws, the average keeps what the draws "
            f"share. The average solved {avg['eval_successes']} of {n} of the first run's "
            f"validation episodes. {told} The training table's DAPG row is the first run; "
            "the held-out table's is DAPG's policy.")


def _overrides(ctx: Context) -> str:
    """The task variant's configuration values, as the report names them."""
    values = ctx.setup.env_overrides
    return "".join(f", {k} {v}" for k, v in values.items()) if values else ""


def _rate(r: dict[str, Any]) -> str:
    """A measured rate with its episode count and 95 % interval, from a result's
    ``eval_successes`` / ``eval_episodes``."""
    from lowcostdex.stats import rate_text

    k, n = r.get("eval_successes"), r.get("eval_episodes")
    if k is None or not n:
        return "n/a (not evaluated)"
    return rate_text(int(k), int(n))


COMPARISONS = (
    ("random", "bc", "the demonstrations (behaviour clone vs uniformly random actions)"),
    ("bc", "dapg", "RL fine-tuning (DAPG vs the clone it started from)"),
    ("npg", "dapg", "demonstrations in RL (DAPG vs NPG from scratch, each with the samples "
                    "and the place of training the table above gives)"),
)
"""What the report judges: (before, after, what the step from before to after is)."""


def stage_verdicts(t: dict[str, Any]) -> list[dict[str, Any]]:
    """Each of COMPARISONS judged from the training results ``t`` (``results["train"]``): the
    rates before and after with their 95 % Wilson intervals and a verdict, "raised" or
    "lowered" only when the intervals do not overlap, else "no difference" ("not measured"
    when either side has no evaluation)."""
    from lowcostdex.stats import wilson_interval

    out = []
    for before, after, what in COMPARISONS:
        a, b = t.get(before, {}), t.get(after, {})
        row: dict[str, Any] = {"before": before, "after": after, "what": what}
        counts = [(r.get("eval_successes"), r.get("eval_episodes")) for r in (a, b)]
        if any(k is None or not n for k, n in counts):
            out.append({**row, "verdict": "not measured"})
            continue
        (ka, na), (kb, nb) = ((int(k), int(n)) for k, n in counts)
        ia, ib = wilson_interval(ka, na), wilson_interval(kb, nb)
        verdict = ("raised" if ib[0] > ia[1] else "lowered" if ib[1] < ia[0]
                   else "no difference")
        out.append({**row, "verdict": verdict, "rate_before": ka / na, "rate_after": kb / nb,
                    "ci_before": ia, "ci_after": ib})
    return out


def _validation_words(t: dict[str, Any], n: int) -> str:
    """How many validation episodes, and whether every validation ran the same ones (each
    run's count from its ``validation_episodes``, else ``n``)."""
    counts = {t.get(a, {}).get("validation_episodes", n) for a in ("dapg", "npg")}
    many = (f"{counts.pop()}" if len(counts) == 1 else
            f"{t['dapg']['validation_episodes']} (DAPG) / {t['npg']['validation_episodes']} (NPG)")
    if all(t.get(a, {}).get("validation_paired") for a in ("dapg", "npg")):
        return (f"the same {many} episodes every time within a run, so the candidates are "
                "compared on the same episodes")
    return f"{many} episodes each"


def _what_each_stage_added(t: dict[str, Any]) -> str:
    """Words for what each stage changed (``stage_verdicts``): a difference is called one only
    when the 95 % intervals do not overlap."""
    parts = []
    for i, v in enumerate(stage_verdicts(t)):
        # one sentence of clauses joined by "; ": only the first starts with a capital
        what = v["what"][0].upper() + v["what"][1:] if i == 0 else v["what"]
        if v["verdict"] == "not measured":
            parts.append(f"{what}: not measured")
            continue
        change = f"from {v['rate_before']:.2f} to {v['rate_after']:.2f}"
        if v["verdict"] == "no difference":
            parts.append(f"{what} changed success {change}, within the overlap of the 95 % "
                         "intervals: no difference the intervals alone can show")
        else:
            parts.append(f"{what} {v['verdict']} success {change}, beyond the 95 % intervals")
    text = "; ".join(parts) + "."
    bc, dapg = t.get("bc", {}), t.get("dapg", {})
    if dapg.get("trained_in") == "simulation":
        text += (f" DAPG's RL samples ({dapg.get('samples')}) came from the randomized "
                 "simulation, none from the robot; the clone and DAPG are compared on the "
                 "robot's held-out episodes.")
    if (bc.get("eval_episodes") and bc.get("eval_successes") == bc["eval_episodes"]
            and dapg.get("eval_successes") == dapg.get("eval_episodes")):
        text += (" The clone alone already solves this task here, so the RL stage cannot show "
                 "a gain on it.")
    paired = paired_test(bc, dapg)
    if paired is not None:
        only_after, only_before, pvalue = paired
        text += (f" Paired on the same {len(bc['solved'])} held-out episodes: DAPG alone solved "
                 f"{only_after}, the clone alone {only_before} (exact one-sided McNemar test "
                 f"that DAPG solves more, p = {pvalue:.3g}"
                 + ("): on the same episodes DAPG solved more than the clone." if pvalue <= 0.05
                    else "): no paired difference this run can show."))
    errors = paired_errors(bc, dapg)
    if errors is not None:
        med_before, med_after, pvalue = errors
        text += (f" Their final |goal error| on those episodes: median {med_before:.3f} rad for "
                 f"the clone, {med_after:.3f} rad for DAPG (one-sided Wilcoxon signed-rank test "
                 f"that DAPG ends nearer the goal, p = {pvalue:.3g}"
                 + ("): DAPG ended nearer the goal than the clone." if pvalue <= 0.05 else
                    "): no paired difference this run can show."))
    if dapg.get("best_iteration") == -1 and "streams" not in t:
        text += (" No DAPG iterate beat the clone on the validation episodes, so DAPG's policy "
                 "is the clone itself: at this budget RL did not improve on it.")
    return text


def _order_words(t: dict[str, Any]) -> str:
    """How the held-out episodes' robot state was controlled between policies
    (``main_job.heldout``)."""
    if t.get("bc", {}).get("heldout_robot") == "a freshly started emulated robot":
        return ("Each policy ran on a freshly started emulated robot (the same pose, motors "
                "at ambient), so its episodes do not depend on the policies evaluated before "
                "it: a robot carries its auto-reset's residue and its motors' warmth from one "
                "episode into the next.")
    if "heldout_robot" in t.get("bc", {}):
        return ("The policies ran one after another on the one robot (random, clone, DAPG, "
                "NPG), which carries its auto-reset's residue and its motors' warmth from one "
                "episode into the next: on the emulated robot that order moved a policy's "
                "count by about one episode in 100.")
    return ""


def write_html(markdown: str, path: Path) -> None:
    """A dependency-free HTML rendering of the report (headings, tables, images, paragraphs)."""
    import html
    import re

    out, table = [], False
    for line in markdown.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if set("".join(cells)) <= set("-: "):
                continue
            if not table:
                out.append("<table>")
                table = True
                out.append("<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in cells) + "</tr>")
            else:
                out.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
            continue
        if table:
            out.append("</table>")
            table = False
        m = re.match(r"!\[(.*)\]\((.*)\)", line)
        if m:
            out.append(f'<img src="{html.escape(m.group(2))}" alt="{html.escape(m.group(1))}" '
                       'style="max-width:100%">')
        elif line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            out.append(f"<h{level}>{html.escape(line.lstrip('# '))}</h{level}>")
        elif line.strip():
            text = html.escape(line)
            text = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", text)
            text = re.sub(r"`(.+?)`", r"<code>\1</code>", text)
            out.append(f"<p>{text}</p>")
    if table:
        out.append("</table>")
    style = ("body{font-family:sans-serif;max-width:60em;margin:2em auto}table{border-collapse:"
             "collapse}td,th{border:1px solid #ccc;padding:2px 8px}")
    path.write_text(f"<!doctype html><meta charset='utf-8'><title>lowcostdex main job</title>"
                    f"<style>{style}</style>\n" + "\n".join(out))
