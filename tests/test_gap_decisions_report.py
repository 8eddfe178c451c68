"""What a user reads of the gap analysis besides its verdict: the public entry point's errors,
the settings' error messages, the report's physics-step line, a delay at its floor, the
report.json keys. Every expected string is written out here; no MuJoCo replay."""

from __future__ import annotations

import importlib
import json
import math

import numpy as np
import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.dataset import Dataset, Split, Window
from lowcostdex.gap.gain import Gain
from lowcostdex.gap.results import (
    Cause,
    GapConfig,
    GapResult,
    _ep,
    param_report,
    timestep_note,
)
from lowcostdex.gap.trajectory import Trajectory

AZ = importlib.import_module("lowcostdex.gap.analyze")

# a user's own model: one hinge, a plain position actuator
MJCF = """<mujoco><option timestep="0.002"/><worldbody><body><joint name="j0" type="hinge"/>
<geom type="capsule" size="0.01 0.05" mass="0.1"/></body></worldbody>
<actuator><position name="a0" joint="j0" kp="2"/></actuator></mujoco>"""


def _dataset():
    t = np.arange(50) * 0.01
    q = 0.1 * np.sin(2 * np.pi * t)[:, None]
    return Dataset({"model": MJCF}, [Trajectory("log0.csv", t, q.copy(), q.copy(), ("a0",),
                                                ("j0",))], ["log0.csv"])


def test_analyze_refuses_what_is_not_a_dataset_or_config_and_fills_in_defaults(monkeypatch):
    with pytest.raises(TypeError) as e:
        AZ.analyze(["log_0.csv"])
    assert str(e.value) == ("analyze takes a Dataset, not list: read the logs first, e.g. "
                            "analyze(load_dataset(['log_0.csv', ...], model='model.xml'))")
    ds = _dataset()
    with pytest.raises(TypeError) as e:
        AZ.analyze(ds, {"seed": 1})
    assert str(e.value) == "config must be a GapConfig, not dict"
    calls = []

    class _Res:
        mujoco_warnings = None

    def fake(d, cfg, prog):
        prog("stage", 0.5)  # a progress callback is always callable
        calls.append((d, cfg))
        return _Res()

    monkeypatch.setattr(AZ, "_analyze", fake)
    res = AZ.analyze(ds)
    ((d, cfg),) = calls
    assert d is ds and cfg == GapConfig()
    assert res.mujoco_warnings == {}  # counted (none here), not left unset
    mine, seen = GapConfig(seed=3), []
    AZ.analyze(ds, mine, progress=lambda s, f: seen.append((s, f)))
    assert calls[-1][1] is mine and seen == [("stage", 0.5)]


@pytest.mark.parametrize("kw, message", [
    (dict(probes=(0.5, 1.0)), "probes entry=1.0 must be a finite number in [0, 1)"),
    (dict(probes=(-0.1,)), "probes entry=-0.1 must be a finite number in [0, 1)"),
    (dict(probes="0.1"), "probes='0.1' must be a tuple of fractions of a physics step in "
                         "[0, 1), e.g. (0.01, 0.02)"),
    (dict(test_logs=(-1,)), "test_logs entry=-1 must be an integer in [0, inf)"),
    (dict(test_logs="0"), "test_logs='0' must be a tuple of log indices (0-based, in the order "
                          "given) or None"),
    (dict(tie=1.0), "tie=1.0 must be a finite number in [0, 1)"),
    (dict(chunk=0.0), "chunk=0.0 must be a finite number in (0, inf) or None"),
    (dict(candidates=("latncy",)), "unknown candidate effect 'latncy'; valid choices: "
     "'latency', 'backlash', 'coulomb_friction', 'stribeck_friction', "
     "'load_dependent_friction', 'viscous_damping', 'gain_error', 'torque_limit', "
     "'velocity_limit', 'position_offset', 'inertia_error', 'mass_error', "
     "'thermal_derating', 'voltage_sag', 'gearbox_friction', 'mounting_offset', "
     "'motor_strength', 'deadband', 'sensor_scale', 'goal_profile'; did you mean 'latency'?"),
    (dict(candidates="latency"), "candidates='latency' must be a tuple of effect names, e.g. "
     "('latency',), or None; valid names: latency, backlash, coulomb_friction, "
     "stribeck_friction, load_dependent_friction, viscous_damping, gain_error, torque_limit, "
     "velocity_limit, position_offset, inertia_error, mass_error, thermal_derating, "
     "voltage_sag, gearbox_friction, mounting_offset, motor_strength, deadband, sensor_scale, "
     "goal_profile"),
    (dict(candidates={"latency"}), "candidates={'latency'} must be a tuple of effect names, "
     "e.g. ('latency',), or None; valid names: latency, backlash, coulomb_friction, "
     "stribeck_friction, load_dependent_friction, viscous_damping, gain_error, torque_limit, "
     "velocity_limit, position_offset, inertia_error, mass_error, thermal_derating, "
     "voltage_sag, gearbox_friction, mounting_offset, motor_strength, deadband, sensor_scale, "
     "goal_profile"),
    (dict(min_gain=1.0), "min_gain must be in (0, 1)"),
    (dict(search="back"), "unknown search 'back'; valid choices: 'forward', 'both'"),
    (dict(burn_in=-1.0), "segment must be > 0 s and burn_in >= 0 s"),
    (dict(interval_block=0.0), "interval_block must be > 0 s"),
    (dict(interval_step=1.0), "interval_step must be in [0, 1) (a fraction of the physics "
                              "step; 0: off), got 1.0"),
])
def test_a_bad_setting_is_named_with_what_is_valid(kw, message):
    with pytest.raises(ConfigError) as e:
        GapConfig(**kw)
    assert str(e.value) == message


def test_the_physics_step_line_of_the_report():
    assert timestep_note({}) == ""
    assert timestep_note({"model": 0.002, "used": 0.002, "rmse": [(0.002, 0.01)]}) == ""
    ts = {"model": 0.002, "used": 0.001, "rmse": [(0.002, 0.0123), (0.001, 0.0041)]}
    base = ("the model's physics step 2 ms is too coarse for these logs (nominal replay RMSE on "
            "train + select: 2 ms 12.3 mrad, 1 ms 4.1 mrad{}); analysed at 1 ms, which the "
            "extended model carries")
    assert timestep_note(ts) == base.format("")
    ts.update(fitted=[(0.002, 0.0052), (0.001, 0.0017)], first_at_coarse_step="latency")
    assert timestep_note(ts) == base.format(
        "; with the accepted causes refitted, training RMSE: 2 ms 5.2 mrad, 1 ms 1.7 mrad; the "
        "first cause, latency at the model's step, was chosen again at the finer one")


def test_a_delay_at_its_floor_is_reported_as_no_delay():
    """A delay fitted at its lower bound (one physics step, 2 ms) is replayed as no delay: the
    report says 0 s with an interval from 0 to the interval's top (2 + 1 ms); a delay above
    it is reported as fitted (20 +- 1 ms)."""
    ctx = fitmod.Context(dt=0.002, peak_force=np.array([1.0, 1.0]),
                         stall=np.array([math.inf, math.inf]), damping=np.array([0.1, 0.1]))
    s = fitmod.Structure.build(("latency",), ("j0", "j1"), ctx)
    d = param_report(s, np.array([0.002, 0.02]), np.array([0.001, 0.001]), "latency")
    assert d["delay"]["value"] == [0.0, pytest.approx(0.02)]
    assert d["delay"]["interval"][0] == [0.0, pytest.approx(0.003)]
    assert d["delay"]["interval"][1] == pytest.approx([0.019, 0.021])
    assert d["delay"]["unit"] == "s"


def test_the_report_json_keys_a_reader_looks_up():
    eps = [Window(0, 0, 10, 0), Window(3, 5, 9, 5)]
    assert _ep(eps[0], ["a.csv"]) == {"log": "a.csv", "start": 0, "stop": 10}
    # an episode of a log without a source name is named by its index
    assert _ep(eps[1], ["a.csv", "b.csv", "c.csv"]) == {"log": 3, "start": 5, "stop": 9}
    cause = Cause("position_offset", ("j0",), {}, heldout_rmse_after=0.002,
                  heldout_mae_after=0.0015)
    res = GapResult(GapConfig(probes=(0.01,)), ["a.csv"], ("j0", "j1"), Split((0,), (), ()),
                    eps, np.array([0.001, 0.002]), {}, {}, [cause], [], {"j0": {"lag": 0.01}},
                    Gain(0.01, 0.002, 0.01, 0.002, 0.008, 0.8, (0.0, 0.0), (0.0, 0.0), 0.001,
                         None, 2), [], "v", {}, [], {}, mujoco_warnings={"nan": 2})
    d = res.to_dict()
    d = json.loads(json.dumps(d))
    assert d["noise_floor"]["per_joint"] == {"j0": 0.001, "j1": 0.002}
    assert d["diagnostics"] == {"j0": {"lag": 0.01}}
    assert d["mujoco_warnings"] == {"nan": 2}
    assert d["config"]["probes"] == [0.01]
    assert d["causes"][0]["heldout_mae_after"] == 0.0015


MJCF2 = """<mujoco><option timestep="0.002"/><worldbody>
<body><joint name="j0" type="hinge"/><geom type="capsule" size="0.01 0.05" mass="0.1"/></body>
<body pos="0.2 0 0"><joint name="j1" type="hinge"/><geom type="capsule" size="0.01 0.05"
 mass="0.1"/></body></worldbody>
<actuator><position name="a0" joint="j0" kp="2"/><position name="a1" joint="j1" kp="2"/>
</actuator></mujoco>"""


def _dataset2():
    """Two joints, the log's actuator columns in the other order than the model's."""
    t = np.arange(40) * 0.01
    q = np.stack([np.arange(40.0), 100 + np.arange(40.0)], axis=1)
    return Dataset({"model": MJCF2}, [Trajectory("log0.csv", t, q.copy(), q.copy(),
                                                 ("a1", "a0"), ("j0", "j1"))], ["log0.csv"])


class _Replayer:
    """Stands in for the MuJoCo replay: column k predicts k everywhere."""

    made: list = []

    def __init__(self, ds, candidates, nthread=0):
        _Replayer.made.append((ds, list(candidates), nthread))
        self.asked = []

    def run(self, windows, columns, **kw):
        self.asked.append((list(windows), columns, kw))
        preds = [[np.full((w.stop - w.start, 2), float(k)) for w in windows]
                 for k in range(len(columns))]
        return preds, [np.zeros(2) for _ in columns]


def test_the_engine_scores_each_window_from_its_scored_sample(monkeypatch):
    """``_Engine``: the replay made for the candidates with the configured threads; residuals
    measured - predicted from each window's ``score_from`` on, windows one after the other,
    one vector per column; a residual function replays each (structure, values) point."""
    monkeypatch.setattr(AZ, "Replayer", _Replayer)
    _Replayer.made = []
    ds = _dataset2()
    eng = AZ._Engine(ds, GapConfig(nthread=3), ("position_offset",))
    assert _Replayer.made == [(ds, ["position_offset"], 3)] and eng.joints == ("j0", "j1")
    assert eng.ds is ds and eng.cfg.nthread == 3
    wins = [Window(0, 10, 20, 15), Window(0, 30, 40, 30)]
    q = ds.trajectories[0].qpos
    r0, r1 = eng.residuals(wins, [[], []])
    want = np.concatenate([q[15:20].ravel(), q[30:40].ravel()])
    np.testing.assert_array_equal(r0, want)
    np.testing.assert_array_equal(r1, want - 1.0)
    assert len(r0) == 2 * (5 + 10)
    p = eng.predict(wins, [[]])
    assert len(p) == 1 and [x.shape for x in p[0]] == [(10, 2), (10, 2)]
    s = fitmod.Structure.build(("position_offset",), ("j0", "j1"), fitmod.Context(
        dt=0.002, peak_force=np.ones(2), stall=np.full(2, math.inf), damping=np.zeros(2)))
    (r,) = eng.residual_fn(wins[:1])([(s, np.array([0.01, -0.02]))])
    np.testing.assert_array_equal(r, q[15:20].ravel())
    (col,) = eng.rep.asked[-1][1]
    assert col[0].name == "position_offset"
    assert col[0].values["offset"].tolist() == pytest.approx([0.01, -0.02])


def test_each_effect_joints_actuator_is_found_in_the_logs_columns():
    ds = _dataset2()
    m = ds.compiled("model")

    class T:
        actuators = np.array([0, 1])  # a0, a1 in the model

    assert AZ._act_cols(ds, T, m) == [1, 0]  # the log lists a1 first
    T.actuators = np.array([1])
    assert AZ._act_cols(ds, T, m) == [0]
