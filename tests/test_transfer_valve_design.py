"""The valve log's episode designs and condition (d)'s per-episode valve (issue 14, transfer17).

Truth: goal sequences written out in this test; a valve hinge written in a plain MJCF here
(damping b, dry friction F, pulled through a spring: a position actuator of stiffness k to a
moving goal) whose steady lag is (b v + F) / k, so one goal speed sees only b v + F and two speeds
separate b and F; the D'Claw's nominal valve damping read from the compiled model with plain
MuJoCo indexing.
"""

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from scipy.optimize import least_squares

import lowcostdex.sim  # noqa: F401  (registers the ids)
from lowcostdex.errors import ConfigError
from lowcostdex.hands import dclaw_spec
from lowcostdex.sim.vector import make_vec
from lowcostdex.transfer import valve_fit
from lowcostdex.transfer.valve_fit import DESIGNS, design, randomized_valve, valve_ranges

ID = "lowcostdex/DClawTurnValve-v0"


def test_designs_play_the_goals_as_written_here():
    a = np.arange(10, dtype=float)[:, None] * np.array([[1.0, -1.0]])  # 10 steps, 2 joints
    assert DESIGNS[0] == "playback" and len(DESIGNS) == 5
    np.testing.assert_array_equal(design(a, "playback"), a)
    fast = design(a, "fast")
    np.testing.assert_array_equal(fast[:, 0], [0, 2, 4, 6, 8, 8, 8, 8, 8, 8])
    slow = design(a, "slow")
    np.testing.assert_array_equal(slow[:, 0], [0, 0.5, 1, 1.5, 2, 2.5, 3, 3.5, 4, 4.5, 5, 5.5,
                                               6, 6.5, 7, 7.5, 8, 8.5, 9, 9])
    np.testing.assert_array_equal(slow[:, 1], -slow[:, 0])
    stop = design(a, "stop_and_go")
    np.testing.assert_array_equal(stop[:, 0], [0, 1, 2, 3, 4, 4, 4, 4, 5, 6, 7, 8, 9, 9, 9, 9])
    np.testing.assert_array_equal(design(a, "twice")[:, 0], [*range(10), *range(10)])
    with pytest.raises(ConfigError, match="playback"):
        design(a, "backwards")


XML = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <body name="valve">
      <joint name="valve" type="hinge" axis="0 0 1" damping="{b}" frictionloss="{f}"/>
      <geom type="cylinder" size="0.04 0.005" mass="0.05"/>
    </body>
  </worldbody>
  <actuator><position joint="valve" kp="0.5"/></actuator>
</mujoco>
"""


def valve_angle(params, goals):
    """The valve angle every 0.1 s, each goal held 0.1 s; params = (damping b [N m s/rad],
    dry friction F [N m])."""
    model = mujoco.MjModel.from_xml_string(XML.format(b=params[0], f=params[1]))
    data = mujoco.MjData(model)
    out = []
    for g in goals:
        data.ctrl[0] = g
        for _ in range(50):
            mujoco.mj_step(model, data)
        out.append(data.qpos[0])
    return np.asarray(out)


def test_the_varied_designs_separate_the_valve_damping_from_its_friction():
    """One push speed sees b v + F; the designs' speeds and stops tell b from F."""
    push = np.minimum(np.arange(40) * 0.08, 2.4)[:, None]  # a 0.8 rad/s push, then held
    truth = np.array([0.05, 0.02])
    one = [push[:, 0]] * 2  # two playbacks: near-duplicates
    varied = [design(push, d)[:, 0] for d in DESIGNS]

    def fit(episodes):
        observed = np.concatenate([valve_angle(truth, g) for g in episodes])
        res = least_squares(lambda p: np.concatenate(
            [valve_angle(p, g) for g in episodes]) - observed, x0=[0.1, 0.0],
            bounds=([0.0, 0.0], [1.0, 0.2]), diff_step=1e-3)
        jac = res.jac / np.linalg.norm(res.jac, axis=0)
        return res.x, np.linalg.svd(jac, compute_uv=False)

    x_one, s_one = fit(one)
    x_var, s_var = fit(varied)
    np.testing.assert_allclose(x_var, truth, rtol=0.05)
    # the smallest singular value of the normalized Jacobian: how well b and F are told apart
    assert s_var[-1] > 3 * s_one[-1], (s_one, s_var)


FIT = {"used_finger": "th", "fits": [{
    "finger": "th", "values": [-0.1, 0.02, 0.003, 1.1, 1.05, 1.0, 1.0, 1.0],
    "intervals": [[-0.11, -0.09], [0.01, 0.03], [0.002, 0.005], [1.0, 1.2], [1.0, 1.1],
                  [1.0, 1.0], [1.0, 1.0], [1.0, 1.0]]}]}
FIT["model_edit"] = valve_fit.edit_from_params("th", FIT["fits"][0]["values"]).to_dict()
GAIN = {"effects": ["gain_error"], "joints": list(dclaw_spec().joint_names),
        "ranges": {"gain_error": {"scale": [[1.1] * 9, [1.1] * 9]}}}


def nominal_valve_damping():
    m = mujoco.MjSpec.from_string(gym.make(ID).unwrapped.task.build_spec().to_xml()).compile()
    return float(m.dof_damping[m.joint("valve").dofadr[0]])


def test_valve_ranges_are_the_fit_intervals_at_least_the_pad():
    r = valve_ranges(FIT)
    pad = valve_fit.VALVE_PAD
    assert r["valve_frictionloss"] == pytest.approx((min(0.002, 0.003 * (1 - pad)),
                                                     max(0.005, 0.003 * (1 + pad))))
    assert r["valve_damping"] == pytest.approx((min(1.0, 1.1 * (1 - pad)),
                                                max(1.2, 1.1 * (1 + pad))))


def test_a_collapsed_valve_range_is_the_fitted_model_bitwise(monkeypatch):
    """The valve joint added to the randomization at its null changes nothing."""
    collapsed = {**FIT, "fits": [{**FIT["fits"][0], "intervals": [
        [v, v] for v in FIT["fits"][0]["values"]]}]}
    monkeypatch.setattr(valve_fit, "VALVE_PAD", 0.0)
    dr, edit = randomized_valve(GAIN, collapsed, nominal_valve_damping())
    assert dr["joints"][-1] == "valve" and edit == FIT["model_edit"]
    goals = np.tile(np.linspace(-0.5, 0.5, 9), (20, 1)) * np.linspace(0, 1, 20)[:, None]
    eps = [(0, goals), (1, goals[::-1])]
    a = valve_fit.valve_trace(ID, {"randomize": GAIN, "model_edit": FIT["model_edit"]}, eps)
    b = valve_fit.valve_trace(ID, {"randomize": dr, "model_edit": edit}, eps)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("randomize", [GAIN, None], ids=["with_servo_effects", "valve_only"])
def test_the_valve_is_drawn_per_episode_within_its_ranges(randomize):
    d0 = nominal_valve_damping()
    dr, edit = randomized_valve(randomize, FIT, d0)
    (fl_lo, fl_hi), (k_lo, k_hi) = valve_ranges(FIT).values()
    env = gym.make(ID, randomize=dr, model_edit=edit).unwrapped
    spec = mujoco.MjSpec.from_string(gym.make(ID).unwrapped.task.build_spec().to_xml())
    fl0 = float(spec.compile().dof_frictionloss[spec.compile().joint("valve").dofadr[0]])
    dof = env.model.joint("valve").dofadr[0]
    fl, damp = [], []
    for seed in range(12):
        env.reset(seed=seed)
        fl.append(env.model.dof_frictionloss[dof] - fl0)
        damp.append(env.model.dof_damping[dof] / d0)
        if randomize is not None:  # the servo effects still act on the hand joints
            gain = {e.name: e for e in env.backend.plant.effects}["gain_error"]
            np.testing.assert_allclose(gain.values["scale"][:9], 1.1)
    assert fl_lo - 1e-12 <= min(fl) < max(fl) <= fl_hi + 1e-12
    assert k_lo - 1e-9 <= min(damp) < max(damp) <= k_hi + 1e-9
    assert max(fl) - min(fl) > 0.5 * (fl_hi - fl_lo)
    # the batched training envs draw each copy's valve
    vec = make_vec(ID, 4, nthread=1, randomize=dr, model_edit=edit)
    vec.reset(seed=0)
    per_copy = vec.plant.array("dof_frictionloss")[:, dof] - fl0
    assert len(set(np.round(per_copy, 12))) == 4
    assert np.all((per_copy >= fl_lo - 1e-12) & (per_copy <= fl_hi + 1e-12))
    vec.close()
