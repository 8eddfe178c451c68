"""A play whose servo reads its position AND its damping on the output shaft (issue 11, sim2).

A Dynamixel's encoder sits behind the gearbox: its P-D loop reads the output, so with a gear play
the motor side hunts inside the play while the D term damps the OUTPUT's rate. A model's joint
damping beside a plain ``position`` actuator (kp only) is that D term. The truth here is the
second truth simulator's ``backlash_output`` (``tests/gap_truth_sim2.py``, written without the
analyzer's effect code: its own P-D loop on a ``motor`` actuator, the nominal joint damping on the
output rate outside the force range, 0.25 ms physics). Replayed through the catalogue's play at
the true width with the loop on the output (``sensor`` 1), the model must land at the noise; until
session 15 the catalogue kept the joint damping on the rotor's rate and the replay at the true
width was worse than the nominal model (12.6-15.4 vs 6.4-7.7 mrad per episode at 2 ms).
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

from lowcostdex.gap.dataset import episodes, load_dataset
from lowcostdex.gap.replay import Replayer
from lowcostdex.sim.effects import AppliedEffect

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import gap_truth_sim2 as sim  # noqa: E402

WIDTH = 2.5 * sim.DEG  # the truth's full play [rad]


def _replay(tmp_path, effects, fac=0.5, widths=(WIDTH,), sensor=1.0):
    """Per-episode RMS [rad] of the nominal model and of the play at each width, replayed at
    ``fac`` x the model's 2 ms step."""
    case = sim.Case("c", "pendulum", effects, 100, (8.0,), ("steps",), seed=15)
    files = sim.write_case(case, tmp_path)
    ds = load_dataset(files["logs"], model=files["model"]).with_timestep(fac)
    eps = episodes(ds)
    extra = [AppliedEffect("viscous_damping", ds.effect_joints, {"damping": np.array([e.value])})
             for e in effects if e.kind == "viscous_mj"]
    cols = [extra] + [[AppliedEffect("backlash", ds.effect_joints,
                                     {"width": np.array([w]), "sensor": np.array([sensor])})]
                      + extra for w in widths]
    pred = Replayer(ds, ["backlash", "viscous_damping"], nthread=1).run(eps, cols)[0]
    q = ds.trajectories[0].qpos
    return [np.array([np.sqrt(np.mean((q[w.start:w.stop] - p) ** 2)) for w, p in zip(eps, col, strict=True)])
            for col in pred]


def test_output_loop_play_replays_at_the_noise_at_its_true_width(tmp_path):
    nominal, true, narrow = _replay(tmp_path, (sim.Effect("backlash_output", WIDTH),),
                                    widths=(WIDTH, 0.6 * WIDTH))
    # read noise 0.6 mrad + 1.5 mrad ticks: ~0.7 mrad RMS is the floor
    assert np.all(true < 2.0e-3), true
    assert np.all(true < 0.4 * nominal), (true, nominal)
    # the true width beats a narrower play on every episode that moves (the fit can find it)
    moving = nominal > 2e-3
    assert np.all(true[moving] < narrow[moving]), (true, narrow)


def test_hidden_damping_stays_on_the_motor_side(tmp_path):
    """The same play with 0.25 N m s/rad more damping on the truth's motor joint: the catalogue's
    ``viscous_damping`` (a gearbox loss, the rotor's rate) beside the play replays it at the
    noise too, while the nominal joint damping keeps reading the output."""
    _, true = _replay(tmp_path, (sim.Effect("backlash_output", WIDTH),
                                 sim.Effect("viscous_mj", 0.25)))
    assert np.all(true < 2.0e-3), true
