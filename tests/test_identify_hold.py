"""identify's family holds keep a scalar the context holds at a value (``Structure.held``).

A ``Context.widened`` range of one value holds a scalar at that value (e.g. a backlash read on
the motor side, ``gap.play_side``, or a torque-off Coulomb level a user knows). ``identify``'s
families hold further (effect, param) pairs at their null by rebuilding the structure with fewer
free scalars; until 2026-11-28 that rebuild dropped ``Structure.held``, so the held scalar went
back to its catalogue null in every family's fit. Truth: the value asked for, exactly.
"""

import numpy as np

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.identify import HELD_FIRST, IdentifyConfig, _fit_families, _hold
from lowcostdex.gap.identify_starts import own

EFFECTS = ("gearbox_friction", "backdriven_friction")
JOINTS = ("a", "b")
ASKED = 0.0182  # N m: held on joint b only
KEY = ("backdriven_friction", "coulomb", 1)


def _ctx() -> fitmod.Context:
    return fitmod.Context(dt=0.005, peak_force=np.array([1.0, 1.0]), stall=np.array([1.0, 1.0]),
                          damping=np.zeros(2), widened={KEY: (ASKED, ASKED)})


def _coulomb(st: fitmod.Structure, x: np.ndarray) -> np.ndarray:
    (bd,) = [e for e in st.to_effects(x) if e.name == "backdriven_friction"]
    return np.asarray(bd.values["coulomb"])


def test_a_family_hold_keeps_the_value_the_context_holds():
    st = fitmod.Structure.build(EFFECTS, JOINTS, _ctx())
    assert st.held == {KEY: ASKED}
    held = _hold(st, HELD_FIRST | {("backdriven_friction", "viscous")})
    assert held is not None and len(held.free) < len(st.free)
    for s in (held, own(st)):
        assert s.held == {KEY: ASKED}
        for x in s.starts():
            assert _coulomb(s, x)[1] == ASKED  # exactly the value asked for
        assert not any((f.effect, f.param, f.joint) == KEY for f in s.free)


def test_every_family_fit_replays_the_held_value():
    """The held value reaches every model ``_fit_families`` evaluates, in every family and
    stage (a residual that records what it is asked to replay)."""
    seen: list[float] = []

    def residual(points):
        out = []
        for s, x in points:
            c = _coulomb(s, x)
            seen.append(float(c[1]))
            out.append(np.concatenate([c - 0.01, np.ones(1)]))
        return out

    families = {"held": HELD_FIRST, "nominal_motor": HELD_FIRST | {("gearbox_friction", "mu")}}
    cfg = IdentifyConfig(effects=EFFECTS, max_rounds=2, joint_rounds=1)
    best, _ = _fit_families(residual, JOINTS, _ctx(), cfg, families, 1, lambda s, f: None)
    assert set(best) == {("held", 0), ("nominal_motor", 0)}
    assert seen and set(seen) == {ASKED}
    for t in best.values():
        assert _coulomb(t.structure, t.x)[1] == ASKED
