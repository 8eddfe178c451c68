"""The verdict of an identification on its held-out logs: is the identified model a reliable gain
over the nominal (datasheet) one? (issue 11 item 5)

A mean held-out error below the nominal model's is not enough: on real servos an identified
model can win the mean on one log and lose on most (Pham XL330's up_and_down fold: 6.5 mrad
identified against 4.7 nominal; STS3250 sin_time_square: 51.3 against 44.2, 2026-11-27). The
unit of evidence is the held-out log (a log's samples are strongly autocorrelated): the gain is
reliable when the identified model is better on most held-out logs AND the 95 % percentile
bootstrap interval over logs of the mean per-log gain (nominal MAE - identified MAE, paired) lies
above zero. With one held-out log there is no interval; its sign is all there is, and the text
says so.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from lowcostdex.gap.gain import bootstrap_ci


def verdict(nominal: Mapping[int, float], identified: Mapping[int, float], logs: Sequence[int],
            rng: np.random.Generator | None = None, n_boot: int = 2000) -> dict:
    """Judge the identified model against the nominal one on the held-out ``logs``.

    Args:
      nominal, identified: {log index: MAE [rad]} (BAM's per-log measure).
      logs: the held-out log indices.
      rng: generator of the bootstrap (default: seeded 0, so the verdict is reproducible).
      n_boot: bootstrap resamples.
    Returns:
      {"logs": n, "better": logs where the identified MAE is lower, "nominal_mae",
      "identified_mae": means [rad], "gain": their difference [rad], "gain_ci95": [lo, hi] or
      None (fewer than 2 logs), "reliable": bool, "text": one line}.
    """
    logs = [int(i) for i in logs]
    if not logs:
        return {"logs": 0, "better": 0, "nominal_mae": math.nan, "identified_mae": math.nan,
                "gain": math.nan, "gain_ci95": None, "reliable": False,
                "text": "no held-out logs: the gain over the nominal model is not measured "
                        "(hold some logs out)"}
    nom = np.array([nominal[i] for i in logs], float)
    idn = np.array([identified[i] for i in logs], float)
    diff = nom - idn
    n, better = len(logs), int(np.sum(idn < nom))
    ci = None
    if n >= 2:
        gen = rng if rng is not None else np.random.default_rng(0)
        ci = bootstrap_ci(lambda idx: diff[idx].mean(1), n, gen, n_boot)
    most = better > n / 2
    reliable = most and (ci is None or ci[0] > 0)
    mean_nom, mean_id = float(nom.mean()), float(idn.mean())
    nums = (f"mean MAE nominal {1e3 * mean_nom:.1f} -> identified {1e3 * mean_id:.1f} mrad, "
            f"gain {1e3 * (mean_nom - mean_id):.1f} mrad"
            + (f" [{1e3 * ci[0]:.1f}, {1e3 * ci[1]:.1f}] (95 % bootstrap over logs)" if ci
               else " (one held-out log: no interval)"))
    if reliable:
        text = f"identified model better on {better} of {n} held-out logs: {nums}"
    else:
        why = (f"worse than the nominal model on {n - better} of {n} held-out logs" if not most
               else "the gain's interval includes zero")
        text = (f"no reliable gain: the identified model is {why} ({nums}); the nominal model "
                "is not beaten on these logs")
    return {"logs": n, "better": better, "nominal_mae": mean_nom, "identified_mae": mean_id,
            "gain": mean_nom - mean_id, "gain_ci95": list(ci) if ci else None,
            "reliable": bool(reliable), "text": text}
