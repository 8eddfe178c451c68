"""When the report calls a named effect a possible stand-in (``gap.standin``, session 20).

Truth from physics written out here, not from the analyzer: a link of mass m and length l whose
centre of mass sits a distance d across it has the gravity torque m g (l cos q + d sin q); a
model with a reading offset and a mass factor predicts s m g l cos(q - offset). Fitted by least
squares over the logged poses, the offset lands on atan(d / l), an angle the encoder never
had. Whether the logs can tell that offset from a mass change depends on the poses: over a
narrow arc sin and cos are nearly proportional and the two trade; over poses all round the joint
they do not. The rule must flag the first and leave the second (and any offset named without a
mass effect, the sim2-sim5 cases whose truth is an offset) worded as before.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import standin
from lowcostdex.gap.gain import Gain
from lowcostdex.gap.results import Cause, verdict_text

M, G, L, D = 0.05, 9.81, 0.04, 0.005  # kg, m/s^2, m, m: a 5 mm centre-of-mass shift


def _ctx(nj: int = 1) -> fitmod.Context:
    return fitmod.Context(dt=0.002, peak_force=np.full(nj, 0.5), stall=np.full(nj, np.inf),
                          damping=np.zeros(nj))


def _fit(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton fit of (offset, mass factor) to the shifted link's gravity torques; returns
    the values, the Jacobian at them (columns: offset, scale) and the residual."""
    truth = M * G * (L * np.cos(poses) + D * np.sin(poses))
    x = np.array([0.0, 1.0])
    for _ in range(50):
        model = x[1] * M * G * L * np.cos(poses - x[0])
        jac = -np.column_stack([x[1] * M * G * L * np.sin(poses - x[0]),
                                M * G * L * np.cos(poses - x[0])])
        r = truth - model
        x = x - np.linalg.lstsq(jac, r, rcond=None)[0]
    model = x[1] * M * G * L * np.cos(poses - x[0])
    jac = -np.column_stack([x[1] * M * G * L * np.sin(poses - x[0]),
                            M * G * L * np.cos(poses - x[0])])
    return x, jac, truth - model


def _params(x: np.ndarray, half: float = 0.01) -> dict[str, dict]:
    return {"position_offset": {"offset": {"value": [x[0]], "interval": [[x[0] - half,
                                                                          x[0] + half]],
                                           "unit": "rad"}},
            "mass_error": {"scale": {"value": [x[1]], "interval": [[x[1] - 0.01, x[1] + 0.01]],
                                     "unit": "1"}}}


def _gain(rb: float, re: float, floor: float, ci: tuple[float, float], episodes: int = 3) -> Gain:
    return Gain(rb, re, rb, re, rb - re, (rb - re) / rb, ci, (ci[0] / rb, ci[1] / rb), floor,
                None, episodes)


def test_shared_information_is_the_squared_correlation_for_two_columns():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=50), rng.normal(size=50)
    jac = np.column_stack([a, 0.6 * a + 0.8 * b])
    cos2 = (a @ jac[:, 1]) ** 2 / ((a @ a) * (jac[:, 1] @ jac[:, 1]))
    assert standin.shared_information(jac, 0, [1]) == pytest.approx(cos2, rel=1e-9)
    assert standin.shared_information(jac, 0, []) == 0.0
    # scaling a column (optimizer coordinates: log of a scale) changes nothing
    assert standin.shared_information(jac * [3.0, 0.01], 0, [1]) == pytest.approx(cos2, rel=1e-9)


def test_a_centre_of_mass_shift_fitted_as_an_offset_is_flagged_over_a_narrow_arc_only():
    free = fitmod.Structure.build(("position_offset", "mass_error"), ("pip",), _ctx()).free
    assert [(f.effect, f.param) for f in free] == [("position_offset", "offset"),
                                                   ("mass_error", "scale")]
    # a finger moving over 0.4 rad: the fit's offset is the shifted centre of mass' angle
    narrow = np.linspace(0.3, 0.7, 200)
    x, jac, r = _fit(narrow)
    assert x[0] == pytest.approx(math.atan2(D, L), abs=1e-9)  # 124 mrad: not the encoder
    assert x[1] == pytest.approx(math.hypot(L, D) / L, abs=1e-9)
    assert np.abs(r).max() < 1e-12
    share = standin.shared_information(jac, 0, [1])
    assert share > 0.85 > standin.SHARED  # 0.893: uncentred sin and cos over 0.3-0.7 rad
    notes = standin.stand_in_notes(free, ("pip",), jac, _params(x))
    assert list(notes) == ["position_offset"]
    (text,) = notes["position_offset"]
    assert text.startswith("may stand in for a centre-of-mass shift")
    assert f"pip {1e3 * x[0]:.3g} mrad: {100 * share:.0f} %" in text
    assert "before re-zeroing" in text
    # poses all round the joint: sin and cos are orthogonal, the offset is measured
    wide = np.linspace(-math.pi, math.pi, 400, endpoint=False)
    x, jac, _ = _fit(wide)
    assert standin.shared_information(jac, 0, [1]) < 0.01
    assert standin.stand_in_notes(free, ("pip",), jac, _params(x)) == {}


def test_an_offset_whose_interval_holds_zero_or_that_is_fitted_alone_is_not_flagged():
    x, jac, _ = _fit(np.linspace(0.3, 0.7, 200))
    both = fitmod.Structure.build(("position_offset", "mass_error"), ("pip",), _ctx()).free
    assert standin.stand_in_notes(both, ("pip",), jac, _params(x, half=0.2)) == {}
    alone = fitmod.Structure.build(("position_offset",), ("pip",), _ctx()).free
    assert standin.stand_in_notes(alone, ("pip",), jac[:, :1], _params(x)) == {}
    assert standin.stand_in_notes(both, ("pip",), None, _params(x)) == {}


def test_the_verdict_of_an_offset_named_alone_is_worded_as_before():
    """The sim2-sim5 cases whose truth is an offset name it alone (or beside a latency): no
    mass effect trades with it, so the decision step leaves their verdict unchanged."""
    x, jac, _ = _fit(np.linspace(0.3, 0.7, 200))
    s = fitmod.Structure.build(("latency", "position_offset"), ("pip",), _ctx())
    track = fitmod.Track(s, np.zeros(s.n))
    track.jac = np.column_stack([np.linspace(0, 1, 200), jac[:, 0]])[:, :s.n]
    causes = [Cause("latency", ("pip",), {}),
              Cause("position_offset", ("pip",), _params(x)["position_offset"])]
    g = _gain(0.04, 0.002, 0.0005, (0.03, 0.045))
    before = verdict_text(causes, g, "x")
    assert before == "latency, position_offset: held-out RMSE 0.04 -> 0.002 rad (95 % lower)"
    # ... and the judge adds only what is left (2 mrad over a 0.5 mrad floor: 4 floors)
    assert standin.judge(causes, track, g, "x") == before + (
        "; left: 2 mrad held-out RMSE (5 % of the nominal model's), 4x the noise floor 0.5 mrad: "
        "above the 3 floors a replay of an exact model leaves, so something beyond the named "
        "causes is at work")
    assert all(c.stand_in == [] for c in causes)


def test_the_verdict_warns_beside_an_offset_traded_against_the_mass():
    x, jac, _ = _fit(np.linspace(0.3, 0.7, 200))
    s = fitmod.Structure.build(("position_offset", "mass_error"), ("pip",), _ctx())
    track = fitmod.Track(s, np.zeros(s.n))
    track.jac = jac
    p = _params(x)
    causes = [Cause("position_offset", ("pip",), p["position_offset"]),
              Cause("mass_error", ("pip",), p["mass_error"])]
    text = standin.judge(causes, track, _gain(0.04, 0.002, 0.0005, (0.03, 0.045)), "x")
    assert text == ("position_offset (may stand in for a centre-of-mass shift, link geometry or a "
                    "tilted base: check before re-zeroing), mass_error: held-out RMSE 0.04 -> "
                    "0.002 rad (95 % lower)" + "; left: 2 mrad held-out RMSE (5 % of the nominal model's), 4x the noise floor 0.5 mrad: "
                    "above the 3 floors a replay of an exact model leaves, so something beyond the named "
                    "causes is at work")
    assert len(causes[0].stand_in) == 1 and causes[1].stand_in == []


def test_an_unreliable_gain_that_leaves_the_discrepancy_is_at_best_a_partial_stand_in():
    """sim6 deadband_torque (a PWM deadband, outside the catalogue): gain_error lowered the
    held-out RMSE 485 -> 168 mrad, noise floor 0.443 mrad, gain interval [-49.6, 603] mrad."""
    causes = [Cause("gain_error", ("mcp",), {})]
    g = _gain(0.4854, 0.1682, 0.000443, (-0.0496, 0.603))
    text = standin.judge(causes, None, g, "x")
    assert text == ("gain_error: no reliable gain (held-out RMSE 0.4854 -> 0.1682 rad; the gain's "
                    "95 % interval [-49.6, 603] mrad includes zero): the extended model is not "
                    "recommended; the discrepancy is not explained (380x the noise floor left): "
                    "gain_error at best a partial stand-in for something outside the candidate "
                    "effects")
    assert causes[0].stand_in and causes[0].stand_in[0].startswith("at best a partial stand-in")
    # the same unreliable gain with the extended model within two noise floors: nothing left
    # to explain, no stand-in sentence
    near = _gain(0.4854, 0.0008, 0.000443, (-0.0496, 0.603))
    causes = [Cause("gain_error", ("mcp",), {})]
    text = standin.judge(causes, None, near, "x")
    assert text.endswith("not recommended") and causes[0].stand_in == []
    # a reliable gain is worded as before
    causes = [Cause("gain_error", ("mcp",), {})]
    assert standin.judge(causes, None, _gain(0.4854, 0.1682, 0.000443, (0.1, 0.6)), "x") == (
        "gain_error: held-out RMSE 0.4854 -> 0.1682 rad (65 % lower); left: 168 mrad held-out "
        "RMSE (35 % of the nominal model's), 380x the noise floor 0.443 mrad: above the 3 "
        "floors a replay of an exact model leaves, so something beyond the named causes is at "
        "work")
