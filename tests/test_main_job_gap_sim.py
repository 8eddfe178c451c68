"""The gap-extended simulation DAPG trained in for issue 13 item 3 (``bench/main_job_sim.py
candidates --sim gap``), and a randomization that draws the same after a config round trip.

The expected ranges are written out here from the rule ``gap.extension.dr_ranges`` documents
(the hull of the joints' 95 % intervals, widened to reach at least 10 % of the largest
fitted value below the smallest fitted value and above the largest), for a hand-made extended model whose numbers are typed in.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

from lowcostdex.gap.extension import save_extended
from lowcostdex.hands import dclaw_spec
from lowcostdex.main_job.setup import DAPG_RANDOMIZE
from lowcostdex.sim.effects import AppliedEffect

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from main_job_sim import gap_randomization  # noqa: E402

FF = ("ff_top", "ff_middle", "ff_bottom")


def extended_model(folder):
    effects = [AppliedEffect("latency", FF, {"delay": [0.0119, 0.0120, 0.0121]}),
               AppliedEffect("backlash", FF, {"width": [0.018, 0.017, 0.019],
                                              "sensor": [0.0, 0.0, 0.0]})]
    intervals = {"latency": {"delay": [[0.0110, 0.0128], [0.0118, 0.0122], [0.0119, 0.0123]]},
                 "backlash": {"width": [[0.0175, 0.0185], [0.0165, 0.0175], [0.0185, 0.0195]],
                              "sensor": [[-math.inf, math.inf]] * 3}}
    return save_extended(folder, {}, effects, intervals)


def test_the_gap_stages_effects_within_their_fitted_ranges_on_every_joint(tmp_path):
    extended_model(tmp_path / "extended")
    dr = gap_randomization(tmp_path, "gap")
    assert dr["effects"] == ["latency", "backlash"]
    assert dr["joints"] == list(dclaw_spec().joint_names) and len(dr["joints"]) == 9
    # latency: hull 0.0110-0.0128 s; values 0.0119-0.0121 s -+ 10 % of 0.0121 s: 0.01069-0.01331
    lo, hi = dr["ranges"]["latency"]["delay"]
    assert lo == pytest.approx(0.0119 - 0.00121) and hi == pytest.approx(0.0121 + 0.00121)
    # backlash width: hull 0.0165-0.0195 rad; values 0.017-0.019 -+ 0.0019: 0.0151-0.0209 rad
    lo, hi = dr["ranges"]["backlash"]["width"]
    assert lo == pytest.approx(0.017 - 0.0019) and hi == pytest.approx(0.019 + 0.0019)
    # a parameter the analysis held (unbounded interval) stays at its value, not its full range
    assert dr["ranges"]["backlash"]["sensor"] == [0.0, 0.0]


def test_gap_plus_dr_keeps_the_main_jobs_effects_with_the_fitted_ranges(tmp_path):
    extended_model(tmp_path / "extended")
    dr = gap_randomization(tmp_path, "gap+dr")
    assert dr["effects"] == list(DAPG_RANDOMIZE)
    assert dr["ranges"] == gap_randomization(tmp_path, "gap")["ranges"]


def test_no_identified_effect_is_refused(tmp_path):
    save_extended(tmp_path / "extended", {}, [], {})
    with pytest.raises(SystemExit, match="identified no effect"):
        gap_randomization(tmp_path, "gap")


def test_the_draws_do_not_depend_on_the_order_of_the_ranges_keys():
    # a training run's config.json is written with sorted keys; read back, its randomization
    # must draw what the run drew (the clone choice is re-checked from it in test_main_job.py)
    import json

    import numpy as np

    from lowcostdex.sim.effects import DomainRandomization

    ranges = {"backlash": {"width": (0.015, 0.02), "sensor": (0.0, 0.0)},
              "coulomb_friction": {"frictionloss": (0.02, 0.07), "creep": (0.9, 1.0)}}
    declared = DomainRandomization(("backlash", "coulomb_friction"), FF, ranges)
    read_back = DomainRandomization.from_dict(json.loads(json.dumps(declared.to_dict(),
                                                                    sort_keys=True)))
    assert list(read_back.ranges["backlash"]) == ["sensor", "width"]  # the order did change
    a = declared.sample(np.random.default_rng(7))
    b = read_back.sample(np.random.default_rng(7))
    for x, y in zip(a, b, strict=True):
        assert x.name == y.name
        for p in x.values:
            np.testing.assert_array_equal(x.values[p], y.values[p])
    width = a[0].values["width"]
    assert np.all((width >= 0.015) & (width <= 0.02)) and np.all(a[0].values["sensor"] == 0)
