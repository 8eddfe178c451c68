"""GapConfig's documented ranges at their edges, and the report's parameter intervals and flags.

Every bound below is the one GapConfig's docstring (or its error message) states; each is checked
on both sides of the edge, with the message naming the setting. The parameter report's intervals
follow ``param_report``'s docstring: value +- half-width in optimizer coordinates (log of scale
factors), a log-scaled parameter's interval clipped to its search range.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.results import (
    GapConfig,
    bound_flags,
    param_interval,
    param_report,
    timestep_note,
)

OK_AND_BAD = [
    # (setting, accepted at/near the edge, refused beyond it, words of the message)
    ("top_k", 1, 0, "top_k"),
    ("max_effects", 1, 0, "max_effects"),
    ("max_rounds", 1, 0, "max_rounds"),
    ("bootstrap", 1, 0, "bootstrap"),
    ("joint_k", 0, -1, "joint_k"),
    ("exchange_k", 0, -1, "exchange_k"),
    ("seed", 0, -1, "seed"),
    ("nthread", 0, -1, "nthread"),
    ("rank_tie", 0.0, -0.01, "rank_tie"),
    ("min_gain", 0.999, 1.0, "min_gain"),
    ("min_gain", 0.001, 0.0, "min_gain"),
    ("floor_margin", 1e-9, 0.0, "floor_margin"),
    ("rank_seconds", 1e-9, 0.0, "rank_seconds"),
    ("min_effect", 0.0, -0.01, "min_effect"),
    ("backward_above", 0.0, -0.01, "backward_above"),
    ("explain_above", 0.0, -0.01, "explain_above"),
    ("tie", 0.0, -0.01, "tie"),
    ("tie", 0.999, 1.0, "tie"),
    ("chunk", 1e-9, 0.0, "chunk"),
    ("segment", 1e-9, 0.0, "segment"),
    ("burn_in", 0.0, -0.01, "burn_in"),
    ("interval_block", 1e-9, 0.0, "interval_block"),
    ("interval_step", 0.0, -0.01, "interval_step"),
    ("interval_step", 0.999, 1.0, "interval_step"),
    ("refine_gain", 0.999, 1.0, "refine_gain"),
    ("refine_gain", 0.001, 0.0, "refine_gain"),
    ("min_step", 1e-9, 0.0, "min_step"),
    ("probes", (0.0, 0.999), (0.5, 1.0), "probes"),
    ("probes", (), (-0.01,), "probes"),
    ("test_logs", (0, 3), (-1,), "test_logs"),
    ("search", "forward", "backward", "search"),
    ("candidates", ("latency", "backlash"), ("latency", "friction"), "candidate effect"),
]


@pytest.mark.parametrize("name,ok,bad,words", OK_AND_BAD)
def test_each_setting_is_accepted_at_its_edge_and_refused_beyond(name, ok, bad, words):
    assert getattr(GapConfig(**{name: ok}), name) == ok
    with pytest.raises(ConfigError, match=words):
        GapConfig(**{name: bad})


@pytest.mark.parametrize("name,bad", [
    ("top_k", 2.5), ("seed", True), ("min_gain", math.nan), ("tie", math.inf),
    ("chunk", "5"), ("refine_step", 1), ("refine_step", "false"), ("test_logs", 0),
    ("test_logs", (0.5,)), ("probes", 0.01), ("candidates", "latency")])
def test_wrong_kinds_are_refused_with_the_setting_named(name, bad):
    with pytest.raises(ConfigError, match=name.split("_")[0]):
        GapConfig(**{name: bad})


def test_the_defaults_are_the_documented_ones():
    c = GapConfig()
    assert (c.top_k, c.rank_tie, c.max_effects, c.min_gain, c.floor_margin) == (6, 0.5, 3, 0.05,
                                                                                1.2)
    assert (c.explain_above, c.min_effect, c.probes, c.tie, c.search) == (3.0, 0.75,
                                                                          (0.01, 0.02, 0.03),
                                                                          0.002, "both")
    assert (c.backward_above, c.interval_block, c.interval_step, c.refine_step) == (1.5, 0.5,
                                                                                     0.5, True)
    assert (c.min_step, c.refine_gain, c.candidates, c.chunk, c.test_logs) == (2.5e-4, 0.2, None,
                                                                               None, None)
    assert GapConfig(chunk=None).chunk is None


def _ctx():
    return fitmod.Context(dt=0.002, peak_force=np.array([1.0, 1.0]),
                          stall=np.array([np.inf, np.inf]), damping=np.array([0.1, 0.1]))


def test_param_report_gives_values_and_intervals_in_parameter_units():
    # gain_error's scale is log-scaled (u = ln scale) with search range [0.2, 4] (fit.space);
    # position_offset's offset is linear, search range [-0.2, 0.2]
    s = fitmod.Structure.build(("gain_error", "position_offset"), ("a", "b"), _ctx())
    assert [(f.effect, f.joint, f.log) for f in s.free] == [
        ("gain_error", 0, True), ("gain_error", 1, True), ("position_offset", 0, False),
        ("position_offset", 1, False)]
    u = np.array([math.log(2.0), 0.0, 0.05, -0.01])
    half = np.array([0.1, 5.0, 0.02, np.inf])
    rep = param_report(s, u, half, "gain_error", {"interval_noise": half / 2})
    assert rep["scale"]["value"] == pytest.approx([2.0, 1.0])
    # 2 exp(+-0.1) = [1.8097, 2.2103]; 1 exp(+-5) clipped to the search range [0.2, 4]
    assert np.allclose(rep["scale"]["interval"],
                       [[2 * math.exp(-0.1), 2 * math.exp(0.1)], [0.2, 4.0]])
    assert np.allclose(rep["scale"]["interval_noise"],
                       [[2 * math.exp(-0.05), 2 * math.exp(0.05)], [0.2, 4.0]])
    rep = param_report(s, u, half, "position_offset", shift=np.array([0, 0, 0.004, 0.0]),
                       centre=np.array([0, 0, 0.06, -0.01]))
    d = rep["offset"]
    assert d["value"] == pytest.approx([0.05, -0.01])
    # about the centre 0.06 +- 0.02; an infinite half-width gives an unbounded linear interval
    assert np.allclose(d["interval"], [[0.04, 0.08], [-math.inf, math.inf]])
    assert d["step_shift"] == pytest.approx([0.004, 0.0])
    assert d["unit"] == "rad"
    assert "step_shift" not in param_report(s, u, half, "position_offset")[
        "offset"]


def test_param_interval_of_a_log_parameter_with_an_infinite_half_width_is_its_range():
    f = fitmod.space("gain_error", "scale", 0, _ctx())
    assert param_interval(f, 0.0, math.inf) == [f.lo, f.hi] == [0.2, 4.0]


def test_bound_flags_name_the_parameter_joint_and_side():
    s = fitmod.Structure.build(("position_offset", "mounting_offset"), ("a", "b"), _ctx())
    u = np.array([0.2, 0.0, 0.0, -0.3])  # offset[a] at +0.2, mounting offset[b] at -0.3
    assert bound_flags(s, u, "position_offset") == ["offset[a] at its upper bound"]
    assert bound_flags(s, u, "mounting_offset") == ["offset[b] at its lower bound"]
    assert bound_flags(s, np.array([0.19, 0.0, 0.0, -0.29]), "mounting_offset") == []


def test_timestep_note_only_when_the_step_was_refined():
    assert timestep_note({}) == ""
    assert timestep_note({"model": 0.002, "used": 0.002, "rmse": [(0.002, 1e-3)]}) == ""
    note = timestep_note({"model": 0.002, "used": 0.001,
                          "rmse": [(0.002, 2.1e-3), (0.001, 0.9e-3)]})
    assert note == ("the model's physics step 2 ms is too coarse for these logs (nominal replay "
                    "RMSE on train + select: 2 ms 2.1 mrad, 1 ms 0.9 mrad); analysed at 1 ms, "
                    "which the extended model carries")
    # seconds -> ms by 1000 exactly (9.99 ms, not 10.0)
    note = timestep_note({"model": 0.00999, "used": 0.000999,
                          "rmse": [(0.00999, 1.234e-3), (0.000999, 0.5e-3)]})
    assert note == ("the model's physics step 9.99 ms is too coarse for these logs (nominal "
                    "replay RMSE on train + select: 9.99 ms 1.23 mrad, 0.999 ms 0.5 mrad); "
                    "analysed at 0.999 ms, which the extended model carries")


def test_a_plays_width_interval_does_not_reach_below_no_play():
    # sim5 backlash2deg_pendulum_500hz_us reported 0.0299 [-0.0028, 0.040]: the symmetric
    # widening for goal timing took the interval's low end past 0; no play is narrower than none
    f = fitmod.Free("backlash", "width", 0, 0.0, 0.1, 0.01, False, 2e-4)
    assert param_interval(f, 0.01858, 0.02142) == pytest.approx([0.0, 0.04])
    assert param_interval(f, 0.03, 0.01) == pytest.approx([0.02, 0.04])
    g = fitmod.Free("position_offset", "offset", 0, -0.2, 0.2, 0.0, False, 1e-4)
    assert param_interval(g, 0.01, 0.02) == pytest.approx([-0.01, 0.03])  # others as before
