"""A user's model written at a coarse physics step, logs from a robot in continuous time.

A real robot is not discretised; a user's MJCF is, at whatever step its author chose (1-2 ms
is common), and that discretisation is a model error of its own. ``tests/gap_truth_sim.py``
simulates the truth with steps of at most 0.25 ms (``truth_step``) while the nominal model keeps
its 2 ms. Measured 2026-11-26 on the clean bench (seed 401): the nominal replay is 2.13 mrad
off at 2 ms, 1.06 at 1 ms, 0.66 at 0.5 ms, 0.59 at 0.25 ms (read-noise floor 0.535); the
analysis named a viscous damping of 0.0057 N m s/rad (held-out 2.44 -> 0.75 mrad) for data
with no hidden effect. With ``GapConfig.refine_step`` it analyses at 0.25 ms and finds no
significant discrepancy (44 s at load 17). Redteam's clean pendulum (0.25 ms truth, 2 ms model,
floor 0.70): 1.79 / 1.13 / 0.90 / 0.83 mrad at 2 / 1 / 0.5 / 0.25 ms; a viscous damping of
0.002 was named at 2 ms and 0.0011 at 1 ms (a first version stopped there: the predictions
moved less than the floor). On the independent cases' own 2 ms world a finer step moves the
nominal replay away from the data (clean bench 0.61 -> 1.24 mrad) and the step is kept.
"""

from __future__ import annotations

import gap_truth_sim as ts
import numpy as np
import pytest

FINE = 2.5e-4  # [s] the truth's physics step: continuous time for these rigs


def _data(tmp_path, names=(), seed=401, truth_step=FINE):
    from lowcostdex.gap import load_dataset
    from lowcostdex.gap.dataset import episodes

    case = ts.make_case("bench", list(names), seed, duration=5.0, truth_step=truth_step)
    model, paths = case.write(tmp_path)
    ds = load_dataset(paths, model=model)
    return case, ds, episodes(ds)


def test_a_coarse_model_step_is_refined_until_the_replay_stops_improving(tmp_path):
    from lowcostdex.gap import GapConfig
    from lowcostdex.gap.analyze import _refine_step

    _, ds, eps = _data(tmp_path)
    fine, rec = _refine_step(ds, eps, GapConfig())
    steps = [dt for dt, _ in rec["rmse"]]
    rmse = [r for _, r in rec["rmse"]]
    assert rec["model"] == pytest.approx(ts.TIMESTEP)
    assert steps[:2] == pytest.approx([ts.TIMESTEP, ts.TIMESTEP / 2])
    assert rmse[0] > 3 * ts.FLOOR  # the 2 ms discretisation is visible in the data
    assert rec["used"] < ts.TIMESTEP and fine.timestep == pytest.approx(rec["used"])
    assert rmse[steps.index(rec["used"])] < 1.3 * ts.FLOOR
    assert np.all(np.diff(rmse) < 0)
    # the refined data set shares the logs; only the models' step changed
    assert fine.trajectories is ds.trajectories


def test_the_step_is_kept_when_the_data_come_from_it(tmp_path):
    """The independent cases' truth steps at most 2 ms (events split the steps): a finer replay
    is farther from their data and the model's step stays."""
    from lowcostdex.gap import GapConfig
    from lowcostdex.gap.analyze import _refine_step

    for names, seed in (((), 401), (("coulomb_friction",), 106)):
        _, ds, eps = _data(tmp_path / str(seed), names, seed, truth_step=ts.TIMESTEP)
        fine, rec = _refine_step(ds, eps, GapConfig())
        assert rec["used"] == rec["model"] == fine.timestep, rec
    with pytest.raises(Exception, match="refine_gain"):
        GapConfig(refine_gain=0.0)


@pytest.mark.slow
def test_clean_continuous_time_data_give_no_discrepancy(tmp_path):
    """44 s at load 17. Without the refinement: viscous_damping 0.0057 named on clean data."""
    from lowcostdex.gap import GapConfig, analyze, report

    _, ds, _ = _data(tmp_path)
    res = analyze(ds, GapConfig(seed=0))
    assert not res.causes, [(c.effect, c.params) for c in res.causes]
    assert res.verdict == "no significant discrepancy"
    assert res.timestep["used"] < ts.TIMESTEP
    assert "Physics step: the model's physics step 2 ms is too coarse" in report.markdown(res)
    assert f'timestep="{res.timestep["used"]:g}"' in next(iter(res.models.values()))


@pytest.mark.parametrize("truth_step", [FINE, ts.TIMESTEP])
def test_a_large_cause_hides_the_step_error_until_it_is_fitted(tmp_path, truth_step):
    """A 50 ms latency dominates the nominal replay, so the nominal test keeps the 2 ms step
    even on continuous-time data; with the latency fitted at each step (``refine_fitted``) the
    finer step pays on them, and does not on data that come from the model's own step."""
    from lowcostdex.gap import GapConfig
    from lowcostdex.gap import fit as fitmod
    from lowcostdex.gap.analyze import _Engine, _refine_step
    from lowcostdex.gap.dataset import segments
    from lowcostdex.gap.diagnostics import noise_floor
    from lowcostdex.gap.stepsize import refine_fitted

    case = ts.make_case("bench", ["latency"], 401, duration=5.0, values={"latency": 0.05},
                        truth_step=truth_step)
    model, paths = case.write(tmp_path)
    from lowcostdex.gap import load_dataset
    from lowcostdex.gap.dataset import episodes
    ds = load_dataset(paths, model=model)
    cfg = GapConfig()
    eps = episodes(ds)
    kept, rec = _refine_step(ds, eps, cfg)
    assert rec["used"] == ts.TIMESTEP, rec          # hidden behind the latency
    segs = segments(ds, eps, cfg.segment, cfg.burn_in)
    n = len(ds.effect_joints)
    ctx = fitmod.Context(dt=ds.timestep, peak_force=np.full(n, np.inf), stall=np.full(n, np.inf),
                         damping=np.zeros(n))
    st = fitmod.Structure.build(("latency",), ds.effect_joints, ctx)
    fn = _Engine(ds, cfg, ["latency"]).residual_fn(segs)
    t = fitmod.Track(st, st.u(np.full(st.n, 0.04)))
    fitmod.lockstep_lm([t], fn, cfg.max_rounds, jacobian_at_end=False)
    fitmod.polish(t, fn, ds.timestep)
    floor_mse = float(np.mean(noise_floor(ds.trajectories) ** 2))
    out = refine_fitted(ds, lambda d: _Engine(d, cfg, ["latency"]).residual_fn(segs), st, t.x,
                        ctx, cfg, floor_mse)
    if truth_step == ts.TIMESTEP:
        assert out is None
        return
    assert out is not None
    fine, fctx, fst, fx, tried = out
    assert fine.timestep < ts.TIMESTEP and fctx.dt == fine.timestep
    rms = dict(tried)
    assert rms[fine.timestep] < 0.8 * rms[ts.TIMESTEP]
    assert np.abs(fx - 0.05).max() < np.abs(t.x - 0.05).max() + 1e-4
