"""Real servo logs held back: the identification fitted on a few drawn logs (bench/gap_real.py
--train-size), as a user with fewer logs than BAM's split would run it."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import pytest


def _bench_module():
    path = Path(__file__).resolve().parents[1] / "bench" / "gap_real.py"
    spec = importlib.util.spec_from_file_location("gap_real_bench_small", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _headers(n: int):
    return SimpleNamespace(trajectories=[SimpleNamespace(meta={
        "kp": 32, "mass": (0.259, 0.3247, 0.457)[i % 3], "length": (0.05, 0.07, 0.1)[i // 3 % 3],
        "trajectory": f"t{i}"}) for i in range(n)])


def test_training_logs_drawn_are_a_seeded_subset_of_the_split():
    gr = _bench_module()
    ds = _headers(40)
    pool = list(range(4, 40))  # the split's training logs (0-3 held out)
    a, info = gr.draw_train(ds, pool, 5, 0)
    b, _ = gr.draw_train(ds, pool, 5, 0)
    c, _ = gr.draw_train(ds, pool, 5, 1)
    assert a == b and a != c  # the draw is the seed's, and another seed draws others
    assert len(set(a)) == 5 and set(a) <= set(pool) and a == sorted(a)
    assert info["train_drawn"]["of"] == 36
    assert [x["trajectory"] for x in info["train_drawn"]["logs"]] == [f"t{i}" for i in a]
    assert gr.draw_train(ds, pool, None, 0) == (pool, {})  # no size: every training log
    for bad in (0, 37):
        with pytest.raises(SystemExit, match="between 1 and the split's 36"):
            gr.draw_train(ds, pool, bad, 0)
