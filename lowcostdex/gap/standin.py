"""When a named calibration offset may stand in for something else: the fit's own statistics.

A reading or mounting offset moves the angle at which the model's gravity acts. Under a torque
replay (the logged torques applied open loop) or a loop closed on the offset encoder, that is how
the logs see it: the gravity torque of a link, m g l cos(q - offset). A centre of mass moved a
distance d across a link of length l gives m g sqrt(l^2 + d^2) cos(q - atan(d / l)): the same
angle shift with a mass factor; a tilted base or a bent link shifts the angle too. When the fit
also frees the links' mass (``mass_error``), the two trade: what the data says about the offset
is in large part what it says about the mass. The offset then explains the data without showing
that the encoder is off: re-zeroing it by the fitted angle would move a correct zero.

The rule (``stand_in_notes``): an offset whose 95 % interval excludes zero is flagged when the
final fit's information (J^T J of its residuals) on it is shared with the mass parameters:
``shared`` = 1 - var(offset | masses held) / var(offset | masses free) >= ``SHARED`` (the
squared multiple correlation of the offset with the masses; 0.5: half of what the data says about
the offset is also explained by a mass change). Measured on sim6's com_offset_torque (a 5 mm
centre-of-mass shift; session 20, gap-judge15): the fitted pip/dip offsets -93/-98 mrad share
0.73/0.87 with mass_error. An offset named without a mass effect (every sim2-sim5 and
test_gap_independent offset case whose truth is an offset) is not judged: nothing in the fit
trades with it. The rule does not see an offset that alone stands in for a centre-of-mass shift
(no mass effect freed beside it).

A name is also only a stand-in when another mechanism explained the data nearly as well where
it was chosen (``rival_notes``: a note, the name and the verdict unchanged).

``judge`` writes these notes on the causes and the verdict; a cause whose held-out gain is not
reliable while the discrepancy stays above the noise floors is noted as a partial stand-in too
(``results.verdict_text``). A reliable gain's verdict also says what the named causes leave
(``residual_left``): the held-out RMSE left, its share of the nominal model's and its noise
floors, within or above what a replay of an exact model leaves (``EXPLAINED`` floors): "named
X; 0.8 mrad left, at the floor" and "named X; 12 mrad left, something else is at work" are
different findings (sim10's latency beside a friction rising over the session read "85 % lower"
with 19.5 floors left).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.gain import Gain
from lowcostdex.gap.results import (
    CandidateResult,
    Cause,
    partial_stand_in,
    unreliable,
    verdict_text,
)
from lowcostdex.gap.spaces import Free

OFFSETS = ("position_offset", "mounting_offset")  # calibration offsets a user would re-zero
LOADS = (("mass_error", "scale"),)  # parameters that scale the gravity load itself
SHARED = 0.5
RIVAL = 0.9  # a rival explaining this share of a chosen cause's select gain makes it a tie ...
RIVAL_LEFT = 1.1  # ... when it also leaves at most this factor of the chosen one's select error
ALTERNATIVES = "a centre-of-mass shift, link geometry or a tilted base"
EXPLAINED = 3.0  # noise floors a replay of an exact model leaves (GapConfig.explain_above)


def shared_information(jac: np.ndarray, i: int, others: Sequence[int]) -> float:
    """Share of column ``i``'s information that columns ``others`` also carry: 1 - var(i |
    others held) / var(i | all free) from J^T J (the squared multiple correlation of parameter
    ``i`` with ``others`` in the Gauss-Newton covariance); 0 without ``others``."""
    if not len(others):
        return 0.0
    a = jac.T @ jac
    full = np.linalg.pinv(a)[i, i]
    keep = [k for k in range(a.shape[0]) if k not in set(others)]
    held = np.linalg.pinv(a[np.ix_(keep, keep)])[keep.index(i), keep.index(i)]
    return float(1.0 - held / full) if full > 0 else 0.0


def stand_in_notes(free: Sequence[Free], joints: Sequence[str], jac: np.ndarray | None,
                   params: dict[str, dict]) -> dict[str, list[str]]:
    """Offset effect -> notes (one per effect, naming its joints) for offsets the fit trades
    against a gravity load (module docstring). ``free``: the final fit's free scalars, in
    ``jac``'s column order; ``params``: effect -> ``param_report`` dict (values, intervals)."""
    if jac is None or not len(free):
        return {}
    loads = [k for k, f in enumerate(free) if (f.effect, f.param) in LOADS]
    out: dict[str, list[str]] = {}
    for name in OFFSETS:
        hits = []
        for k, f in enumerate(free):
            if f.effect != name or not loads:
                continue
            d = params.get(name, {}).get(f.param)
            if d is None:
                continue
            lo, hi = d["interval"][f.joint]
            if lo <= 0.0 <= hi:  # no offset shown: nothing to re-zero
                continue
            share = shared_information(jac, k, loads)
            if share >= SHARED:
                hits.append((joints[f.joint], d["value"][f.joint], share))
        if hits:
            where = ", ".join(f"{j} {1e3 * v:.3g} mrad: {100 * sh:.0f} %" for j, v, sh in hits)
            out[name] = [f"may stand in for {ALTERNATIVES}: the fit trades the offset against "
                         f"mass_error (share of its information: {where}); an offset moves the "
                         "angle at which gravity acts, as those do: it explains the data but "
                         "does not show that the encoder is off; check the zero against a "
                         "reference pose before re-zeroing"]
    return out


def rival_notes(causes: Sequence[Cause], rounds: Sequence[Sequence[CandidateResult]],
                ratio: float = RIVAL, left: float = RIVAL_LEFT) -> None:
    """Add a note to each named cause that, in the selection round that accepted it, had a
    rival of another mechanism explaining at least ``ratio`` of what it explained on the select
    split AND leaving at most ``left`` times its select error (select gains g_rival >= ratio x
    g_chosen > 0 and 1 - g_rival <= left x (1 - g_chosen)), the rival itself not named: the
    data do not tell the two mechanisms apart, so the name may be a stand-in (sim10's
    latency_tight_spot: a friction bump on one joint beside a true latency was named
    inertia_error, select gain 15.4 %, with viscous_damping at 14.5 %). A cause that explains
    nearly everything is not tied by a rival that explains most (sim4 viscous_motor_posonly:
    viscous_damping 99.997 %, load_dependent_friction 93.5 %, 2000x the error left)."""
    named = {c.effect: c for c in causes}
    for table in rounds:
        for a in table:
            c = named.get(a.effect)
            if c is None or not a.accepted or not a.select_gain or a.select_gain <= 0:
                continue
            rivals = sorted((r for r in table if r.effect != a.effect
                             and r.effect not in named and r.select_gain is not None
                             and r.select_gain >= ratio * a.select_gain
                             and 1.0 - r.select_gain <= left * (1.0 - a.select_gain)),
                            key=lambda r: -r.select_gain)
            if rivals:
                what = ", ".join(f"{r.effect} {100 * r.select_gain:.3g} %" for r in rivals)
                c.stand_in.append(
                    f"may stand in for another mechanism: when it was chosen ({100 * a.select_gain:.3g} "
                    f"% lower select error) {what} explained the select data nearly as well "
                    f"(>= {100 * ratio:.0f} % of its gain, within {100 * (left - 1):.0f} % of its "
                    "select error); these data do not tell them apart")


def residual_left(gain: Gain, explained: float = EXPLAINED) -> dict:
    """What the extended model leaves on the held-out episodes (the nominal model's error when
    nothing is named): ``rmse`` [rad], its ``share`` of the nominal model's RMSE, the
    ``noise_floor`` [rad] and ``floors`` (rmse / floor), and ``at_floor``: within ``explained``
    floors (what a replay of an exact model leaves: the clean and exact truth-simulator cases
    end at 1.2-2.9 floors, sim10 clean_finger 1.2 and latency40_finger 2.9)."""
    left, base, fl = gain.extended_rmse, gain.baseline_rmse, gain.noise_floor
    floors = left / fl if fl > 0 else float("inf")
    return {"rmse": left, "share": left / base if base > 0 else None, "noise_floor": fl,
            "floors": floors, "explained_within_floors": explained,
            "at_floor": bool(floors <= explained)}


def residual_text(r: dict, unit: str = "mrad") -> str:
    """The verdict's words for ``residual_left`` (``unit``: of its x1e-3 figures)."""
    share = f" ({100 * r['share']:.2g} % of the nominal model's)" if r["share"] is not None else ""
    head = (f"left: {1e3 * r['rmse']:.3g} {unit} held-out RMSE{share}, {r['floors']:.3g}x the "
            f"noise floor {1e3 * r['noise_floor']:.3g} {unit}")
    if r["at_floor"]:
        return (f"{head}: within the {r['explained_within_floors']:g} floors a replay of an "
                "exact model leaves")
    return (f"{head}: above the {r['explained_within_floors']:g} floors a replay of an exact "
            "model leaves, so something beyond the named causes is at work")


def per_joint_text(joints: Sequence[str], slide: np.ndarray | None, before: dict, after: dict,
                   logged: Sequence[str], floor: np.ndarray) -> str:
    """Held-out RMSE per joint in its own unit, where the joints' units mix (a slide in m beside
    a hinge in rad; '' otherwise): the pooled RMSE adds metres to radians (gap-sim15's gripper
    read "1.19 -> 1.11 mrad" for a jaw 1.40 -> 0.18 mm beside its finger's 1.69 -> 1.55 mrad).
    ``before`` / ``after``: ``gain.episode_errors`` of the nominal and extended models;
    ``floor``: the noise floor of each ``logged`` joint."""
    if slide is None or not np.any(slide) or np.all(slide):
        return ""
    parts = []
    for j, lin in zip(joints, slide, strict=True):
        unit = "mm" if lin else "mrad"
        a, b = before["per_joint_rmse"][j], after["per_joint_rmse"][j]
        parts.append(f"{j} {1e3 * a:.3g} -> {1e3 * b:.3g} {unit} (noise floor "
                     f"{1e3 * float(floor[list(logged).index(j)]):.2g} {unit})")
    return "per joint, in each joint's unit (the pooled figures add m to rad): " + ", ".join(parts)


def judge(causes: Sequence[Cause], track: fitmod.Track | None, gain: Gain, stop_reason: str,
          worse: int = 0, explained: float = EXPLAINED, drift_note: str = "",
          per_joint: str = "") -> str:
    """Write each cause's ``stand_in`` notes and return the verdict (``results.verdict_text``):
    offsets the final fit ``track`` trades against a gravity load (``stand_in_notes``), and every
    cause when the held-out gain is not reliable and the discrepancy stays above ``UNEXPLAINED``
    noise floors (``worse``: test episodes on which the extended model is worse). A reliable
    gain's verdict ends with what is left (``residual_text``, ``explained`` floors); a
    ``drift_note`` (``diagnostics.session_drift``) is added to any verdict; so is ``per_joint``
    (``per_joint_text``: where a slide's m mix with a hinge's rad, the pooled figures
    are said to pool both and each joint's follow in its own unit)."""
    notes = (stand_in_notes(track.structure.free, track.structure.joints, track.jac,
                            {c.effect: c.params for c in causes}) if track is not None else {})
    short = {}
    for c in causes:
        c.stand_in = list(notes.get(c.effect, []))
        if c.stand_in:
            short[c.effect] = f"may stand in for {ALTERNATIVES}: check before re-zeroing"
    if causes and partial_stand_in(gain, worse):  # above UNEXPLAINED floors, gain not reliable
        for c in causes:
            c.stand_in.append("at best a partial stand-in: its held-out gain is not reliable "
                              "and the discrepancy is not explained (see the verdict); "
                              "something outside the candidate effects may be at work")
    pooled = ("rad and m pooled", "mrad and mm pooled") if per_joint else ("rad", "mrad")
    text = verdict_text(causes, gain, stop_reason, worse, short, pooled[0])
    if causes and not unreliable(gain, worse):
        text += "; " + residual_text(residual_left(gain, explained), pooled[1])
    return text + "".join(f"; {x}" for x in (per_joint, drift_note) if x)
