"""bench/mutation.py's pure parts: mutmut's results read back, the seeded sample, the Markdown.

The mutation run itself takes minutes to hours and stays out of the default test run (README,
"Testing"); these checks take their truth from mutmut 3.8.1 itself: its exit-code table
(mutmut/stats.py), a ``.meta`` file's layout and ``mutmut show``'s output, copied below from a
run on this repository (2026-11-26, /work/mut-mut/fresh).
"""

from __future__ import annotations

import importlib.util
import json
import random
import sys
from collections import Counter
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib", reason="tomllib is in the standard library from Python 3.11")

ROOT = Path(__file__).resolve().parents[1]


def _load(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "bench" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


mutation = _load("mutation")

# `mutmut show lowcostdex.gap.gain.x_episode_errors__mutmut_8` (mutmut 3.8.1), verbatim
SHOW_STRICT = '''# lowcostdex.gap.gain.x_episode_errors__mutmut_8: survived
--- lowcostdex/gap/gain.py
+++ lowcostdex/gap/gain.py
@@ -1,7 +1,7 @@
 def episode_errors(ds, eps: Sequence, pred: Sequence[np.ndarray], joints: Sequence[str]) -> dict:
     """Held-out RMSE/MAE pooled, per joint and per episode [rad]."""
     rs = [ds.trajectories[w.traj].qpos[w.start:w.stop] - p for w, p in zip(eps, pred,
-                                                                             strict=True)]
+                                                                             )]
     allr = np.concatenate(rs)
     return {
         "heldout_rmse": float(np.sqrt(np.mean(allr ** 2))),
'''
SHOW_MESSAGE = '''# lowcostdex.gap.results.x\u01c1GapConfig\u01c1__post_init____mutmut_56: killed
--- lowcostdex/gap/results.py
+++ lowcostdex/gap/results.py
@@ -11,7 +11,7 @@
         raise ConfigError("min_gain must be in (0, 1)")
     check_choice("search", self.search, ("forward", "both"))
     if not self.segment > 0 or self.burn_in < 0:
-        raise ConfigError("segment must be > 0 s and burn_in >= 0 s")
+        raise ConfigError("XXsegment must be > 0 s and burn_in >= 0 sXX")
     if not self.interval_block > 0:
         raise ConfigError("interval_block must be > 0 s")
'''


def test_exit_codes_follow_mutmut_3_8_1():
    # mutmut/stats.py status_by_exit_code: 1 and 3 (pytest internal error) kill, 0 survives,
    # 5 and 33 are "no tests", 36 and the SIGXCPU codes are timeouts, None is not checked
    assert [mutation.status(c) for c in (1, 3, 0, 5, 33, 36, -24, 24, 152, 255, None, 34)] == [
        "killed", "killed", "survived", "no tests", "no tests", "timeout", "timeout", "timeout",
        "timeout", "timeout", "not checked", "skipped"]
    assert mutation.status(42) == "suspicious"


def test_meta_results_and_scores_per_module():
    # two .meta files as mutmut writes them ("exit_code_by_key" among other keys)
    gain = {"exit_code_by_key": {"lowcostdex.gap.gain.x_f__mutmut_1": 1,
                                 "lowcostdex.gap.gain.x_f__mutmut_2": 0,
                                 "lowcostdex.gap.gain.x_f__mutmut_3": 36,
                                 "lowcostdex.gap.gain.x_f__mutmut_4": None},
            "durations_by_key": {}}
    analyze = {"exit_code_by_key": {"lowcostdex.gap.analyze.x_g__mutmut_1": 33,
                                    "lowcostdex.gap.analyze.x\u01c1C\u01c1m__mutmut_1": 1}}
    results = mutation.meta_results(gain) | mutation.meta_results(analyze)
    scores = mutation.score_by_module(
        results, ["lowcostdex/gap/analyze.py", "lowcostdex/gap/gain.py"])
    a, g = scores
    # gain: killed 1 + timeout 1 of 3 checked (the unchecked one is left out): 2/3
    assert (g.killed, g.scored, g.not_killed) == (2, 3, 1)
    assert g.score == pytest.approx(200 / 3)
    # analyze: "no tests" counts as not killed: 1/2
    assert (a.killed, a.scored, a.score) == (1, 2, 50.0)
    with pytest.raises(ValueError, match="none of"):
        mutation.score_by_module({"lowcostdex.motion.x_f__mutmut_1": "killed"},
                                 ["lowcostdex/gap/gain.py"])


def test_a_module_is_not_matched_by_a_longer_name_sharing_its_prefix():
    scores = mutation.score_by_module(
        {"lowcostdex.gap.gain_extra.x_f__mutmut_1": "killed"},
        ["lowcostdex/gap/gain.py", "lowcostdex/gap/gain_extra.py"])
    assert [s.scored for s in scores] == [0, 1]


def test_sample_is_seeded_order_free_and_the_documented_expression():
    names = [f"m.x_f__mutmut_{i}" for i in range(50)]
    s = mutation.sample_names(names, 10, seed=1)
    assert s == random.Random(1).sample(sorted(names), 10)
    assert mutation.sample_names(list(reversed(names)) + names[:5], 10, seed=1) == s
    assert len(set(s)) == 10 and set(s) <= set(names)
    assert mutation.sample_names(names, 10, seed=2) != s
    assert mutation.sample_names(names, None, seed=1) == sorted(names)
    assert mutation.sample_names(names, 80, seed=1) == sorted(names)


def test_one_line_diff_from_mutmut_show():
    assert mutation.one_line_diff(SHOW_STRICT) == "`strict=True)]` -> `)]`"
    assert mutation.one_line_diff(SHOW_MESSAGE) == (
        '`raise ConfigError("segment must be > 0 s and burn_in >= 0 s")` -> '
        '`raise ConfigError("XXsegment must be > 0 s and burn_in >= 0 sXX")`')
    removed = "--- a.py\n+++ a.py\n@@ -1 +1 @@\n-    x = 1\n"
    assert mutation.one_line_diff(removed) == "`x = 1` -> (removed)"
    long = "--- a\n+++ a\n-" + "a" * 300 + "\n+b\n"
    assert mutation.one_line_diff(long, width=20) == "`" + "a" * 17 + "...` -> `b`"


def test_markdown_block_numbers_and_survivors():
    c1 = Counter({"killed": 8, "timeout": 1, "survived": 1})
    c2 = Counter({"killed": 3, "no tests": 1})
    scores = [mutation.ModuleScore("lowcostdex/a.py", c1), mutation.ModuleScore("lowcostdex/b.py", c2)]
    surv = {"lowcostdex.a.x_f__mutmut_2": "`x < 1` -> `x <= 1`",
            "lowcostdex.b.x_g__mutmut_1": "`y` -> `None` (no tests)"}
    md = mutation.markdown("safety", "abc1234", scores, surv,
                           [("lowcostdex/a.py", 4, ["`LIMIT` 5 (line 3)"])],
                           header="H", sampled="all 14 mutants")
    lines = md.splitlines()
    assert lines[0] == "#### `python bench/mutation.py safety` at abc1234"
    # 9 of 10 (timeouts count), 3 of 4 ("no tests" does not), total 12 of 14
    assert "| `lowcostdex/a.py` | 10 | 9 (1) | 1 | 0 | 0 | 90.0 % |" in lines
    assert "| `lowcostdex/b.py` | 4 | 3 (0) | 0 | 1 | 0 | 75.0 % |" in lines
    assert "| **total** | 14 | 12 (1) | 1 | 1 | 0 | 85.7 % |" in lines
    assert "- `x_f__mutmut_2` (a.py): `x < 1` -> `x <= 1`" in lines
    assert "- `x_g__mutmut_1` (b.py): `y` -> `None` (no tests)" in lines
    assert "| `lowcostdex/a.py` | 4 | 3 | 75.0 % | `LIMIT` 5 (line 3) |" in lines


def test_the_copy_gets_the_groups_modules_and_tests_in_the_repositorys_mutmut_table():
    text = (ROOT / "pyproject.toml").read_text()
    base = tomllib.loads(text)
    group = mutation.GROUPS["codec"]
    new = tomllib.loads(mutation.group_pyproject(text, group))
    cfg = new["tool"]["mutmut"]
    assert cfg["only_mutate"] == list(group.modules)
    assert cfg["pytest_add_cli_args_test_selection"] == [
        *group.tests, "--deselect", group.deselect[0]]
    # everything else unchanged, and the default test options kept out of the mutation run
    del cfg["only_mutate"], cfg["pytest_add_cli_args_test_selection"]
    assert new == base
    assert "not slow" in base["tool"]["mutmut"]["pytest_add_cli_args"]
    with pytest.raises(ValueError, match="no \\[tool.mutmut\\]"):
        mutation.group_pyproject("[project]\n", group)


def test_every_group_names_files_that_exist():
    for group in mutation.GROUPS.values():
        for path in group.modules:
            assert (ROOT / path).is_file(), path
        for test_id in (*group.tests, *group.deselect):
            if "::" not in test_id:
                assert (ROOT / test_id).is_file(), test_id
                continue
            file, name = test_id.split("::")
            assert f"def {name}(" in (ROOT / file).read_text()


def test_mutmut_is_pinned_in_the_dev_extra():
    dev = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert "mutmut==3.8.1" in dev["dev"]


def test_report_of_a_stopped_run_leaves_the_unchecked_out(tmp_path, capsys):
    # a copy as the runner leaves it: run.json, the chosen names, mutmut's .meta per module
    group = {"modules": ["lowcostdex/a.py"], "tests": ["tests/test_a.py"], "deselect": [],
             "note": "n"}
    (tmp_path / "run.json").write_text(json.dumps(
        {"commit": "abc1234", "sampled": "all 4 mutants", "group": group}))
    names = [f"lowcostdex.a.x_f__mutmut_{i}" for i in range(1, 5)]
    (tmp_path / "mutants_chosen.txt").write_text("\n".join(names) + "\n")
    (tmp_path / "mutants" / "lowcostdex").mkdir(parents=True)
    (tmp_path / "mutants" / "lowcostdex" / "a.py.meta").write_text(json.dumps(
        {"exit_code_by_key": dict(zip(names, [1, 0, 36, None], strict=True))}))
    fake = tmp_path / "mutmut"  # stands in for `mutmut show NAME`
    fake.write_text("#!/bin/sh\nprintf '%s\\n' '--- a.py' '+++ a.py' '-    x < 1' '+    x <= 1'\n")
    fake.chmod(0o755)
    assert mutation.report("safety", tmp_path, str(fake), "t", None, 1, tmp_path / "o.md") == 0
    md = (tmp_path / "o.md").read_text()
    assert md == (tmp_path / "mutation.md").read_text() and md in capsys.readouterr().out
    # 3 checked (killed, survived, timeout), the unchecked one left out: 2/3
    assert "| `lowcostdex/a.py` | 3 | 2 (1) | 1 | 0 | 0 | 66.7 % |" in md
    assert "all 4 mutants (3 of the 4 checked: the run was stopped)" in md
    assert "- `x_f__mutmut_2` (a.py): `x < 1` -> `x <= 1`" in md
    assert "`test_a.py`" in md


def test_constants_include_a_dataclass_default_and_are_applied_in_place():
    mc = _load("mutate_constants")
    src = ("LIMIT = 80.0\n"
           "class Config:\n"
           "    warn_margin: float = 15.0\n"
           "    flag: bool = True\n"
           "    def f(self):\n"
           "        return 3\n"
           "OTHER = -2\n")
    lits = mc.module_literals(src)
    # the function body's 3 is mutmut's; the bool is no number
    assert [(lit.name, lit.value, lit.line) for lit in lits] == [
        ("LIMIT", 80.0, 1), ("Config.warn_margin", 15.0, 3), ("OTHER", 2, 7)]
    assert mc.apply(src, lits[1]).splitlines()[2] == "    warn_margin: float = 16.0"
    assert mc.apply(src, lits[2]).splitlines()[6] == "OTHER = -3"
    # --only: the constants of one class (or name) only; nothing given: all
    assert [lit.name for lit in mc.chosen(lits, ["Config."])] == ["Config.warn_margin"]
    assert [lit.name for lit in mc.chosen(lits, ["OTHER", "LIMIT"])] == ["LIMIT", "OTHER"]
    assert mc.chosen(lits) == lits and mc.chosen(lits, ["Nothing"]) == []
