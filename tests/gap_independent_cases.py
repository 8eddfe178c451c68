"""Shared by the tests/test_gap_independent*.py files: each case of ``gap_truth_sim.CASES``
analysed once per worker, the way ``lowcostdex gap analyze --model model.xml --log ...`` does
(``load_dataset`` + ``analyze`` with the default ``GapConfig``).

The exact-name and family tests of a case read the same analysis: the first test of a case to run
pays for it, under a per-test timeout of its own (``ANALYSIS_TIMEOUT``: pyproject's 600 s is
for a hung test, and one bench-backlash analysis took 600 s of wall at load 7-10), and a failed
analysis (a timeout included) is remembered and re-raised, never run twice.
"""

from __future__ import annotations

from pathlib import Path

import gap_truth_sim as ts
import numpy as np
import pytest

# per-test timeout of a test that may run one analysis [s] (wall; ~110-170 CPU-s for the
# backlash cases, the heaviest)
ANALYSIS_TIMEOUT = 1800

# What the analysis named on each case when it was not exact: (exact reason, family reason)
# (None: that assertion passes).
KNOWN_FAILS: dict[str, tuple[str | None, str | None]] = {}

_RESULTS: dict[str, tuple[set[str], object]] = {}
_FAILED: dict[str, BaseException] = {}
TRUTH: dict[str, dict[str, np.ndarray]] = {}  # case id -> hidden effect -> value per joint


def analysed(case_id: str, tmp_path_factory) -> tuple[set[str], object]:
    """Analyse one case (once per worker): (hidden names, GapResult)."""
    if case_id in _FAILED:
        raise RuntimeError(f"the analysis of {case_id} failed in an earlier test: "
                           f"{_FAILED[case_id]!r}")
    if case_id not in _RESULTS:
        from lowcostdex.gap import GapConfig, analyze, load_dataset

        _, rig, names, seed, duration = next(c for c in ts.CASES if c[0] == case_id)
        case = ts.make_case(rig, list(names), seed, duration=duration)
        model, paths = case.write(Path(tmp_path_factory.mktemp(case_id)))
        try:
            res = analyze(load_dataset(paths, model=model), GapConfig(seed=0))
        except BaseException as e:  # a timeout too: remembered, so the twin test does not re-run it
            _FAILED[case_id] = e
            raise
        _RESULTS[case_id] = (set(names), res)
        TRUTH[case_id] = case.hidden.values
    return _RESULTS[case_id]


def params(which: int, rig: str) -> list:
    """The cases with hidden effects on ``rig``, as pytest params: ``which`` 0 for the exact-name
    test, 1 for the family test (their ``KNOWN_FAILS`` marks)."""
    out = []
    for cid, r, names, _, _ in ts.CASES:
        if not names or r != rig:
            continue
        reason = KNOWN_FAILS.get(cid, (None, None))[which]
        marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
        out.append(pytest.param(cid, id=cid, marks=marks))
    return out


def describe(res) -> str:
    named = [(c.effect, {p: np.round(v["value"], 3).tolist() for p, v in c.params.items()})
             for c in res.causes]
    return f"named {named}; {res.verdict}; stop: {res.stop_reason}"


def assert_names_exactly(cid: str, tmp_path_factory) -> None:
    hidden, res = analysed(cid, tmp_path_factory)
    assert {c.effect for c in res.causes} == hidden, describe(res)


def assert_names_up_to_family(cid: str, tmp_path_factory) -> None:
    hidden, res = analysed(cid, tmp_path_factory)
    assert ts.grade(hidden, {c.effect for c in res.causes}) in ("exact", "family"), \
        describe(res)
