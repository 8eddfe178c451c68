"""What the simulation gets wrong: residual statistics, signatures, the noise floor.

Residuals are r = measured - predicted per joint (04-sysid.md section 4.1). Each statistic below
is a signature of some effects: a constant mean (offset), a lag (latency; cross-correlation),
dependence on velocity sign (dry friction) or on the approach direction at rest (friction or
backlash hysteresis), growth with command step size (saturation, torque limit), dependence on
position (gravity/mass), drift with temperature (thermal derating). The score statistic of a
candidate is the share of the residual's energy its sensitivity columns can explain to first
order (a Lagrange-multiplier test), computed before fitting it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from lowcostdex.gap.logs import Trajectory, quantization_step


def noise_floor(trajs: Sequence[Trajectory]) -> np.ndarray:
    """RMS of (reading - true position) per joint [rad] that no model can remove.

    Read noise is estimated where the joint holds still (goal unchanged and |velocity| small
    for +-3 samples), from the spread of second differences (white noise has variance 6 sigma^2
    there; a resting joint has no motion to leak in; the largest 2 % are trimmed). Dithered
    quantization error is part of that spread; a still, noiseless encoder shows none, so the
    floor is never below the quantization floor q / sqrt(12) when the readings sit on a grid.
    Without enough resting samples the floor is the quantization floor (or, for unquantized
    readings, the spread over all samples: an overestimate on fast motion).
    """
    nj = trajs[0].qpos.shape[1]
    out = np.zeros(nj)
    for j in range(nj):
        parts, rest_parts = [], []
        for tr in trajs:
            q = tr.qpos[:, j]
            d2 = q[2:] - 2 * q[1:-1] + q[:-2]
            parts.append(d2)
            g = tr.goal[:, min(j, tr.goal.shape[1] - 1)]
            v = tr.qvel[:, j] if tr.qvel is not None else np.gradient(q, tr.time)
            still = (np.abs(v) < 0.1) & np.concatenate([[False], np.diff(g) == 0])
            k = np.ones(7)
            still = np.convolve(still.astype(float), k, mode="same") >= 7 - 1e-9
            rest_parts.append(d2[still[1:-1]])
        rest = np.concatenate(rest_parts)
        q = quantization_step(np.concatenate([tr.qpos[:, j] for tr in trajs]))
        if len(rest) < 50 and q > 0:
            out[j] = q / math.sqrt(12.0)  # no still periods: the quantization floor only
            continue
        d2 = rest if len(rest) >= 50 else np.concatenate(parts)
        cut = np.percentile(np.abs(d2), 98) if len(d2) else 0.0
        d2 = d2[np.abs(d2) <= cut]
        sigma = float(np.sqrt(np.mean(d2 * d2)) / math.sqrt(6.0)) if len(d2) else 0.0
        out[j] = max(sigma, q / math.sqrt(12.0))
    return out


def lag1(r: np.ndarray) -> float:
    """Lag-1 autocorrelation of a residual series (pooled over columns)."""
    r = np.asarray(r, float)
    if r.ndim == 1:
        r = r[:, None]
    r = r - r.mean(0)
    den = float((r * r).sum())
    if den <= 0 or len(r) < 3:
        return 0.0
    return float((r[1:] * r[:-1]).sum() / den)


def effective_n(r: np.ndarray) -> float:
    """Effective sample size n (1 - rho) / (1 + rho) of autocorrelated residuals."""
    rho = min(max(lag1(r), -0.99), 0.999)
    return max(len(r) * (1 - rho) / (1 + rho), 1.0)


def lag_estimate(t: np.ndarray, measured: np.ndarray, predicted: np.ndarray,
                 max_lag: float = 0.1) -> float:
    """Delay of measured behind predicted [s] by cross-correlation of their increments.

    Both series are resampled on a uniform grid (median sample period); the peak of the
    normalised cross-correlation of first differences within +-``max_lag`` is refined by a
    parabola. Positive: the measurement lags the model.
    """
    t = np.asarray(t, float)
    h = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1], h)
    if len(grid) < 10:
        return 0.0
    m = np.diff(np.interp(grid, t, measured))
    p = np.diff(np.interp(grid, t, predicted))
    kmax = max(1, min(int(max_lag / h), len(m) // 4))
    lags = np.arange(-kmax, kmax + 1)
    cc = np.array([_corr(m[max(k, 0):len(m) + min(k, 0)], p[max(-k, 0):len(p) - max(k, 0)])
                   for k in lags])
    i = int(np.argmax(cc))
    shift = 0.0
    if 0 < i < len(cc) - 1:
        a, b, c = cc[i - 1], cc[i], cc[i + 1]
        den2 = a - 2 * b + c
        if den2 < 0:
            shift = 0.5 * (a - c) / den2
    return float((lags[i] + shift) * h)


def _binned(x: np.ndarray, r: np.ndarray, edges: np.ndarray) -> dict:
    idx = np.clip(np.digitize(x, edges) - 1, 0, len(edges) - 2)
    mean, rms, count = [], [], []
    for b in range(len(edges) - 1):
        sel = idx == b
        count.append(int(sel.sum()))
        mean.append(float(r[sel].mean()) if sel.any() else float("nan"))
        rms.append(float(np.sqrt((r[sel] ** 2).mean())) if sel.any() else float("nan"))
    return {"edges": edges.tolist(), "mean": mean, "rms": rms, "count": count}


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b / den) if den > 0 else 0.0


def residual_diagnostics(trajs: Sequence[Trajectory], windows: Sequence,
                         pred: Sequence[np.ndarray], joint: int) -> dict:
    """Signature statistics of one joint's residuals over open-loop windows.

    Args:
      trajs: the data set's trajectories.
      windows: replayed windows (``dataset.Window``).
      pred: predicted readings (n_w, nj) per window.
      joint: joint column.
    Returns:
      a JSON-ready dict: rmse, mae, bias, per-window rmse, lag [s], and residual means/rms binned
      by velocity, position, command step size, time, temperature; direction statistics.
    """
    r_all, v_all, q_all, t_all, temp_all = [], [], [], [], []
    lags, per_window = [], []
    step_pk, step_sz = [], []
    up, down, after_rev, elsewhere = [], [], [], []
    for w, p in zip(windows, pred, strict=True):
        tr = trajs[w.traj]
        sl = slice(w.start, w.stop)
        meas = tr.qpos[sl, joint]
        r = meas - p[:, joint]
        t = tr.time[sl]
        v = tr.qvel[sl, joint] if tr.qvel is not None else np.gradient(meas, t)
        g = tr.goal[sl, min(joint, tr.goal.shape[1] - 1)]
        r_all.append(r)
        v_all.append(v)
        q_all.append(meas)
        t_all.append(t - t[0])
        if "temperature" in tr.channels:
            temp_all.append(tr.channels["temperature"][sl, min(joint, tr.goal.shape[1] - 1)])
        per_window.append(float(np.sqrt(np.mean(r * r))))
        lags.append(lag_estimate(t, meas, p[:, joint]))
        # command steps: peak |r| within 0.3 s after each goal jump
        dg = np.diff(g)
        jumps = np.flatnonzero(np.abs(dg) > 1e-3 + 5 * np.median(np.abs(dg)))
        for i in jumps:
            stop = np.searchsorted(t, t[i + 1] + 0.3)
            step_pk.append(float(np.max(np.abs(r[i + 1:stop]))) if stop > i + 1 else 0.0)
            step_sz.append(float(abs(dg[i])))
        # direction of approach during holds (goal constant, slow): hysteresis
        sgn = np.sign(dg)
        last = 0.0
        for i in range(1, len(g)):
            if sgn[i - 1] != 0:
                if last != 0 and sgn[i - 1] != last:
                    after_rev.extend(r[i:np.searchsorted(t, t[i] + 0.1)].tolist())
                last = sgn[i - 1]
            elif abs(v[i]) < 0.05 and last != 0:
                (up if last > 0 else down).append(r[i])
            else:
                elsewhere.append(r[i])
    r, v, q, tt = map(np.concatenate, (r_all, v_all, q_all, t_all))
    vmax = max(float(np.percentile(np.abs(v), 99)), 1e-3)
    out = {
        "rmse": float(np.sqrt(np.mean(r * r))),
        "mae": float(np.mean(np.abs(r))),
        "bias": float(np.mean(r)),
        "lag1": lag1(r),
        "per_window_rmse": per_window,
        "lag_s": float(np.median(lags)),
        "corr_velocity": _corr(r, v),
        "corr_sign_velocity": _corr(r, np.sign(v)),
        "corr_position": _corr(r, q),
        "corr_sin_position": _corr(r, np.sin(q)),
        "vs_velocity": _binned(v, r, np.linspace(-vmax, vmax, 9)),
        "vs_position": _binned(q, r, np.linspace(q.min(), q.max() + 1e-9, 9)),
        "vs_time": _binned(tt, r, np.linspace(0, tt.max() + 1e-9, 9)),
        "hold_after_up": float(np.mean(up)) if up else None,
        "hold_after_down": float(np.mean(down)) if down else None,
        "hysteresis": (float(np.mean(up) - np.mean(down)) if up and down else None),
        "rms_after_reversal": float(np.sqrt(np.mean(np.square(after_rev)))) if after_rev
        else None,
        "rms_elsewhere": float(np.sqrt(np.mean(np.square(elsewhere)))) if elsewhere else None,
    }
    if step_sz:
        sz, pk = np.array(step_sz), np.array(step_pk)
        edges = np.unique(np.percentile(sz, [0, 25, 50, 75, 100]))
        if len(edges) >= 2:
            edges[-1] += 1e-9
            out["vs_step_size"] = _binned(sz, pk, edges)
        out["corr_step_size"] = _corr(sz, pk)
    if temp_all:
        temp = np.concatenate(temp_all)
        out["corr_temperature"] = _corr(r, temp)
        out["vs_temperature"] = _binned(temp, r, np.linspace(temp.min(), temp.max() + 1e-9, 7))
    return out


def score_fraction(r: np.ndarray, cols: np.ndarray) -> float:
    """Share of the residual energy the columns can explain to first order, in [0, 1].

    Args:
      r: (n,) residual at the current model.
      cols: (n, p) sensitivity columns (finite differences or secants toward the candidate).
    """
    if cols.size == 0 or float(r @ r) <= 0:
        return 0.0
    q, rr = np.linalg.qr(cols)
    keep = np.abs(np.diag(rr)) > 1e-12 * max(float(np.max(np.abs(np.diag(rr)))), 1e-300)
    q = q[:, keep]
    proj = q.T @ r
    return float(min(proj @ proj / (r @ r), 1.0))


# a drift over the session: the later logs fit consistently worse than the earlier ones
DRIFT_TAU = 0.8  # Kendall's tau of the logs' RMSE against their order (3 logs: strictly rising)
DRIFT_RATIO = 1.5  # the later half's RMSE over the earlier half's


def per_log(ds, eps: Sequence, pred: Sequence[np.ndarray]) -> list[dict]:
    """Open-loop RMSE [rad] of each log (``ds.sources``: the pieces of a log split at a time gap
    together) over every episode, with its first and last time stamp [s], in the order given."""
    out: dict[str, dict] = {}
    for w, p in zip(eps, pred, strict=True):
        tr = ds.trajectories[w.traj]
        name = ds.sources[w.traj] if len(ds.sources) == len(ds.trajectories) else tr.name
        r = tr.qpos[w.start:w.stop] - p
        d = out.setdefault(name, {"log": name, "start": math.inf, "stop": -math.inf,
                                  "sse": 0.0, "n": 0})
        d["start"] = min(d["start"], float(tr.time[w.start]))
        d["stop"] = max(d["stop"], float(tr.time[w.stop - 1]))
        d["sse"] += float((r * r).sum())
        d["n"] += r.size
    return [{"log": d["log"], "start": d["start"], "stop": d["stop"],
             "rmse": math.sqrt(d["sse"] / max(d["n"], 1))} for d in out.values()]


def kendall_tau(x: Sequence[float]) -> float:
    """Kendall's tau of ``x`` against its index (1: strictly rising; ties count 0)."""
    n = len(x)
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    if not pairs:
        return 0.0
    return float(sum(np.sign(x[j] - x[i]) for i, j in pairs) / len(pairs))


def session_drift(logs: Sequence[dict], floor: float, above: float = 3.0,
                  tau: float = DRIFT_TAU, ratio: float = DRIFT_RATIO) -> dict:
    """Does the model fit the later logs of the session consistently worse (a plant that changed
    while it was logged: friction rising as grease stiffens or a gearbox wears, a motor warming
    up, a part loosening)? A model fitted over all logs averages such a change, and no constant
    effect explains it.

    Args:
      logs: ``per_log`` rows {"log", "start", "stop", "rmse"}, in the order given (file order).
      floor: the noise floor [rad] (RMS).
      above: the later half's RMSE must exceed the earlier half's by more than this many
        floors (what a replay of an exact model leaves: ``GapConfig.explain_above``): sim6's
        deadband_torque, exactly named, rose 2.4 / 2.9 / 3.5 floors over its logs (tau 1,
        1.48x), a change an exact model's replay can show; sim10's drifting friction rises
        11-13.5 floors.
      tau, ratio: the rank trend (Kendall's tau of the logs' RMSE against their order) and the
        later half's RMSE over the earlier half's that make a drift note.
    Returns:
      {"order": "time stamps" or "file order", "logs": [{"log", "rmse", "floors"}], "tau",
      "ratio", "note"} ("note" is "" without a drift; fewer than 3 logs: no test). The logs
      are ordered by their time stamps when they share a clock (sorted by their first stamp,
      none overlaps the next), else kept in file order (a clock restarting at every log).
    """
    rows = list(logs)
    order = "file order"
    by_time = sorted(rows, key=lambda d: d["start"])
    if len(rows) > 1 and all(b["start"] > a["stop"]
                                 for a, b in zip(by_time[:-1], by_time[1:], strict=True)):
        rows, order = by_time, "time stamps"
    fl = floor if floor > 0 else math.nan
    out = {"order": order, "logs": [{"log": d["log"], "rmse": d["rmse"],
                                     "floors": d["rmse"] / fl} for d in rows],
           "tau": None, "ratio": None, "note": ""}
    if len(rows) < 3:
        return out
    e = [d["rmse"] for d in rows]
    k = len(e) // 2
    early, late = math.sqrt(np.mean(np.square(e[:k]))), math.sqrt(np.mean(np.square(e[-k:])))
    out["tau"] = kendall_tau(e)
    out["ratio"] = late / early if early > 0 else math.inf
    if out["tau"] >= tau and out["ratio"] >= ratio and late - early > above * floor:
        each = ", ".join(f"{_stem(d['log'])} {d['rmse'] / fl:.3g}" for d in rows)
        out["note"] = (f"drift over the session: the later logs fit consistently worse ({order}"
                       f"; RMSE in noise floors: {each}; the later half {out['ratio']:.2g}x "
                       "the earlier half): the plant may have changed while it was logged "
                       "(friction rising, a motor warming up, wear); a model fitted over all "
                       "logs averages it: compare fits of the early and the late logs")
    return out


def _stem(name: str) -> str:
    return str(name).replace("\\", "/").rsplit("/", 1)[-1]
