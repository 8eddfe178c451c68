"""Hidden-effect tests: logs come from the nominal model plus an effect the analyzer is not told
(random plausible magnitude, 4096-tick quantization, read noise, timestamp jitter, drifting
temperature and sagging supply channels). Given only the nominal model and the logs, the analysis
must name the effect and bring the held-out error near the noise floor; effect-free data must give
"no significant discrepancy".

These logs are made by the project's own generator (``lowcostdex.gap.generate``) with the same
effect and servo code the analyzer fits: they check the analysis is consistent with its own models
(a selection or fitting regression shows here), not that those models match the world. The truth
that comes from outside the analyzer is tests/gap_truth_sim.py (tests/test_gap_independent.py)
and the measured servo logs (tests/test_gap_real.py).

The default run keeps a representative subset (three bench effects including the confusable
friction/backlash pair, an effect drawn at random from the catalogue, one finger effect, two
effects at once, effect-free data); the full sweep over every effect and magnitude on the bench
and the finger is marked slow (and is what bench/gap_sweep.py measures).
"""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.gap.analyze import GapConfig, analyze
from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.generate import HIDDEN, generate
from lowcostdex.gap.replay import Replayer

NEAR_FLOOR = 1.5  # extended held-out RMSE within this factor of the noise / replay floor


def run(rig: str, hidden: list[str], seed: int, level: float | None = None):
    syn = generate(rig, hidden, np.random.default_rng(seed), n_logs=3, duration=8.0,
                   level=level)
    res = analyze(Dataset({"model": syn.xml}, syn.trajectories), GapConfig(seed=seed))
    return syn, res


def truth_rmse(syn, res) -> float:
    """Held-out RMSE of the true model replayed like the extended one: the replay floor (read
    noise, plus initial-state errors a stuck or saturated servo carries through a move)."""
    ds = Dataset({"model": syn.xml}, syn.trajectories)
    test = [res.episodes[i] for i in res.split.test]
    pred = Replayer(ds, [e.name for e in syn.hidden]).run(test, [syn.hidden])[0][0]
    r = np.concatenate([ds.trajectories[w.traj].qpos[w.start:w.stop] - p
                        for w, p in zip(test, pred, strict=True)])
    return float(np.sqrt(np.mean(r * r)))


def assert_recovered(syn, res, rel: float = 0.15):
    """Named causes equal the hidden effects, parameters close to the truth, error at the
    floor (read noise, or what the true model itself reaches), gain interval above zero."""
    hidden = {e.name: e for e in syn.hidden}
    assert {c.effect for c in res.causes} == set(hidden), (res.verdict, res.stop_reason)
    for c in res.causes:
        for p, d in c.params.items():
            truth = hidden[c.effect].values[p]
            if c.effect == "stribeck_friction" and p == "velocity":
                continue  # weakly identified shape parameter
            np.testing.assert_allclose(d["value"], truth, rtol=rel, atol=1e-3,
                                       err_msg=f"{c.effect}.{p}")
    floor = max(syn.settings.floor, truth_rmse(syn, res))
    assert res.extended["heldout_rmse"] <= NEAR_FLOOR * floor
    assert res.baseline["heldout_rmse"] > 2 * res.extended["heldout_rmse"]
    assert res.gain.ci95[0] > 0


@pytest.mark.parametrize("name, seed", [("latency", 11), ("coulomb_friction", 12),
                                        ("backlash", 13)])
def test_bench_names_the_hidden_effect(name, seed):
    syn, res = run("bench", [name], seed)
    assert res.causes[0].effect == name
    assert_recovered(syn, res)


def test_effect_drawn_at_random_from_the_catalogue_is_named():
    rng_seed = 21
    syn, res = run("bench", ["random"], rng_seed)
    assert len(syn.hidden) == 1 and syn.hidden[0].name in HIDDEN
    assert_recovered(syn, res, rel=0.25)


def test_finger_names_the_hidden_effect_per_joint():
    syn, res = run("finger", ["viscous_damping"], 31)
    assert [c.effect for c in res.causes] == ["viscous_damping"]
    assert res.causes[0].joints == ("ff_top", "ff_middle", "ff_bottom")
    assert_recovered(syn, res)


def test_two_hidden_effects_are_both_found():
    syn, res = run("bench", ["latency", "coulomb_friction"], 41, level=0.5)
    assert_recovered(syn, res, rel=0.2)


def test_effect_free_data_gives_no_false_discovery():
    for seed in (51, 52):
        syn, res = run("bench", [], seed)
        assert res.causes == [] and res.effects == []
        assert res.verdict == "no significant discrepancy"
        assert res.extended["heldout_rmse"] == res.baseline["heldout_rmse"]
        assert res.baseline["heldout_rmse"] <= NEAR_FLOOR * syn.settings.floor


@pytest.mark.slow
@pytest.mark.parametrize("rig", ["bench", "finger"])
@pytest.mark.parametrize("name", list(HIDDEN))
@pytest.mark.parametrize("level", [0.0, 0.5, 1.0])
def test_sweep_every_effect_and_magnitude(rig, name, level):
    seed = 1000 + 100 * list(HIDDEN).index(name) + int(10 * level) + (0 if rig == "bench" else 7)
    syn, res = run(rig, [name], seed, level=level)
    assert res.causes and res.causes[0].effect == name, (res.verdict, res.stop_reason)
    assert res.extended["heldout_rmse"] <= NEAR_FLOOR * syn.settings.floor
