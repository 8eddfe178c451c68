"""Which side of a backlash play the log reads: the link, or the motor side (issue 11).

The catalogue's ``backlash`` has a ``read`` parameter (``sim.effects.backlash``): 1, its null,
reads the link (an output-shaft or link encoder: the reading swings through the play), 0 the
motor side (the servo's own encoder before the play: a rotor-side encoder, a horn, belt or tendon
beyond the servo; the play shows only through the link's load on the motor). The two are
different models, not a continuum a fit could slide along: the side is chosen, not fitted.
A backlash candidate is fitted on both sides (``structures``): as the catalogue frees it (link
read, the loop's ``sensor`` free) and read on the motor side with the loop reading there too
(read and sensor held at 0: the servo closes its loop on the encoder the log reads). The side with
the lower training cost is the candidate's (the forward round's best track per effect); once the
cause is accepted its side is kept for every later refit (``chosen``: ranges for the context's
``widened``, as a freed asymmetry's are).

Measured (gap-rotor12, session 17, third truth simulator's finger, encoder on the rotor side):
the link-read play replays fin_backlash080_dist worse than none at every width (whole logs at
0.5 ms: 0.827 mrad nominal, 20.4 at the true 0.08 rad); read on the motor side, 0.683 mrad, every
joint at the read floor; fin_pair's 0.05 rad prox play (its 80 ms latency on abd applied): 1.211
-> 0.685 mrad (13.1 read on the link).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from lowcostdex.gap import fit as fitmod
from lowcostdex.sim.effects import AppliedEffect

READ, SENSOR = ("backlash", "read"), ("backlash", "sensor")
WIDTH = ("backlash", "width")
ONE_JOINT = (0.01, 1.0)  # a one-joint start: width [rad] (the catalogue's start), sensor (across)
UNTOLD = 1e-6  # a sensor moving the training cost by less (relative) is not told by the data


def motor_ranges(n: int) -> dict[tuple[str, str, int], tuple[float, float]]:
    """Ranges holding a backlash on ``n`` joints read on the motor side, its loop there too."""
    return {(*key, j): (0.0, 0.0) for key in (READ, SENSOR) for j in range(n)}


def structures(name: str, joints: Sequence[str], ctx: fitmod.Context,
               fixed: Sequence[AppliedEffect] = ()) -> list[fitmod.Structure]:
    """The structures a forward round fits for candidate ``name``: the catalogue's and, for a
    backlash whose side the context does not hold yet, the same read on the motor side."""
    out = [fitmod.Structure.build((name,), joints, ctx, fixed=fixed)]
    if name == READ[0] and not any(k[:2] == READ for k in ctx.widened):
        out.append(fitmod.Structure.build((name,), joints,
                                          ctx.with_ranges(motor_ranges(len(joints))), fixed=fixed))
    return out


def tracks(name: str, joints: Sequence[str], ctx: fitmod.Context,
           fixed: Sequence[AppliedEffect] = (), warm: Sequence[AppliedEffect] | None = None,
           one_joint: bool = False) -> list[fitmod.Track]:
    """A forward round's tracks for candidate ``name``: each of its ``structures`` from its
    starts (and ``one_joint_starts`` when ``one_joint``, ``GapConfig.play_step``), or from
    ``warm`` (its fit at a coarser step) when given."""
    return [fitmod.Track(st, st.u(x0), label=f"{name}#{k}" + (" motor side" if i else ""))
            for i, st in enumerate(structures(name, joints, ctx, fixed))
            for k, x0 in enumerate([st.values_from(warm)] if warm is not None else
                                   st.starts() + (one_joint_starts(st) if i == 0 and one_joint else []))]


def one_joint_starts(st: fitmod.Structure) -> list[np.ndarray]:
    """Starts of a backlash structure ``st`` with a play on one joint each (``ONE_JOINT``: its
    width and sensor there; every other joint's width at none): one per joint whose width is
    free, none for other structures or a one-joint rig (the catalogue's starts put their play
    on its only joint already). A sensor the data cannot tell stays where a start put it:
    ``settle_sensor``."""
    x0 = np.array([f.start for f in st.free])
    out = []
    for j in range(len(st.joints) if len(st.joints) > 1 else 0):
        x = np.array([0.0 if (f.effect, f.param) == WIDTH else v
                      for f, v in zip(st.free, x0, strict=True)])
        moved = False
        for i, f in enumerate(st.free):
            if f.joint == j and (f.effect, f.param) in (WIDTH, SENSOR):
                x[i] = float(np.clip(ONE_JOINT[(f.effect, f.param) == SENSOR], f.lo, f.hi))
                moved = moved or (f.effect, f.param) == WIDTH
        if moved:
            out.append(x)
    return out


def settle_sensor(t: fitmod.Track | None, fn: fitmod.ResidualFn) -> bool:
    """Set every backlash sensor of the fitted track ``t`` that sits at 0.5 or more (across the
    play) but moves ``t``'s cost on ``fn`` by less than ``UNTOLD`` (relative) back to its
    catalogue start (the motor side), in place; True when one moved (None: no track, False).
    One batched replay.

    A start is not evidence: where the replay cannot tell the sensor, a fit leaves it where its
    start put it. Measured (session 26, the main job's emulated D'Claw, dcmotor servos, truth
    sensor 0): the one-joint start (sensor 1.0) that won left ff_middle's sensor at 1.0, its
    widths the same to 1e-9 rad as the catalogue start's (sensor 0) fit."""
    if t is None:
        return False
    s = t.structure
    idx = [i for i, (f, v) in enumerate(zip(s.free, t.x, strict=True))
           if (f.effect, f.param) == SENSOR and v >= 0.5]
    if not idx or t.r is None or not math.isfinite(t.cost):
        return False
    trials = []
    for i in idx:
        x = t.x.copy()
        x[i] = s.free[i].start
        trials.append((s, x))
    rs = fn(trials)
    untold = [i for i, r in zip(idx, rs, strict=True)
              if np.all(np.isfinite(r)) and 0.5 * float(r @ r) <= t.cost * (1 + UNTOLD)]
    if not untold:
        return False
    x = t.x.copy()
    for i in untold:
        x[i] = s.free[i].start
    r = rs[idx.index(untold[0])] if len(untold) == 1 else fn([(s, x)])[0]
    t.u, t.r, t.cost, t.jac = s.u(x), r, 0.5 * float(r @ r), None
    return True


def keep(best: dict[str, fitmod.Track], widened: dict[str, tuple[dict, list]]) -> None:
    """Add the side of the round's best backlash track (``chosen``) to ``widened`` (candidate
    name -> (ranges, report lines), kept in the context once the cause is accepted), in place."""
    for n, (r, lines) in chosen(best).items():
        old = widened.get(n, ({}, []))
        widened[n] = ({**r, **old[0]}, [*lines, *old[1]])


def ranges(s: fitmod.Structure) -> dict[tuple[str, str, int], tuple[float, float]]:
    """The ranges that rebuild ``s``'s reading side (empty: the catalogue's, the link)."""
    return motor_ranges(len(s.joints)) if s.held.get((*READ, 0)) == 0.0 else {}


def chosen(best: dict[str, fitmod.Track]) -> dict[str, tuple[dict, list]]:
    """{"backlash": (ranges, [(effect, report line)])} when the best backlash track of a round
    (``best``: candidate name -> track) reads the motor side; empty otherwise."""
    t = best.get(READ[0])
    if t is None or not (r := ranges(t.structure)):
        return {}
    return {READ[0]: (r, [(READ[0], "read on the motor side (read 0: the servo's own encoder "
                                    "before the play, its loop there too): a lower training "
                                    "error than read on the link")])}
