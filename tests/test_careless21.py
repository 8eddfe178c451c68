"""Careless calls, session 24 (issues 13, 11): each test failed on the code before its fix.
Expected bounds are ROBEL's D'Claw joint ranges, written out here (its MJCF: top -0.5..1.35,
middle and bottom -2.0..2.0 rad)."""

from __future__ import annotations

import dataclasses

import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.hands import HandSpec, dclaw_spec

HAND = dclaw_spec()


def with_joint(hand: HandSpec, name: str, **changes) -> HandSpec:
    return dataclasses.replace(hand, joints=tuple(
        dataclasses.replace(j, **changes) if j.name == name else j for j in hand.joints))


@pytest.mark.parametrize("joint,low,high,stop", [
    ("ff_middle", -2.5, 2.5, r"\[-2.0, 2.0\]"),   # fits the motor's turn (pi -+ 2.5), not the finger
    ("mf_top", -0.48, 1.5, r"\[-0.5, 1.35\]"),      # motor angles [1.09, 3.07]: inside the turn
    ("th_bottom", -2.2, 1.0, r"\[-2.0, 2.0\]"),
])
def test_a_dclaw_spec_with_limits_past_the_fingers_stops_is_refused_where_it_is_built(
        joint, low, high, stop):
    # a Robot is built from a spec and a bus, with no model: before, only a backend given the
    # model checked the stops, so Robot(spec, bus) drove the finger into them
    with pytest.raises(ConfigError, match=rf"joint {joint}: limits \[{low}, {high}\] rad leave "
                                          rf"the D'Claw's joint range {stop}.*type limits"):
        with_joint(HAND, joint, low=low, high=high)


def test_a_dclaw_spec_inside_the_stops_still_passes():
    with_joint(HAND, "ff_middle", low=-2.0, high=2.0)
    with_joint(HAND, "mf_top", low=-0.5, high=1.35)
