"""Writing a gap-analysis report: report.json, report.md, PNG plots and the extended model.

``write_report(result, out)`` builds everything in a temporary sibling folder and moves it into
place at the end, so an interrupted or failed run never leaves a half-written report.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from lowcostdex.gap import chaos
from lowcostdex.gap.analyze import GapResult
from lowcostdex.gap.extension import save_extended
from lowcostdex.gap.results import timestep_note
from lowcostdex.outdir import staged_output, user_path
from lowcostdex.sim.mjwarnings import describe_warnings

PLOTS = ("traces.png", "residuals.png", "candidates.png")


def _intervals(result: GapResult) -> dict[str, dict[str, list]]:
    return {c.effect: {p: d["interval"] for p, d in c.params.items()} for c in result.causes}


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else (None if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(x, np.integer):
        return int(x)
    return x


def write_report(result: GapResult, out: str | Path) -> Path:
    """Write report.json, report.md, plots and extended/ into ``out``.

    Everything is built in a temporary sibling folder and moved into place at the end
    (:func:`lowcostdex.outdir.staged_output`): a folder holding files this command did not write
    is refused untouched, and a previous report is kept in ``out/previous/<time>/``.
    """
    if not isinstance(result, GapResult):  # before anything is written
        raise TypeError("write_report(result, out) takes the GapResult analyze() returned, then "
                        "the folder" + (": the arguments are swapped"
                                        if isinstance(out, GapResult) else
                                        f", not {type(result).__name__}") +
                        "; e.g. write_report(analyze(ds, GapConfig()), 'report/')")
    with staged_output(out, "gap analyze") as tmp:
        payload = _jsonable(result.to_dict())
        payload["extended_model"] = "extended/effects.json"
        payload["plots"] = list(PLOTS)
        (tmp / "report.json").write_text(json.dumps(payload, indent=2))
        save_extended(tmp / "extended", result.models, result.effects, _intervals(result))
        plot_traces(result, tmp / "traces.png")
        plot_residuals(result, tmp / "residuals.png")
        plot_candidates(result, tmp / "candidates.png")
        (tmp / "report.md").write_text(markdown(result))
    return user_path(out)


# ------------------------------------------------------------------------------------------------
# text


def _mrad(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{1e3 * x:.3g}"


def summary(result: GapResult) -> str:
    """A few lines for the terminal."""
    g = result.gain
    lines = [f"verdict: {result.verdict}",
             f"held-out RMSE: baseline {_mrad(g.baseline_rmse)} mrad -> extended "
             f"{_mrad(g.extended_rmse)} mrad (noise floor {_mrad(g.noise_floor)} mrad; "
             f"{g.episodes} test episodes)",
             f"gain: {_mrad(g.absolute)} mrad, {_gain_interval(g)}"
             + (f", {100 * g.reducible_explained:.0f} % of the reducible error explained"
                if g.reducible_explained is not None else "")]
    lines += [f"  {x}" for x in _left_lines(result)]
    for c in result.causes:
        vals = ", ".join(f"{p}={_fmt(d['value'])} {d['unit']}" for p, d in c.params.items())
        lines.append(f"  cause: {c.effect} on {', '.join(c.joints)}: {vals}; held-out RMSE after "
                     f"{_mrad(c.heldout_rmse_after)} mrad" + (f" [{'; '.join(c.flags)}]"
                                                                 if c.flags else "")
                     + (f" (equivalent: {', '.join(c.equivalent)})" if c.equivalent else ""))
        lines += [f"    range widened: {w}" for w in c.widened]
        lines += [f"    stand-in: {w}" for w in c.stand_in]
    return "\n".join(lines)


def _left_lines(result: GapResult) -> list[str]:
    """What the model leaves on held-out (``standin.residual_left``) and, when the later logs
    fit consistently worse, the drift note (``diagnostics.session_drift``)."""
    r, d = result.residual, result.drift
    out = []
    if r:
        out.append(f"left on held-out: {_mrad(r['rmse'])} mrad RMSE, {r['floors']:.3g}x the noise "
                   f"floor ({'within' if r['at_floor'] else 'above'} the "
                   f"{r['explained_within_floors']:g} floors a replay of an exact model leaves)")
    if d and d.get("logs"):
        each = ", ".join(f"{x['log'].replace(chr(92), '/').rsplit('/', 1)[-1]} "
                         f"{_mrad(x['rmse'])}" for x in d["logs"])
        out.append(f"open-loop RMSE per log in {d['order']} [mrad]: {each}")
    if d and d.get("note"):
        out.append(d["note"])
    return out


def _gain_interval(g) -> str:
    """The gain's 95 % interval, or why there is none (one test episode: a bootstrap over
    episodes resamples that one episode and gives a zero-width interval)."""
    if g.episodes > 1:
        return f"95 % CI [{_mrad(g.ci95[0])}, {_mrad(g.ci95[1])}]"
    return ("no interval: 1 test episode (a bootstrap over one episode says nothing); give "
            "more or longer logs, or --holdout logs")


def _fmt(v) -> str:
    vals = [f"{x:.4g}" for x in np.atleast_1d(v)]
    return vals[0] if len(vals) == 1 else "[" + ", ".join(vals) + "]"


def markdown(result: GapResult) -> str:
    """The human report."""
    g = result.gain
    r = result
    out = ["# Reality-gap report", "", f"**Verdict: {r.verdict}.** Selection stopped: "
           f"{r.stop_reason}.", "",
           f"Logs: {len(r.sources)}; joints: {', '.join(r.joints)}; episodes: "
           f"{len(r.split.train)} train, {len(r.split.select)} select, {len(r.split.test)} test "
           "(the test episodes were used only for the numbers below)" + _unscored(r) + ".", "",
           "## Held-out error (test episodes, open-loop replay)", "",
           "| | RMSE [mrad] | MAE [mrad] |", "|---|---|---|",
           f"| nominal model | {_mrad(g.baseline_rmse)} | {_mrad(g.baseline_mae)} |",
           f"| extended model | {_mrad(g.extended_rmse)} | {_mrad(g.extended_mae)} |",
           f"| noise floor (read noise + quantization) | {_mrad(g.noise_floor)} | |", "",
           f"Gain: {_mrad(g.absolute)} mrad RMSE ({100 * g.relative:.1f} %), "
           + (f"95 % bootstrap CI over test episodes [{_mrad(g.ci95[0])}, {_mrad(g.ci95[1])}] "
              "mrad." if g.episodes > 1 else _gain_interval(g) + ".")]
    if g.reducible_explained is not None:
        out.append(f"Fraction of the reducible error explained: "
                   f"{100 * g.reducible_explained:.1f} %.")
    out += ["", *(x[0].upper() + x[1:] + "." for x in _left_lines(r))]
    out += ["", "![measured vs nominal vs extended](traces.png)", "", "## Causes", ""]
    if not r.causes:
        out.append("No effect lowered the select-split error enough: the nominal model explains "
                   "the data to within the acceptance rule.")
    else:
        out += ["| effect | joints | parameters (95 % interval) | held-out RMSE after [mrad] |",
                "|---|---|---|---|"]
        for c in r.causes:
            ps = "; ".join(
                f"{p} = " + ", ".join(f"{v:.4g} [{iv[0]:.4g}, {iv[1]:.4g}]"
                                      for v, iv in zip(d["value"], d["interval"], strict=True))
                + f" {d['unit']}" for p, d in c.params.items())
            out.append(f"| {c.effect} | {', '.join(c.joints)} | {ps} | "
                       f"{_mrad(c.heldout_rmse_after)} |")
            for f in c.flags:
                out.append(f"\n> flag: {c.effect}: {f}")
            for w in c.widened:
                out.append(f"\n> range widened: {c.effect}: {w} (a size beyond the usual "
                           "range: check it is physical)")
            for w in c.stand_in:
                out.append(f"\n> stand-in: {c.effect}: {w}")
            if c.equivalent:
                out.append(f"\n> {c.effect} and {', '.join(c.equivalent)} explain the select "
                           "data equally well (not identifiable from these logs); "
                           f"{c.effect} is named by catalogue order.")
    out += ["", "## Candidates by selection round", "",
            "Score: share of the training residual the candidate's sensitivity explains to first "
            "order. Select: open-loop RMSE on the select episodes after fitting on train.", ""]
    for k, rnd in enumerate(r.rounds):
        out += [f"### Round {k + 1}", "", "| effect | score | select RMSE [mrad] | select MSE gain"
                " | fitted parameters | accepted |", "|---|---|---|---|---|---|"]
        for c in rnd:
            params = ("; ".join(f"{p}={_fmt(v)}" for p, v in c.params.items())
                      if c.params else "")
            gain = f"{100 * c.select_gain:.1f} %" if c.select_gain is not None else ""
            if c.at_bound:
                params += " (at a bound)"
            if c.widened:
                params += " (range widened)"
            out.append(f"| {c.effect} | {c.score:.3f} | {_mrad(c.select_rmse)} | {gain} | "
                       f"{params} | {'yes' if c.accepted else ''} |")
        out.append("")
    out += ["![candidates](candidates.png)", "", "## What the nominal model gets wrong", "",
            "Residual = measured - nominal prediction, all episodes, open loop.", "",
            "| joint | RMSE [mrad] | bias [mrad] | lag [ms] | corr(r, sign v) | "
            "hysteresis [mrad] | corr(r, step size) | corr(r, temperature) |",
            "|---|---|---|---|---|---|---|---|"]
    for j, d in r.diagnostics.items():
        out.append(f"| {j} | {_mrad(d['rmse'])} | {_mrad(d['bias'])} | {1e3 * d['lag_s']:.1f} | "
                   f"{d['corr_sign_velocity']:.2f} | {_mrad(d.get('hysteresis'))} | "
                   f"{d.get('corr_step_size', float('nan')):.2f} | "
                   f"{d.get('corr_temperature', float('nan')):.2f} |")
    out += ["", "![residual diagnostics](residuals.png)", "", "## Extended model", "",
            "`extended/effects.json` holds every fitted effect (load it with "
            "`lowcostdex.gap.load_extended`); `extended/extended_*.xml` has the "
            "MJCF-expressible ones baked in; domain-randomization ranges come from the fitted "
            "intervals.", ""]
    t = r.timing
    out.append("Timing: " + ", ".join(f"{k} {v:.1f} s" for k, v in t.items()) + ".")
    if r.mujoco_warnings:
        out += ["", "While simulating the nominal and candidate models: "
                + describe_warnings(r.mujoco_warnings, None) + "."]
    if timestep_note(r.timestep):
        out += ["", "Physics step: " + timestep_note(r.timestep) + "."]
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------------------------------------
# plots


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    fig.savefig(path, dpi=80)
    _plt().close(fig)


def _legend_on_top(fig, axes, top: float) -> None:
    """One figure legend above the axes (never over data), from the handles of ``axes``."""
    handles, labels = [], []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.tight_layout(rect=(0, 0, 1, top))
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, top + (1 - top) * 0.55),
               ncol=min(len(labels), 6), fontsize=8, frameon=False)


def plot_traces(result: GapResult, path: Path) -> None:
    """Measured vs nominal vs extended on the first test episodes, with their residuals."""
    _save(traces_figure(result), path)


def traces_figure(result: GapResult):
    """The figure of :func:`plot_traces`."""
    plt = _plt()
    traces = result.traces
    nj = len(traces[0]["joints"]) if traces else 1
    rows = max(len(traces), 1) * nj
    fig, axes = plt.subplots(rows, 2, figsize=(14, 2.6 * rows), squeeze=False)
    row = 0
    for tr in traces:
        t = tr["time"]
        for j, name in enumerate(tr["joints"]):
            ax, ax_r = axes[row, 0], axes[row, 1]
            a = list(tr["actuators"]).index(name) if name in tr["actuators"] else None
            if a is not None:
                ax.step(t, tr["goal"][:, a], where="post", color="0.7", lw=1, label="goal")
            ax.plot(t, tr["measured"][:, j], "k", lw=1.2, label="measured")
            ax.plot(t, tr["baseline"][:, j], "tab:red", lw=1, label="nominal")
            ax.plot(t, tr["extended"][:, j], "tab:blue", lw=1, ls="--", label="extended")
            ax.set_ylabel(f"{name} [rad]")
            ax.set_title(f"{tr['name']}: {name}", fontsize=9)
            ax_r.plot(t, 1e3 * (tr["measured"][:, j] - tr["baseline"][:, j]), "tab:red", lw=1,
                      label="measured - nominal")
            ax_r.plot(t, 1e3 * (tr["measured"][:, j] - tr["extended"][:, j]), "tab:blue", lw=1,
                      label="measured - extended")
            ax_r.axhline(0, color="0.6", lw=0.8)
            ax_r.set_ylabel("residual [mrad]")
            row += 1
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle("Held-out episodes: measured, nominal and extended model (left); "
                 "residuals (right)", fontsize=10)
    _legend_on_top(fig, [axes[0, 0], axes[0, 1]], top=1 - 0.75 / (2.6 * rows))
    return fig


def plot_residuals(result: GapResult, path: Path) -> None:
    """Nominal-model residual signatures per joint: over time, vs velocity, position, step size
    and temperature."""
    _save(residuals_figure(result), path)


def residuals_figure(result: GapResult):
    """The figure of :func:`plot_residuals`."""
    plt = _plt()
    joints = list(result.diagnostics)
    keys = ["vs_time", "vs_velocity", "vs_position", "vs_step_size", "vs_temperature"]
    labels = ["time in episode [s]", "velocity [rad/s]", "position [rad]", "command step [rad]",
              "temperature [deg C]"]
    fig, axes = plt.subplots(len(joints), len(keys), figsize=(15, 2.8 * len(joints)),
                             squeeze=False)
    for i, j in enumerate(joints):
        d = result.diagnostics[j]
        for k, (key, lab) in enumerate(zip(keys, labels, strict=True)):
            ax = axes[i, k]
            b = d.get(key)
            if not b:
                ax.set_axis_off()
                continue
            e = np.asarray(b["edges"])
            mid = 0.5 * (e[1:] + e[:-1])
            ax.plot(mid, 1e3 * np.asarray(b["mean"], float), "o-", label="mean")
            ax.plot(mid, 1e3 * np.asarray(b["rms"], float), "s--", label="rms")
            ax.axhline(0, color="0.6", lw=0.8)
            ax.set_xlabel(lab, fontsize=8)
            ax.set_ylabel(f"{j}: residual [mrad]" if k == 0 else "residual [mrad]", fontsize=8)
        axes[i, 0].set_title(f"{j}: lag {1e3 * d['lag_s']:.1f} ms, bias "
                             f"{1e3 * d['bias']:.2f} mrad", fontsize=8)
    fig.suptitle("Residual of the nominal model (measured - nominal) binned by what it could "
                 "depend on", fontsize=10)
    _legend_on_top(fig, [ax for ax in axes.flat if ax.axison],
                   top=1 - 0.75 / (2.8 * max(len(joints), 1)))
    return fig


def plot_candidates(result: GapResult, path: Path) -> None:
    """Score and select RMSE of every candidate, per round."""
    _save(candidates_figure(result), path)


def candidates_figure(result: GapResult):
    """The figure of :func:`plot_candidates`."""
    from matplotlib.patches import Patch

    plt = _plt()
    n = max(len(result.rounds), 1)
    fig, axes = plt.subplots(1, n, figsize=(6 * n, 4.5), squeeze=False)
    for k, rnd in enumerate(result.rounds):
        ax = axes[0, k]
        names = [c.effect for c in rnd][::-1]
        score = [c.score for c in rnd][::-1]
        y = np.arange(len(names))
        ax.barh(y, score, color=["tab:green" if c.accepted else "tab:gray"
                                 for c in rnd][::-1])
        ax.set_yticks(y, names, fontsize=8)
        ax.set_xlabel("score (share of residual explained, linearized)")
        ax.set_xlim(0, 1)
        for yi, c in zip(y, rnd[::-1], strict=True):
            if c.select_rmse is not None:
                ax.text(0.99, yi, f"select {1e3 * c.select_rmse:.3g} mrad", ha="right",
                        va="center", fontsize=7)
        ax.set_title(f"round {k + 1}", fontsize=9)
        ax.set_ylabel("candidate effect")
    fig.suptitle("Candidate effects, ranked per round of the forward selection", fontsize=10)
    axes[0, 0].legend(handles=[Patch(color="tab:green", label="accepted (held-out gain)"),
                               Patch(color="tab:gray", label="not accepted")],
                      loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, fontsize=8,
                      frameon=False)
    fig.tight_layout()
    return fig


def _unscored(r: GapResult) -> str:
    """The report's words for select episodes left out as chaotic (``gap.chaos``)."""
    n = len(r.split.unscored)
    return (f"; {n} more select episode(s) not scored: their open-loop replay is chaotic (goals "
            f"arriving {chaos.SHIFT * 100:g} % of a physics step later move its end by over "
            f"{chaos.FLOORS:g} noise floors)") if n else ""
