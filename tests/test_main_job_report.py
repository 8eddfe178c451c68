"""The main job's report says a stage added something only when the numbers show it (issue 13).

The truth is an independent 95 % Wilson score interval written out here (Wilson 1927; the form
of Brown, Cai & DasGupta 2001, eq. 4), checked against published values, and the rule the report
states: a gain or loss is named only when the intervals of the two rates do not overlap.
"""

from __future__ import annotations

import dataclasses
import math

import pytest

from lowcostdex.main_job.report import (
    _validation_words,
    _what_each_stage_added,
    markdown_report,
    paired_errors,
    stage_summary,
)
from lowcostdex.main_job.setup import Context

Z95 = 1.959963984540054


def wilson(k: int, n: int) -> tuple[float, float]:
    p = k / n
    centre = (k + Z95**2 / 2) / (n + Z95**2)
    half = Z95 * math.sqrt(n) / (n + Z95**2) * math.sqrt(p * (1 - p) + Z95**2 / (4 * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def test_the_interval_written_here_matches_published_values():
    # Newcombe, "Two-sided confidence intervals for the single proportion", Stat. Med. 17
    # (1998) 857-872, worked examples of the score method: 81/263 -> 0.2553-0.3662,
    # 0/10 -> 0-0.2775, 0/20 -> 0-0.1611; and 10/20 -> 0.2993-0.7007 (symmetric about 1/2)
    assert wilson(0, 10)[1] == pytest.approx(0.2775, abs=5e-5)
    lo, hi = wilson(10, 20)
    assert (lo, hi) == (pytest.approx(0.2993, abs=5e-5), pytest.approx(0.7007, abs=5e-5))
    assert wilson(0, 20)[1] == pytest.approx(0.1611, abs=5e-5)
    lo, hi = wilson(81, 263)
    assert (lo, hi) == (pytest.approx(0.2553, abs=5e-5), pytest.approx(0.3662, abs=5e-5))


def truth(before: tuple[int, int], after: tuple[int, int]) -> str:
    a, b = wilson(*before), wilson(*after)
    return "raised" if b[0] > a[1] else "lowered" if b[1] < a[0] else "no difference"


def results(random: tuple[int, int], bc: tuple[int, int], dapg: tuple[int, int],
            npg: tuple[int, int]) -> dict:
    return {name: {"eval_successes": k, "eval_episodes": n}
            for name, (k, n) in (("random", random), ("bc", bc), ("dapg", dapg), ("npg", npg))}


CLAUSES = ("The demonstrations", "RL fine-tuning", "demonstrations in RL")
PAIRS = (("random", "bc"), ("bc", "dapg"), ("npg", "dapg"))


def judged(text: str) -> list[str]:
    """The verdict word of each of the report's three clauses, in order."""
    clauses = text.split(". ")[0].split("; ")
    assert [c.split(" (")[0].lower() for c in clauses] == [c.lower() for c in CLAUSES], text
    out = []
    for c in clauses:
        words = [w for w in ("raised", "lowered", "no difference") if w in c]
        assert len(words) == 1, c
        out.append(words[0])
    return out


CASES = [
    # random, bc, dapg, npg (successes, episodes)
    ((0, 20), (20, 20), (20, 20), (0, 20)),     # the clone solves it: RL cannot show a gain
    ((0, 20), (9, 20), (12, 20), (0, 20)),      # 0.45 -> 0.60: overlapping intervals
    ((0, 20), (4, 20), (16, 20), (0, 20)),      # 0.20 -> 0.80: a gain the intervals show
    ((0, 20), (8, 20), (14, 20), (1, 20)),      # 0.40 -> 0.70: 0.22-0.61 vs 0.48-0.85
    ((0, 20), (15, 20), (5, 20), (0, 20)),      # RL lost what the clone had
    ((1, 10), (2, 10), (3, 10), (3, 10)),       # nothing separable
    ((0, 20), (3, 20), (10, 20), (0, 20)),      # 0.15 -> 0.50: 0.05-0.36 vs 0.30-0.70
]


@pytest.mark.parametrize("random,bc,dapg,npg", CASES)
def test_the_words_follow_the_intervals(random, bc, dapg, npg):
    t = results(random, bc, dapg, npg)
    text = _what_each_stage_added(t)
    expected = [truth((t[a]["eval_successes"], t[a]["eval_episodes"]),
                      (t[b]["eval_successes"], t[b]["eval_episodes"])) for a, b in PAIRS]
    assert judged(text) == expected, text
    # the rates named are the measured ones
    for a, b in PAIRS:
        ka, na = t[a]["eval_successes"], t[a]["eval_episodes"]
        kb, nb = t[b]["eval_successes"], t[b]["eval_episodes"]
        assert f"from {ka / na:.2f} to {kb / nb:.2f}" in text
    solved = bc == dapg and bc[0] == bc[1]
    assert ("already solves" in text) == solved


def test_a_gain_inside_the_intervals_is_not_claimed():
    # 9/20 -> 12/20 is what a main-job seed measured on the random-goal valve: not a gain
    t = results((0, 20), (9, 20), (12, 20), (0, 20))
    text = _what_each_stage_added(t)
    rl = text.split("; ")[1]
    assert rl.startswith("RL fine-tuning") and "raised" not in rl and "no difference" in rl


def test_a_stage_without_an_evaluation_is_not_measured():
    t = results((0, 20), (9, 20), (12, 20), (0, 20))
    del t["random"]["eval_successes"]
    text = _what_each_stage_added(t)
    assert text.startswith("The demonstrations (behaviour clone vs uniformly random actions): "
                           "not measured")


def test_the_report_states_the_task_variant(tmp_path, monkeypatch):
    from lowcostdex.main_job import setup

    variant = dataclasses.replace(setup.TASKS["valve"], env_overrides={"goal_range": 0.5})
    monkeypatch.setitem(setup.TASKS, "variant", variant)
    ctx = Context(out=tmp_path, task="variant")
    assert ctx.env_kwargs()["goal_range"] == 0.5 and ctx.env_kwargs()["backend"] == "emulated"
    text = markdown_report(ctx)
    assert f"`{variant.env_id}`, goal_range 0.5)" in text


def test_a_run_whose_policy_is_the_clone_says_so():
    # validation chose the clone (iteration -1): DAPG's held-out row is the clone's own episodes
    t = results((0, 20), (9, 20), (9, 20), (0, 20))
    assert "DAPG's policy is the clone itself" not in _what_each_stage_added(t)
    t["dapg"]["best_iteration"] = -1
    text = _what_each_stage_added(t)
    assert "DAPG's policy is the clone itself" in text and "RL did not improve on it" in text
    t["dapg"]["best_iteration"] = 3
    assert "clone itself" not in _what_each_stage_added(t)


def mcnemar_upper(b: int, c: int) -> float:
    """P(X >= b) for X ~ Binomial(b + c, 1/2), written out (1 when b + c = 0)."""
    n = b + c
    return sum(math.comb(n, k) for k in range(b, n + 1)) / 2**n if n else 1.0


def test_mcnemar_written_here_matches_a_textbook_value():
    # 10 discordant pairs all one way: p = 1/1024 (one-sided exact sign test); 5 vs 5: 0.623
    assert mcnemar_upper(10, 0) == pytest.approx(1 / 1024)
    assert mcnemar_upper(5, 5) == pytest.approx(638 / 1024)


@pytest.mark.parametrize("only_dapg,only_bc,both", [(0, 0, 7), (6, 0, 5), (9, 2, 4), (1, 4, 0)])
def test_the_paired_test_on_the_same_heldout_episodes(only_dapg, only_bc, both):
    n = 40
    bc = [False] * n
    dapg = [False] * n
    for i in range(both):
        bc[i] = dapg[i] = True
    for i in range(both, both + only_dapg):
        dapg[i] = True
    for i in range(both + only_dapg, both + only_dapg + only_bc):
        bc[i] = True
    t = results((0, n), (sum(bc), n), (sum(dapg), n), (0, n))
    t["bc"]["solved"], t["dapg"]["solved"] = bc, dapg
    text = _what_each_stage_added(t)
    p = mcnemar_upper(only_dapg, only_bc)
    assert (f"Paired on the same {n} held-out episodes: DAPG alone solved {only_dapg}, the "
            f"clone alone {only_bc} (exact one-sided McNemar test that DAPG solves more, "
            f"p = {p:.3g})") in text, text
    # the paired test's own conclusion (0.05, one-sided): 6/0 p 1/64 and 9/2 p 0.033 solve more
    solved_more = "on the same episodes DAPG solved more than the clone" in text
    assert solved_more == (p <= 0.05) and solved_more == (only_dapg >= 6), text
    del t["dapg"]["solved"]
    assert "Paired on" not in _what_each_stage_added(t)


def test_the_report_says_whether_validation_was_paired():
    # "the same episodes" only when both runs validated on one fixed set (TrainConfig.eval_paired)
    t = results((0, 20), (9, 20), (9, 20), (0, 20))
    assert _validation_words(t, 20) == "20 episodes each"
    t["dapg"]["validation_paired"] = True
    assert "same" not in _validation_words(t, 20)
    t["npg"]["validation_paired"] = True
    assert _validation_words(t, 20).startswith("the same 20 episodes every time")


def signed_rank_p_less(d: list[float]) -> float:
    """Exact P(R+ <= observed R+) under the null, written out: R+ is the sum of the ranks of
    |d| over the positive d; every one of the 2^n sign patterns is equally likely (no ties)."""
    ranks = {v: i + 1 for i, v in enumerate(sorted(abs(x) for x in d))}
    observed = sum(ranks[abs(x)] for x in d if x > 0)
    n, hits = len(d), 0
    for mask in range(2**n):
        hits += sum(r for i, r in enumerate(ranks.values()) if mask >> i & 1) <= observed
    return hits / 2**n


def test_the_paired_error_test_on_the_same_heldout_episodes():
    clone = [0.30, 0.12, 0.45, 0.21, 0.08, 0.33, 0.17, 0.26]
    change = [-0.11, -0.05, -0.32, 0.04, -0.02, -0.21, 0.015, -0.07]  # DAPG - clone, distinct |.|
    dapg = [c + d for c, d in zip(clone, change, strict=True)]
    before, after, p = paired_errors({"final_goal_errors": clone}, {"final_goal_errors": dapg})
    assert before == pytest.approx((0.21 + 0.26) / 2)
    assert after == pytest.approx((0.13 + 0.185) / 2)  # .06 .07 .12 .13 .185 .19 .19 .25
    assert p == pytest.approx(signed_rank_p_less(change), rel=1e-9)
    # R+ = 1 + 3 (0.015, 0.04); rank sets with sum <= 4: {}, 1, 2, 3, 4, {1,2}, {1,3}
    assert p == pytest.approx(7 / 256)
    # the words follow: a run where DAPG ends nearer the goal, and one where it does not
    t = results((0, 8), (3, 8), (3, 8), (0, 8))
    t["bc"]["final_goal_errors"], t["dapg"]["final_goal_errors"] = clone, dapg
    text = _what_each_stage_added(t)
    assert f"median {before:.3f} rad for the clone, {after:.3f} rad for DAPG" in text
    assert "DAPG ended nearer the goal than the clone" in text
    t["dapg"]["final_goal_errors"] = clone[::-1]
    assert "no paired difference this run can show" in _what_each_stage_added(t)
    assert paired_errors({"final_goal_errors": clone}, {"final_goal_errors": clone})[2] == 1.0
    assert paired_errors({"final_goal_errors": clone}, {}) is None


def test_dapg_randomizes_the_catalogues_default_effects():
    # the main job's simulation for DAPG is the project's default domain randomization, not a
    # list of its own (the setup module spells the names out so it stays importable cheaply)
    from lowcostdex.main_job.setup import BUDGETS, DAPG_RANDOMIZE
    from lowcostdex.sim.effects.randomization import DEFAULT_DR_EFFECTS

    assert DAPG_RANDOMIZE == DEFAULT_DR_EFFECTS
    assert all(b.dapg_sim is not None and b.dapg_sim.randomize == DEFAULT_DR_EFFECTS
               for b in BUDGETS.values())


def test_the_report_says_where_dapg_trained(tmp_path):
    t = results((0, 40), (15, 40), (21, 40), (0, 40))
    t["dapg"].update(trained_in="simulation", randomized=["latency", "coulomb_friction"],
                     iterations=30, episodes_per_iteration=40, samples=48000, robot_hours=0.0,
                     validation_samples=16000, validation_episodes=100, final_training_success=0.3,
                     last_validation_success=0.4)
    t["npg"].update(trained_in="robot", samples=9600, validation_samples=2400, robot_hours=0.4,
                    validation_episodes=20,
                    final_training_success=0.0, last_validation_success=0.0)
    t.update(plot="learning_curves.png", seconds=300.0)
    ctx = Context(out=tmp_path)
    ctx.results["train"] = t
    text = markdown_report(ctx)
    assert "DAPG trained in simulation, NPG on the robot, both judged on the robot" in text
    assert ("30 iterations of 40 episodes (48000 samples, no robot time), each episode under "
            "randomly drawn servo and model effects (latency, coulomb friction)") in text
    # training samples and validation steps apart: the robot's NPG time covers both
    assert "| DAPG | simulation | 48000 | 16000 | 0.0 |" in text
    assert "| NPG | robot | 9600 | 2400 | 24.0 |" in text
    line = stage_summary("train", t)
    assert "(48000 training samples in simulation)" in line
    assert "(9600 training samples on the robot)" in line
    assert "100 (DAPG) / 20 (NPG)" in text
    assert "DAPG's RL samples (48000) came from the randomized simulation" in text
    del t["dapg"]["trained_in"]
    assert "came from the randomized simulation" not in markdown_report(ctx)


def test_a_policy_averaged_over_runs_is_named_and_not_called_the_clone():
    # several DAPG runs averaged (main_job.streams): the first run's validation chose the
    # clone, but DAPG's policy is the average, so the report must not call it the clone
    from lowcostdex.main_job.report import _streams_words

    t = results((0, 100), (40, 100), (46, 100), (0, 100))
    t["dapg"]["best_iteration"] = -1
    t["streams"] = {"runs": [{"dir": "train_dapg"}, {"dir": "train_dapg_run1"},
                             {"dir": "train_dapg_run2"}],
                    "average": {"file": "train_dapg/averaged_policy.pt", "eval_successes": 44,
                                "eval_episodes": 100, "eval_success": 0.44},
                    "chosen": "average"}
    assert "clone itself" not in _what_each_stage_added(t)
    words = _streams_words(t["streams"])
    assert "DAPG ran 3 times" in words and "solved 44 of 100" in words
    assert "`train_dapg_run2/`" in words and "It is DAPG's policy below." in words
    t["streams"]["chosen"] = "clone"
    assert "DAPG's policy below is the clone" in _streams_words(t["streams"])
