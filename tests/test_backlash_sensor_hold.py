"""Where a backlash's servo reads across its play (``backlash.sensor``) is held at 0 (the motor
side) in the final fit when it only stands in for a lag (``lowcostdex.gap.gates.hold_sensor``).

The sensor has two physical states (0: an encoder on the motor side or a horn's play beyond the
servo; 1: an encoder on the output shaft). A small intermediate value can soak up a misfit the
play does not cause (redteam sim2 ``backlash_body_pendulum``: the truth's goals act from its next
physics step, a 0.125 ms mean lag, and width 0.0271 with sensor 0.035 excluded the true 0.02618).

The residual here is a P servo with a play of width w whose loop reads s x play across it,
written out in this file: after each move the link comes to rest (1 - s) w / 2 short of its goal
on the side it came from (the loop holds motor + s x play at the goal, the link leans on the
stop it was pulled by), and a reversed move takes up w of motor travel before the link follows
(both read with seeded noise). ``bias`` moves every rest by a further amount toward the goal: a
misfit a sensor of 2 bias / w explains exactly, a fudge, not a play. ``late`` is the same data
as a replay with the goals half a step later would see them: with or without that misfit.
"""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.gates import hold_sensor
from lowcostdex.gap.results import GapConfig

W = 0.013  # rad, the play (about sim2's 0.75 deg half-play x 2)
N = 40


def _residual(width: float, sensor: float, bias: float, noise: float):
    rng = np.random.default_rng(5)
    d = np.resize([1.0, -1.0], N)  # direction of each move
    rest = -d * ((1 - sensor) * width / 2 - bias) + noise * rng.standard_normal(N)
    take = width + noise * rng.standard_normal(N)

    def residual(batch):
        out = []
        for s, x in batch:
            e = {e.name: e for e in s.to_effects(x)}["backlash"]
            w, sn = float(e.values["width"][0]), float(e.values["sensor"][0])
            out.append(np.concatenate([-d * (1 - sn) * w / 2 - rest, w - take]))
        return out

    return residual


def _fit(res, ctx):
    s = fitmod.Structure.build(("backlash",), ("q",), ctx)
    assert [f.param for f in s.free] == ["width", "sensor"]
    t = fitmod.Track(s, s.u(np.array([0.01, 0.0])), label="final")
    fitmod.lockstep_lm([t], res, 40, rtol=1e-6)
    return t


def _ctx():
    return fitmod.Context(dt=0.002, peak_force=np.array([1.0]), stall=np.array([np.inf]),
                          damping=np.array([0.1]))


def test_a_sensor_standing_in_for_a_lag_is_held_at_the_motor_side():
    """The 0.3 mrad misfit under 0.3 mrad noise: freed, the sensor goes to 2 x 0.3 / 13 = 0.046
    and lowers the cost ~29 %; replayed with the goals half a step later the misfit is gone and so
    is the gain: held at 0, the width refitted within 0.2 mrad of the play, the hold kept for
    later refits and noted."""
    ctx = _ctx()
    res = _residual(W, 0.0, 3e-4, 3e-4)
    t = _fit(res, ctx)
    assert t.x[1] == pytest.approx(2 * 3e-4 / W, abs=0.01)
    notes: dict = {}
    held = hold_sensor(t, res, ctx, GapConfig(), notes, late=lambda: _residual(W, 0.0, 0.0, 3e-4))
    assert held is not t and [f.param for f in held.structure.free] == ["width"]
    e = held.effects()[0]
    assert float(e.values["sensor"][0]) == 0.0
    assert float(e.values["width"][0]) == pytest.approx(W, abs=2e-4)
    assert ctx.widened == {("backlash", "sensor", 0): (0.0, 0.0)}
    assert "sensor[q] held at 0" in notes["backlash"][0] and "stood in for a lag" in \
        notes["backlash"][0]
    later = fitmod.Structure.build(("backlash",), ("q",), ctx)
    assert [f.param for f in later.free] == ["width"]


@pytest.mark.parametrize("sensor, bias, noise", [
    (0.3, 0.0, 1e-3),   # a loop reading 0.3 across the play: rests 2.3 mrad off a motor side's
    (0.0, 3e-4, 3e-4),  # the misfit, still there with late goals (freeing: ~29 % both ways)
    (0.0, 3e-4, 1e-3),  # the misfit under 1 mrad noise: freeing lowers the cost only ~3.5 %
    (1.0, 0.0, 1e-3),   # an output-shaft sensor: fitted above 0.5, not even refitted
])
def test_a_sensor_the_data_need_or_cannot_tell_stays_free(sensor, bias, noise):
    """Kept as fitted, nothing held: a sensor the data need also with late goals, and one they
    cannot tell from 0 (its freedom is what the width's interval should span)."""
    ctx = _ctx()
    res = _residual(W, sensor, bias, noise)
    t = _fit(res, ctx)
    notes: dict = {}
    calls = []
    late = lambda f=1.0: _residual(W, sensor, bias, noise)  # noqa: E731 (at a finer step too)
    assert hold_sensor(t, lambda b: calls.append(1) or res(b), ctx, GapConfig(), notes,
                       late=late, finer=True) is t
    assert ctx.widened == {} and notes == {}
    assert bool(calls) == (t.x[1] < 0.5)  # a sensor above 0.5 is not even refitted held
    want = sensor if not bias else 2 * bias / W
    assert t.x[1] == pytest.approx(want, abs=0.05)


def test_a_sensor_standing_in_for_the_step_is_held_at_the_motor_side():
    """The misfit survives the late goals but not a 4x finer step (``late(0.25)``; as sim2
    backlash_offset_pendulum_stall since the sensor damps across the play, 4fc78c0: freeing it
    lowered the cost 8.4 % as replayed, 6.1 % with goals half a 2 ms step late, -1.4 % at
    0.5 ms): held at 0 with ``finer``, kept free without it (the late test alone)."""
    res = _residual(W, 0.0, 3e-4, 3e-4)
    steps = []

    def late(f=1.0):
        steps.append(f)
        return _residual(W, 0.0, 3e-4 if f == 1 else 0.0, 3e-4)

    ctx = _ctx()
    assert hold_sensor(_fit(res, ctx), res, ctx, GapConfig(), {}, late=late) is not None
    assert steps == [1.0] and ctx.widened == {}  # without ``finer``: free, as before
    ctx, notes = _ctx(), {}
    held = hold_sensor(_fit(res, ctx), res, ctx, GapConfig(), notes, late=late, finer=True)
    assert steps == [1.0, 1.0, 0.25]  # ctx.dt 2 ms: 0.25 x (cfg.min_step 0.25 ms is finer)
    assert [f.param for f in held.structure.free] == ["width"]
    assert float(held.effects()[0].values["width"][0]) == pytest.approx(W, abs=2e-4)
    assert ctx.widened == {("backlash", "sensor", 0): (0.0, 0.0)}
    assert "at a 0.25x step" in notes["backlash"][0]


def test_no_finer_try_at_the_finest_step():
    """At ``cfg.min_step`` already there is no finer step to try: the late test decides."""
    res, steps = _residual(W, 0.0, 3e-4, 3e-4), []
    ctx = fitmod.Context(dt=2.5e-4, peak_force=np.array([1.0]), stall=np.array([np.inf]),
                         damping=np.array([0.1]))
    t = _fit(res, ctx)
    late = lambda f=1.0: steps.append(f) or res  # noqa: E731
    assert hold_sensor(t, res, ctx, GapConfig(), {}, late=late, finer=True) is t
    assert steps == [1.0] and ctx.widened == {}


def test_without_a_late_replay_nothing_is_held():
    ctx = _ctx()
    res = _residual(W, 0.0, 3e-4, 3e-4)
    t = _fit(res, ctx)
    assert hold_sensor(t, res, ctx, GapConfig(), {}) is t and ctx.widened == {}
