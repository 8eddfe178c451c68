"""DAPG's iterates validated in the simulation the gap stage identified (issue 13 items 2-3):
``main_job.gapsim.identified_randomization``, ``TrainConfig.eval_env_kwargs``,
``main_job.stages.validation_sim`` and the report's words.

Truths: the identified values are typed into a hand-made extended model here (the gap stage's
output format, ``gap.extension.save_extended``); "validation in its own env does not change what
is learned" is checked against a second run without it; "the validation ran in that env" against
the same policy evaluated by hand in an env made by ``gym.make`` with those keyword arguments.
"""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest

import lowcostdex  # noqa: F401  (registers the envs)
from lowcostdex.algos import experiment as ex
from lowcostdex.algos.policy import PolicyConfig
from lowcostdex.algos.train import TrainConfig, load_policy, train
from lowcostdex.errors import ConfigError
from lowcostdex.gap.extension import save_extended
from lowcostdex.hands import dclaw_spec
from lowcostdex.main_job import STAGES
from lowcostdex.main_job.gapsim import GAP_EXTENDED, identified_randomization, validation_sim
from lowcostdex.main_job.report import _validated_in_words
from lowcostdex.main_job.setup import Context
from lowcostdex.sim.effects import AppliedEffect, DomainRandomization

FF = ("ff_top", "ff_middle", "ff_bottom")
DELAY = [0.0118, 0.0120, 0.0122]  # [s], one per first-finger joint (typed in)
WIDTH = [0.018, 0.017, 0.019]  # [rad]
FRICTION = [0.044, 0.048, 0.049]  # [N m]


def _extended(folder, effects=None):
    if effects is None:
        effects = [AppliedEffect("latency", FF, {"delay": DELAY}),
                   AppliedEffect("backlash", FF, {"width": WIDTH, "sensor": [0.0] * 3}),
                   AppliedEffect("coulomb_friction", FF, {"frictionloss": FRICTION})]
    return save_extended(folder, {}, effects, None)


def test_every_joint_holds_the_value_identified_at_its_place_on_the_finger(tmp_path):
    _extended(tmp_path / "extended")
    joints = dclaw_spec().joint_names
    dr = identified_randomization(tmp_path / "extended", joints, spread=False)
    assert dr["effects"] == ["latency", "backlash", "coulomb_friction"]
    assert dr["joints"] == list(joints)
    # ff_top, mf_top and th_top take the first value, *_middle the second, *_bottom the third
    expect = {"latency": {"delay": DELAY}, "backlash": {"width": WIDTH},
              "coulomb_friction": {"frictionloss": FRICTION}}
    for name, params in expect.items():
        for p, values in params.items():
            lo, hi = dr["ranges"][name][p]
            assert lo == hi == values * 3, (name, p)
    # every other parameter is held at the value the model holds (its null): nothing is drawn
    # from the catalogue's ranges, so two draws with different generators agree exactly
    rand = DomainRandomization.from_dict(dr)
    a = rand.sample(np.random.default_rng(1))
    b = rand.sample(np.random.default_rng(2))
    assert [e.name for e in a] == ["latency", "backlash", "coulomb_friction"]
    for ea, eb in zip(a, b, strict=True):
        assert ea.joints == tuple(joints)
        for p in ea.values:
            np.testing.assert_array_equal(ea.values[p], eb.values[p], err_msg=f"{ea.name}.{p}")
    friction = next(e for e in a if e.name == "coulomb_friction")
    np.testing.assert_array_equal(friction.values["frictionloss"], FRICTION * 3)
    np.testing.assert_array_equal(friction.values["asymmetry"], [0.0] * 9)


def test_by_default_each_parameter_is_drawn_from_its_fitted_range(tmp_path):
    # the gap stage's 95 % intervals, typed in; the rule (gap.extension.dr_ranges): the hull
    # over joints, widened to at least +-10 % of the largest value; a held parameter (an
    # unbounded interval) at its values' span
    effects = [AppliedEffect("latency", FF, {"delay": DELAY}),
               AppliedEffect("backlash", FF, {"width": WIDTH, "sensor": [0.0] * 3})]
    intervals = {"latency": {"delay": [[0.0110, 0.0125], [0.0115, 0.0124], [0.0119, 0.0126]]},
                 "backlash": {"width": [[0.0175, 0.0185], [0.0165, 0.0175], [0.0185, 0.0195]],
                              "sensor": [[-math.inf, math.inf]] * 3}}
    save_extended(tmp_path / "extended", {}, effects, intervals)
    joints = dclaw_spec().joint_names
    dr = identified_randomization(tmp_path / "extended", joints)
    assert dr["effects"] == ["latency", "backlash"] and dr["joints"] == list(joints)
    # latency: hull 0.0110-0.0126 s, values 0.0118-0.0122 -+ 0.00122: 0.01058-0.01342 s
    assert dr["ranges"]["latency"]["delay"] == pytest.approx([0.0118 - 0.00122, 0.0122 + 0.00122])
    # backlash: hull 0.0165-0.0195 rad, values 0.017-0.019 -+ 0.0019: 0.0151-0.0209 rad
    assert dr["ranges"]["backlash"]["width"] == pytest.approx([0.017 - 0.0019, 0.019 + 0.0019])
    assert dr["ranges"]["backlash"]["sensor"] == [0.0, 0.0]
    draws = [DomainRandomization.from_dict(dr).sample(np.random.default_rng(k)) for k in range(20)]
    delays = np.concatenate([d[0].values["delay"] for d in draws])
    assert 0.0118 - 0.00122 <= delays.min() < delays.max() <= 0.0122 + 0.00122
    assert np.all(np.concatenate([d[1].values["sensor"] for d in draws]) == 0.0)


def test_a_joint_at_no_identified_place_takes_the_mean(tmp_path):
    _extended(tmp_path / "extended", [AppliedEffect("latency", ("ff_top", "ff_middle"),
                                                    {"delay": [0.010, 0.014]})])
    dr = identified_randomization(tmp_path / "extended", ("ff_top", "ff_middle", "ff_bottom"),
                                  spread=False)
    lo, hi = dr["ranges"]["latency"]["delay"]
    assert lo == hi == pytest.approx([0.010, 0.014, 0.012])


def test_no_identified_effect_gives_no_validation_sim(tmp_path):
    save_extended(tmp_path / "extended", {}, [], {})
    assert identified_randomization(tmp_path / "extended", dclaw_spec().joint_names) is None
    with pytest.raises(ConfigError, match="effects.json"):
        identified_randomization(tmp_path / "nothing", dclaw_spec().joint_names)


def test_the_gap_stage_runs_before_train():
    order = [name for name, _ in STAGES]
    assert order.index("gap") < order.index("train")


def test_train_validates_in_the_gap_sim_only_when_the_gap_stage_finished(tmp_path):
    ctx = Context(out=tmp_path)
    v = validation_sim(ctx)
    assert v["sim"] == "training" and v["env_kwargs"] is None
    assert "gap stage has not run" in v["why"]
    assert "randomized simulation (the gap stage has not run" in _validated_in_words(
        {"validation_episodes": 100, "validated_in": v})
    # the gap stage's folder without its results (e.g. a stage that did not finish): the same
    _extended(tmp_path / GAP_EXTENDED)
    assert validation_sim(ctx)["sim"] == "training"
    ctx.results["gap"] = {"finished": "2026-11-27T19:00:00Z"}
    v = validation_sim(ctx)
    assert v["sim"] == "gap-identified"
    assert v["effects"] == ["latency", "backlash", "coulomb_friction"]
    kw = v["env_kwargs"]
    assert kw["goal_range"] == ctx.setup.env_overrides["goal_range"]
    assert kw["randomize"] == identified_randomization(tmp_path / GAP_EXTENDED,
                                                       dclaw_spec().joint_names)
    words = _validated_in_words({"validation_episodes": 100, "validated_in": v})
    assert "ran in another simulation" in words and "latency, backlash" in words
    # a gap stage that identified nothing: validated where it trained, and said so
    save_extended(tmp_path / GAP_EXTENDED, {}, [], {})
    v = validation_sim(ctx)
    assert v["sim"] == "training" and "identified no effect" in v["why"]


VALVE = "lowcostdex/DClawTurnValve-v0"


def _config(**kw):
    base = dict(algo="npg", env_id=VALVE, backend="sim", n_iter=3, n_traj=2, eval_every=2,
                eval_episodes=2, eval_paired=True, progress=False,
                policy=PolicyConfig(hidden_sizes=(8,), init_log_std=-1.0))
    base.update(kw)
    return TrainConfig(**base)


def _fixed(name, **values):
    """A randomization holding one effect at fixed values on every valve-station joint."""
    joints = list(dclaw_spec().joint_names)
    return {"effects": [name], "joints": joints,
            "ranges": {name: {p: [v, v] for p, v in values.items()}}}


def test_evaluations_in_their_own_env_leave_training_unchanged(tmp_path):
    # validation with a 60 ms command latency, which the training env does not have
    eval_kw = {"randomize": _fixed("latency", delay=0.06)}
    plain = train(_config(), tmp_path / "plain").read_metrics()
    run = train(_config(eval_env_kwargs=eval_kw), tmp_path / "own")
    own = run.read_metrics()
    for key in ("return_mean", "success_rate", "samples", "kl"):
        np.testing.assert_array_equal(plain[key], own[key], err_msg=key)
    evaluated = [k for k, v in enumerate(own["eval_return_mean"]) if math.isfinite(v)]
    assert evaluated == [1, 2]
    # the final evaluation is the final policy's on the evaluation episodes in the latency env,
    # as gym.make builds that env
    from lowcostdex.algos.samplers import EVAL_STREAM, make_jobs

    policy = load_policy(run.path / ex.FINAL_POLICY_FILE).snapshot()
    env = gym.make(VALVE, backend="sim", **eval_kw)
    try:
        returns = []
        for job in make_jobs(0, EVAL_STREAM, 0, 2, deterministic=True):
            obs, _ = env.reset(seed=job.env_seed())
            total, done = 0.0, False
            while not done:
                action = np.clip(policy.act(obs, None), env.action_space.low,
                                 env.action_space.high)
                obs, r, term, trunc, _ = env.step(action.astype(np.float32))
                total += float(r)
                done = term or trunc
            returns.append(total)
    finally:
        env.close()
    assert own["eval_return_mean"][2] == pytest.approx(np.mean(returns), rel=1e-9)
    assert own["eval_return_mean"][2] != pytest.approx(plain["eval_return_mean"][2], rel=1e-6)
    assert json.loads((run.path / "config.json").read_text())["eval_env_kwargs"] == eval_kw


@pytest.mark.parametrize("kw, match", [
    (dict(backend="emulated", sampler="serial"), "backend 'sim'"),
    (dict(eval_env_kwargs={"backend": "sim"}), "no 'backend' key"),
    (dict(eval_env_kwargs=["latency"]), "eval_env_kwargs|env_kwargs"),
])
def test_bad_evaluation_envs_are_refused(kw, match):
    base = {"eval_env_kwargs": {"randomize": _fixed("latency", delay=0.01)}}
    base.update(kw)
    with pytest.raises(ConfigError, match=match):
        _config(**base)
