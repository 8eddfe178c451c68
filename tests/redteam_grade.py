"""The one grader of the red-team truth sets: a ``gap analyze`` report.json against a truth set's
truth dict and its ``FAMILIES`` (sets of confusable catalogue effects). Grading is not physics:
the truth simulators import it (it imports nothing from lowcostdex, so they stay free of project
code) and so does the harness (``redteam_check``); two graders would drift apart.

``truth``: ``causes`` (the hidden catalogue effects), optional ``allowed`` (names that may be named
beside them without counting as extra), optional ``outside`` (the hidden effect is not in the
catalogue), optional ``expected_params`` ({effect, param, joint, value, abs}: ``abs`` true when the
sign of the fitted value is a convention, e.g. a play side).
"""

from __future__ import annotations


def neighbours(name: str, families) -> set[str]:
    """``name`` and every effect sharing one of ``families`` with it."""
    out = {name}
    for fam in families:
        if name in fam:
            out |= fam
    return out


VERDICT = {"exact": "exact", "extra": "exact+more", "family": "confusable", "clean": "clean",
           "false": "false"}


def grade(report: dict, truth: dict, families) -> dict:
    """Grade one report.json.

    ``result``: ``exact`` (every hidden cause named, nothing else but ``allowed`` names),
    ``extra`` (every hidden cause named, and more besides), ``family`` (every hidden cause named
    or stood in for by a confusable neighbour, nothing named outside those families and
    ``allowed``), ``miss`` (otherwise), ``clean`` (nothing hidden, nothing but ``allowed``
    named), ``false`` (nothing hidden, something else named: a false discovery). For an effect
    outside the catalogue: ``clean`` when nothing is named or the named effects lower the held-out
    RMSE with the gain's 95 % interval above 0, else ``false``. ``verdict6`` says the same in
    plain words: exact, exact+more, confusable, missed (nothing named), wrong (something else
    named), clean, false; pass / fail for an effect outside the catalogue. ``params``: per
    expected parameter of a named cause on its joint, {effect, param, joint, truth, value,
    interval, inside} (inside: the truth in the 95 % interval). ``heldout``: the held-out RMSE
    before and after (rad); ``gain_ci95``: the gain's 95 % interval."""
    named = sorted({c["effect"] for c in report.get("causes", [])})
    hidden = set(truth["causes"])
    allowed = hidden | set(truth.get("allowed", ()))
    g = report.get("gain") or {}
    before, after = g.get("baseline_rmse"), g.get("extended_rmse")
    ci = g.get("ci95") or [None, None]
    if truth.get("outside"):
        helps = bool(named) and after is not None and before is not None and after < before \
            and ci[0] is not None and ci[0] > 0
        verdict = "pass" if (not named or helps) else "fail"
        result = "clean" if verdict == "pass" else "false"
    else:
        if not hidden:
            result = "clean" if set(named) <= allowed else "false"
        elif hidden <= set(named) <= allowed:
            result = "exact"
        elif hidden <= set(named):
            result = "extra"
        elif not named:
            result = "miss"
        else:
            covered = all(neighbours(h, families) & set(named) for h in hidden)
            near = set().union(*(neighbours(h, families) for h in hidden)) | allowed
            result = "family" if covered and set(named) <= near else "miss"
        verdict = VERDICT.get(result) or ("missed" if not named else "wrong")
    params = []
    by_effect = {c["effect"]: c for c in report.get("causes", [])}
    for exp in truth.get("expected_params", []):
        cause = by_effect.get(exp["effect"])
        if cause is None or exp["param"] not in cause["params"] or \
                exp["joint"] not in cause["joints"]:
            continue
        p = cause["params"][exp["param"]]
        k = cause["joints"].index(exp["joint"])
        value = p["value"][k]
        lo, hi = p["interval"][k]
        want = exp["value"]
        if exp.get("abs") and value * want < 0:
            want = -want
        params.append(dict(effect=exp["effect"], param=exp["param"], joint=exp["joint"],
                           truth=want, value=value, interval=[lo, hi],
                           inside=bool(lo <= want <= hi)))
    return {"result": result, "verdict6": verdict, "named": named, "hidden": sorted(hidden),
            "params": params, "heldout": [before, after], "gain_ci95": ci}
