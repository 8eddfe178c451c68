"""A mounting offset per bench set-up (``gap.setup_offsets``, identify's last stage), on logs of
the BAM-model truth (tests/gap_bam_truth.py: plain numpy, BAM's published STS3215 M1 fit, no
project code), whose two benches hang at their own angles (an arm re-mounted between set-ups).

The project model the stage starts from carries the truth's own numbers, typed from the truth
module (Coulomb ``friction_base``, viscous ``friction_viscous``, the motor's gravity offset with
the project's sign: the truth's gravity zero at -q_offset is a reading offset of +q_offset's
opposite), as a fit that found them would; the stage moves only the offset. Measured
2026-11-28 (lead, session 24): benches +0.05 / -0.05 rad -> -0.048 / +0.052 fitted, held-out
kp 8 logs 34.9 -> 28.4 mrad (28.5 with the true benches' common offset); 2.5 s CPU."""

from __future__ import annotations

import gap_bam_truth as truth
import numpy as np
import pytest

from lowcostdex.gap import bam_measure as bm
from lowcostdex.gap import setup_offsets
from lowcostdex.gap.dataset import load_dataset
from lowcostdex.gap.identify import servo_structure
from lowcostdex.gap.replay import Replayer
from lowcostdex.sim.effects import AppliedEffect

MOTOR = truth.MOTORS["sts3215"]


def _set(folder, offsets):
    """The STS3215 truth's two benches hung at ``offsets`` [rad], kp 8 and 32, all four
    trajectories; (dataset, kp-32 logs, kp-8 logs, replayer, the truth-valued effects)."""
    benches = tuple(truth.Bench(b.mass, b.length, b.arm_mass, o)
                    for b, o in zip(truth.STS3215_BENCHES, offsets, strict=True))
    truth.write_set("sts3215", folder, seed=0, kps=(8, 32), benches=benches)
    ds = bm.grid_dataset(load_dataset(sorted(folder.glob("*.json")), timestep=bm.BAM_DT))
    kp = [t.meta["kp"] for t in ds.trajectories]
    structure = servo_structure(ds)
    values = {"coulomb_friction": {"frictionloss": MOTOR.friction_base},
              "viscous_damping": {"damping": MOTOR.friction_viscous},
              "backdriven_friction": {"joint": 1.0},  # the truth's friction acts torque off too
              "mounting_offset": {"offset": -MOTOR.q_offset}}
    effects = [AppliedEffect(e, ("arm",), values.get(e, {})) for e in structure]
    return (ds, [i for i, k in enumerate(kp) if k == 32], [i for i, k in enumerate(kp) if k == 8],
            Replayer(ds, structure, nthread=1), effects)


def _by_mass(offsets):
    """{bench mass [kg]: offset} of ``fit``'s {set-up: offset}."""
    return {float(k.split("mass ")[1].split(" kg")[0]): v for k, v in offsets.items()}


def test_each_re_mounted_bench_gets_its_own_hanging_angle(tmp_path):
    ds, train, test, rep, effects = _set(tmp_path, (0.05, -0.05))
    fitted = setup_offsets.fit(ds, train, rep, effects)
    found = _by_mass(fitted)
    # the truth's gravity angle q + offset is the project's reading offset's opposite
    assert found == {0.2: pytest.approx(-0.05, abs=0.008), 0.4: pytest.approx(0.05, abs=0.008)}
    common = setup_offsets.scored(ds, test, rep, [effects], {})[0]
    own = setup_offsets.scored(ds, test, rep, [effects], fitted)[0]
    drops = [k for k, i in enumerate(test) if ds.trajectories[i].meta["trajectory"]
             == "lift_and_drop"]
    assert own.mean() < 0.9 * common.mean()  # measured 28.4 vs 34.9 mrad
    assert np.all(own[drops] < common[drops])  # the held-out swings hang where they do
    # the nominal model (no effects) stays as it was: an empty column has no offset to move
    assert np.array_equal(setup_offsets.scored(ds, test, rep, [[]], {"x": 0.1}),
                          setup_offsets.scored(ds, test, rep, [[]], {}))


def test_benches_hung_alike_get_no_offsets_of_their_own(tmp_path):
    ds, train, _, rep, effects = _set(tmp_path, (0.0, 0.0))
    assert setup_offsets.fit(ds, train, rep, effects) == {}


def test_torque_on_logs_alone_set_no_offsets(tmp_path):
    """Without the torque off the offset trades against the drive's gravity load (on the real
    STS3032 such offsets made 6 of 9 set-ups' held-out swings worse): none is fitted."""
    ds, train, _, rep, effects = _set(tmp_path, (0.05, -0.05))
    on = [i for i in train if ds.trajectories[i].meta["trajectory"] != "lift_and_drop"]
    assert setup_offsets.fit(ds, on, rep, effects) == {}


def test_a_log_without_a_bench_header_has_no_set_up():
    assert setup_offsets.setup_key({"trajectory": "sin_sin"}) is None
    assert setup_offsets.setup_key({"motor": "sts3032", "mass": 0.457, "length": 0.07}) == (
        "sts3032: mass 0.457 kg, length 0.07 m")
