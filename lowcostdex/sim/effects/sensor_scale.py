"""The sensor scale (gear-ratio) error: the joint reading is ``scale`` x the joint angle; and
``reading_map``, the affine map from angle to reading of a model's reading effects (scale and
offsets), which a replay inverts to start from a measured reading.

Its own module (the catalogue, ``lowcostdex.sim.effects.catalogue``, lists it in ``EFFECTS`` /
``CAUSES``). 04-sysid.md section 6, "Gear-ratio / scale error": sensor gain != 1, residual
proportional to the reading, confusable with the P gain (static) and with calibration. Real
causes: a wrong gear ratio or steps per turn in the host's conversion of an encoder that is not
the servo's own (an output-shaft encoder behind a belt or gear stage: a 1:2 stage is 2 or 0.5),
ticks converted at 4000 or 4095 per turn for 4096 (-2.3 %, -0.02 %).

Which side: the reading only (kind ``observation``), as a ``position_offset``: the servo closes
its loop on its own (true) angle and the host logs the scaled reading. A conversion error the
host applies to both its goals and its readings (the servo's own encoder converted with one wrong
factor) holds the goal in the host's units, and the reading then differs from the nominal model
only by the factor times the static error (tens of microradians for a 1 % factor on a sagging
arm): it has no signature a replay can see, so it is not a separate effect.

Confusable family: ``gain_error`` (a softer or stiffer P loop also moves the reading away from
the goal in proportion to the load, which grows with the angle on a gravity-loaded joint),
``position_offset`` and ``mounting_offset`` (a reading shifted by a constant; over a small range
of angles a scale is an offset). A reading that is both scaled and shifted is (scale q + offset):
the scale acts first (``EFFECTS`` order), the offsets are added to the scaled reading.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from lowcostdex.sim.effects.base import Effect, Param, Targets, Values


class SensorScale(Effect):
    name = "sensor_scale"
    kind = "observation"
    doc = ("the joint reading is `scale` x the joint angle (a wrong gear ratio or ticks per turn "
           "in the conversion of an output encoder); the servo holds its goal in the true angle")
    # Bounds cover the reference's < 1 % and the conversions users get wrong (4000 vs 4096 ticks:
    # -2.3 %) to +-10 %; the hard limit a fit may widen to holds a 1:2 stage (0.5, 2) and more.
    params = (Param("scale", 1.0, 0.9, 1.1, "1", (0.995, 1.005), limit=(0.4, 2.5),
                    doc="reading per radian of joint angle"),)

    @classmethod
    def observe(cls, t: Targets, v: Values, q: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
        return q * np.asarray(v["scale"], float)


READING = {"position_offset": "offset", "mounting_offset": "offset", "sensor_scale": "scale"}


def reading_map(effects: Sequence[Any], joints: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """How applied effects (``AppliedEffect``s) map a joint angle q to its reading, per joint of
    ``joints``: reading = scale q + offset (the position and mounting offsets summed, the sensor
    scales multiplied); a replay starts a window from the angle (reading - offset) / scale.

    Returns:
      (offset [rad], scale [1]), each (len(joints),).
    """
    offset, scale = np.zeros(len(joints)), np.ones(len(joints))
    names = list(joints)
    for e in effects:
        if e.name not in READING:
            continue
        for j, v in zip(e.joints, e.values[READING[e.name]], strict=True):
            if j in names and e.name == "sensor_scale":
                scale[names.index(j)] *= v
            elif j in names:
                offset[names.index(j)] += v
    return offset, scale
