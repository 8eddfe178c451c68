"""A Stribeck friction whose breakaway is 0 is a Coulomb (``lowcostdex.gap.gates.drop_weak``;
issue 11, redteam sim2 ``torque_coulomb_pendulum``: a sticking 0.1 N m Coulomb beside a 1.2 N m
torque limit was fitted as stribeck_friction static 0, coulomb 0.104, then dropped at the end
because its breakaway interval held 0, leaving "torque_limit alone" with the limit biased to
1.086 [1.042, 1.133]).

The physics truth is Newton's law for a lone rotor written out here: inertia I (armature only, no
gravity, damping or spring) spinning at w0 under dry friction F decelerates at F / I and stops after
I w0 / F; at rest, a torque below F holds it. Both the catalogue's Stribeck with static 0 and its
stiff Coulomb (creep 0) must do that, so replacing one by the other loses nothing. The decision
part is checked on hand-written intervals.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.gates import drop_weak
from lowcostdex.sim.effects import AppliedEffect

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from rotor_bench import DT, INERTIA, run  # noqa: E402  (a plain-MJCF rotor)

LEVEL = 0.1     # N m, the redteam case's Coulomb

STRIBECK0 = AppliedEffect("stribeck_friction", ("q",), {
    "static": 0.0, "velocity": 0.2, "coulomb": LEVEL})
STIFF_COULOMB = AppliedEffect("coulomb_friction", ("q",), {
    "frictionloss": LEVEL, "creep": 0.0, "asymmetry": 0.0})


@pytest.mark.parametrize("eff", [STRIBECK0, STIFF_COULOMB], ids=["stribeck0", "coulomb_stiff"])
def test_a_stribeck_without_breakaway_is_a_stiff_coulomb(eff):
    """Spin-down from 2 rad/s stops after I w0 / F = 0.2 s and turns I w0^2 / (2 F) = 0.2 rad;
    a 0.07 N m push (below 0.1) from rest leaves the rotor within 1 mrad over 2 s."""
    w0 = 2.0
    traj = run(eff, 0.0, w0, 0.4)
    stop = np.argmax(np.abs(traj[:, 1]) < 1e-3) * DT
    assert stop == pytest.approx(INERTIA * w0 / LEVEL, rel=0.03)
    assert traj[-1, 0] == pytest.approx(INERTIA * w0 ** 2 / (2 * LEVEL), rel=0.03)
    held = run(eff, 0.07, 0.0, 2.0)
    assert np.max(np.abs(held[:, 0])) < 1e-3


def _ctx():
    return fitmod.Context(dt=0.002, peak_force=np.array([1.5]), stall=np.array([np.inf]),
                          damping=np.array([0.01]))


def _track(ctx, effects, values):
    s = fitmod.Structure.build(effects, ("q",), ctx)
    x = s.values_from(values)
    return fitmod.Track(s, s.u(x))


def _intervals(t, halves):
    """Centres at the fitted point, half-widths by parameter (default 1e-3 in u)."""
    half = np.array([halves.get((f.effect, f.param), 1e-3) for f in t.structure.free])
    return t.u.copy(), half


TL = AppliedEffect("torque_limit", ("q",), {"torque": 1.2})


def test_stribeck_with_breakaway_at_zero_and_a_level_away_from_zero_becomes_a_stiff_coulomb():
    """static 0 +- 0.02 (holds 0), coulomb 0.104 +- 0.01 (excludes 0): the model keeps
    torque_limit and gets coulomb_friction in the Stribeck's place, its level starting at 0.104
    and its creep freed (range 0..1) starting stiff (0); the context keeps the freed range."""
    ctx = _ctx()
    strib = AppliedEffect("stribeck_friction", ("q",), {
        "static": 0.0, "velocity": 0.2, "coulomb": 0.104})
    t = _track(ctx, ("torque_limit", "stribeck_friction"), [TL, strib])
    mid, half = _intervals(t, {("stribeck_friction", "static"): 0.02,
                               ("stribeck_friction", "coulomb"): 0.01})
    cur, x, why = drop_weak(t, "stribeck_friction", mid, half, ctx)
    assert cur.effects == ("torque_limit", "coulomb_friction")
    got = {(f.effect, f.param): (v, f.lo, f.hi) for f, v in zip(cur.free, x, strict=True)}
    assert got[("coulomb_friction", "frictionloss")][0] == pytest.approx(0.104)
    assert got[("coulomb_friction", "creep")] == (0.0, 0.0, 1.0)
    assert got[("torque_limit", "torque")][0] == pytest.approx(1.2)
    assert ("coulomb_friction", "asymmetry") not in got  # still held symmetric
    assert ctx.widened[("coulomb_friction", "creep", 0)] == (0.0, 1.0)
    assert "refitted as coulomb_friction" in why and "0.104" in why


@pytest.mark.parametrize("drop, coulomb, half_c, has_coulomb", [
    ("stribeck_friction", 0.004, 0.01, False),   # the sliding level holds 0 too: no friction
    ("stribeck_friction", 0.104, 0.01, True),    # a Coulomb is already in the model
    ("torque_limit", 0.104, 0.01, False),        # another effect is weak: dropped as before
])
def test_otherwise_the_weak_effect_is_dropped(drop, coulomb, half_c, has_coulomb):
    ctx = _ctx()
    strib = AppliedEffect("stribeck_friction", ("q",), {
        "static": 0.0, "velocity": 0.2, "coulomb": coulomb})
    names = ("torque_limit", "stribeck_friction") + (("coulomb_friction",) if has_coulomb else ())
    t = _track(ctx, names, [TL, strib, STIFF_COULOMB])
    mid, half = _intervals(t, {("stribeck_friction", "static"): 0.02,
                               ("stribeck_friction", "coulomb"): half_c})
    cur, x, why = drop_weak(t, drop, mid, half, ctx)
    assert cur.effects == tuple(n for n in names if n != drop)
    assert why == f"; {drop} dropped: its 95 % interval holds no effect"
    assert not ctx.widened
    want = {("torque_limit", "torque"): 1.2, ("stribeck_friction", "coulomb"): coulomb,
            ("coulomb_friction", "frictionloss"): LEVEL}
    got = {(f.effect, f.param): v for f, v in zip(cur.free, x, strict=True)}
    assert {k: got[k] for k in want if k[0] in cur.effects} == {
        k: pytest.approx(v) for k, v in want.items() if k[0] in cur.effects}


# ---- gain error and inertia error stand in for each other (gates.swap_equivalent) -------------
# A rotor on a P-D position servo, no gravity, written out here: (J_arm a + J_body) q'' =
# s kp (g - q) - (D0 + d) q', integrated by semi-implicit Euler; a the inertia_error scale (of
# the armature), s the gain_error scale, d the viscous_damping. Dividing by s shows gain s with
# damping d is the same trajectory as gain 1, inertia a' = ((J_arm + J_body) / s - J_body) / J_arm
# and damping (D0 + d) / s - D0: the redteam sim2 gain_viscous_turntable pair (truth 0.7, 0.08).
J_ARM, J_BODY, KP, D0, H = 0.03, 0.01, 2.0, 0.1, 0.002


def _rotor(s: float, a: float, d: float) -> np.ndarray:
    goals = np.repeat([0.5, -0.3, 0.8, 0.0, -0.6], 400)
    q = w = 0.0
    out = np.empty(len(goals))
    for i, g in enumerate(goals):
        w += H * (s * KP * (g - q) - (D0 + d) * w) / (J_ARM * a + J_BODY)
        q += H * w
        out[i] = q
    return out


def _rotor_residual(truth: np.ndarray):
    def residual(batch):
        out = []
        for st, x in batch:
            v = {e.name: float(next(iter(e.values.values()))[0]) for e in st.to_effects(x)}
            out.append(_rotor(v.get("gain_error", 1.0), v.get("inertia_error", 1.0),
                              v.get("viscous_damping", 0.0)) - truth)
        return out
    return residual


def _select_sse(res, ctx):
    """The select SSE of whole models (lists of effects): here the same rotor run."""
    def sse(models):
        out = []
        for m in models:
            st = fitmod.Structure.build(tuple(e.name for e in m), ("q",), ctx)
            out.append(float(np.sum(res([(st, st.values_from(m))])[0] ** 2)))
        return out
    return sse


def _fitted(ctx, names, res):
    from lowcostdex.gap.results import GapConfig

    s = fitmod.Structure.build(names, ("q",), ctx)
    t = fitmod.Track(s, s.u(np.array([f.start for f in s.free])))
    fitmod.lockstep_lm([t], res, GapConfig().max_rounds, jacobian_at_end=False)
    return s, t


def test_a_gain_error_that_an_inertia_error_stood_in_for_is_named_with_the_pair_reported():
    """Truth gain 0.7 + damping 0.08; the model inertia_error + viscous_damping fits it exactly
    (inertia ((0.04 / 0.7) - 0.01) / 0.03 = 1.571, damping 0.18 / 0.7 - 0.1 = 0.157); the swap
    names gain_error 0.7 with damping 0.08 (1 %) and lists inertia_error as its equivalent."""
    from lowcostdex.gap.gates import swap_equivalent
    from lowcostdex.gap.results import GapConfig

    ctx = _ctx()
    noise = 1e-3 * np.random.default_rng(1).standard_normal(2000)  # 1 mrad read noise
    res = _rotor_residual(_rotor(0.7, 1.0, 0.08) + noise)
    s, t = _fitted(ctx, ("viscous_damping", "inertia_error"), res)
    assert t.x == pytest.approx([0.18 / 0.7 - 0.1, (0.04 / 0.7 - 0.01) / 0.03], rel=0.01)
    eq = {"inertia_error": ["mass_error"]}
    sse = _select_sse(res, ctx)
    cur, x, why = swap_equivalent(s, t.x, res, sse, GapConfig(), ctx, eq)
    assert cur.effects == ("viscous_damping", "gain_error")
    assert x == pytest.approx([0.08, 0.7], rel=0.01)
    assert eq == {"gain_error": ["mass_error", "inertia_error"]}
    assert "not identifiable" in why and "inertia_error" in why


def test_an_inertia_error_alone_is_kept_when_a_gain_cannot_replay_it():
    """Truth inertia 1.8 alone: a gain alone (damping fixed) changes the damping ratio too,
    so its best select error is far above the inertia's: nothing is swapped."""
    from lowcostdex.gap.gates import swap_equivalent
    from lowcostdex.gap.results import GapConfig

    ctx = _ctx()
    noise = 1e-4 * np.random.default_rng(0).standard_normal(2000)
    res = _rotor_residual(_rotor(1.0, 1.8, 0.0) + noise)
    s, t = _fitted(ctx, ("inertia_error",), res)
    assert t.x == pytest.approx([1.8], rel=0.01)
    eq: dict = {}
    cur, x, why = swap_equivalent(s, t.x, res, _select_sse(res, ctx), GapConfig(), ctx, eq)
    assert (cur, why, eq) == (s, "", {})
    assert x == pytest.approx([1.8], rel=0.01)
