"""Careless calls on the Python API (issue 13), session 15.

- A seed sweep written the numpy way, ``for seed in np.arange(3): train(TrainConfig(seed=seed),
  ...)``, or a discount read from a float32 array: before session 15 the config passed validation
  (a numpy integer is an integer) and ``train`` died in ``json.dumps`` with "Object of type int64
  is not JSON serializable". The run now writes the number the scalar holds, and resumes.
- A count given as a float (``n_iter=2.0``, a JSON config's ``1e3``): validation said "must be an
  integer" yet let 2.0 through, and the run died in ``range()`` after its folder was written. Now
  it is refused at construction, in one line naming the field.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from lowcostdex.algos.configs import BCConfig, NPGConfig, TrainConfig
from lowcostdex.algos.local_models.train_config import TVLGTrainConfig
from lowcostdex.algos.train import train
from lowcostdex.errors import ConfigError
from lowcostdex.gap import GapConfig
from lowcostdex.hardware.bus import BusError
from lowcostdex.sim.vector import make_vec

POINTMASS = "lowcostdex_test/PointMass-v0"


@pytest.fixture(scope="module", autouse=True)
def _pointmass():
    sys.path.insert(0, str(Path(__file__).parent))
    if POINTMASS not in gym.registry:
        gym.register(POINTMASS, entry_point="pointmass:PointMass", max_episode_steps=30)


def _tiny(**kwargs) -> TrainConfig:
    return TrainConfig(algo="npg", env_id=POINTMASS, n_traj=2, eval_every=1, eval_episodes=1,
                       progress=False, **kwargs)


def test_a_seed_sweep_over_np_arange_writes_plain_numbers_and_resumes(tmp_path):
    for seed in np.arange(2):  # numpy.int64 seeds, as a sweep is often written
        out = tmp_path / f"seed{seed}"
        train(_tiny(seed=seed, n_iter=1, gamma=np.float32(0.99)), out)
        config = json.loads((out / "config.json").read_text())
        assert config["seed"] == int(seed) and isinstance(config["seed"], int)
        assert config["gamma"] == pytest.approx(0.99, abs=1e-7)
    # the same numpy config resumes its run (the file's numbers compare equal to the scalars)
    run = train(_tiny(seed=np.int64(1), n_iter=2, gamma=np.float32(0.99)), tmp_path / "seed1",
                resume=True)
    assert list(run.read_metrics()["iteration"]) == [0, 1]


@pytest.mark.parametrize("make, message", [
    (lambda: TrainConfig(algo="npg", n_iter=2.0), "n_iter=2.0 must be an integer in [1, inf)"),
    (lambda: TrainConfig(algo="npg", n_traj=1e3), "n_traj=1000.0 must be an integer"),
    (lambda: TrainConfig(algo="npg", seed=0.0), "seed=0.0 must be an integer in [0, inf)"),
    (lambda: NPGConfig(cg_iters=10.0), "cg_iters=10.0 must be an integer"),
    (lambda: BCConfig(epochs=5.0), "BC epochs=5.0 must be an integer"),
    (lambda: TVLGTrainConfig(n_iter=3.0), "n_iter=3.0 must be an integer"),
    (lambda: GapConfig(max_effects=3.0), "max_effects=3.0 must be an integer"),
    (lambda: make_vec("lowcostdex/DClawTurnValve-v0", num_envs=2.0),
     "num_envs=2.0 must be an integer"),
], ids=["n_iter", "n_traj", "seed", "cg_iters", "bc_epochs", "tvlg_n_iter", "gap_max_effects",
        "num_envs"])
def test_a_count_given_as_a_float_is_refused_at_construction(make, message):
    with pytest.raises(ConfigError) as exc:
        make()
    assert message in str(exc.value)


def test_a_float_iteration_count_writes_no_run_folder(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(ConfigError, match="n_iter=2.0 must be an integer"):
        train(_tiny(n_iter=2.0), out)
    assert not out.exists()


def test_counts_as_numpy_integers_still_work(tmp_path):
    config = _tiny(n_iter=np.int64(1), seed=np.int32(0))
    assert train(config, tmp_path / "run").read_metrics()["iteration"].tolist() == [0]


# ------------------------------------------------------------------------------------------------
# the batched env, the Allegro's keywords, rendering, the CAN channel

VALVE = "lowcostdex/DClawTurnValve-v0"


def test_a_vector_env_stepped_before_reset_says_so():
    """Before session 15: KeyError 'angle' from inside the task's reward (no goal yet)."""
    vec = make_vec(VALVE, num_envs=2)
    with pytest.raises(gym.error.ResetNeeded, match=r"before reset\(\).*vec.reset\(seed=...\)"):
        vec.step(np.zeros((2, 9)))
    vec.reset(seed=0)
    assert vec.step(np.zeros((2, 9)))[0].shape == (2, 30)


@pytest.mark.parametrize("seed, message", [
    (-1, "reset seed=-1 must be an integer in [0, inf)"),      # was numpy's ValueError
    (1.5, "reset seed=1.5 must be an integer"),                # was SeedSequence's TypeError
    ([0], "got 1 seeds for 2 copies: give one seed per copy"),  # was IndexError
    ([0, 1, 2], "got 3 seeds for 2 copies"),                   # was silently cut to 2
])
def test_a_vector_env_reset_with_bad_seeds_names_them(seed, message):
    with pytest.raises(ConfigError) as exc:
        make_vec(VALVE, num_envs=2).reset(seed=seed)
    assert message in str(exc.value)


def test_a_motor_for_the_allegro_is_refused_without_listing_motor_as_valid():
    """The list of valid keywords named 'motor' while refusing it (the Allegro's motors are its
    own; ``motor=`` picks a D'Claw servo)."""
    with pytest.raises(ConfigError) as exc:
        gym.make("lowcostdex/AllegroTurnValve-v0", motor="XM430-W350")
    text = str(exc.value)
    assert "unknown keyword argument 'motor'" in text
    valid = text.split("valid: ")[1].split(", ")
    assert "motor" not in valid and "init_range" in valid
    # the D'Claw still lists and takes it
    assert gym.make(VALVE, motor="XM430-W350").unwrapped.task.hand.motor == "XM430-W350"


def test_rendering_without_an_opengl_context_names_mujoco_gl(monkeypatch):
    """A headless machine: MuJoCo's FatalError ('an OpenGL platform library has not been loaded')
    becomes one error naming the fix (MUJOCO_GL=egl or osmesa). The failure is made here by a
    renderer that cannot be created, as on a machine without a display."""
    import mujoco

    def no_context(*args, **kwargs):
        raise mujoco.FatalError("an OpenGL platform library has not been loaded into this "
                                "process")

    monkeypatch.setattr(mujoco, "Renderer", no_context)
    env = gym.make(VALVE, render_mode="rgb_array")
    env.reset(seed=0)
    with pytest.raises(ConfigError, match="MUJOCO_GL=egl .*MUJOCO_GL=osmesa"):
        env.render()


NO_CHANNEL = "lcdxnope9"  # no machine has this network interface


def test_an_allegro_on_a_can_channel_that_is_not_there_is_one_bus_error():
    """python-can raised a bare OSError ('[Errno 97] Address family not supported by protocol' on
    a kernel without SocketCAN, 'No such device' without the interface), naming neither the
    channel nor the fix."""
    from lowcostdex.hardware.allegro.driver import AllegroBus
    from lowcostdex.hardware.bus import BusError

    with pytest.raises(BusError, match=f"CAN channel '{NO_CHANNEL}'"):
        AllegroBus(channel=NO_CHANNEL).connect()


def test_record_log_on_a_missing_can_channel_is_one_line_and_writes_nothing(tmp_path, capsys):
    from lowcostdex.cli import main

    out = tmp_path / "allegro_logs"
    code = main(["record-log", "--hand", "allegro", "--port", NO_CHANNEL, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert err.strip().startswith(f"lowcostdex record-log: error: CAN channel '{NO_CHANNEL}'")
    assert not out.exists()


@pytest.mark.parametrize("env_id, fix", [
    (VALVE, "make a new env with gym.make, or connect() the Robot again"),
    ("lowcostdex/AllegroTurnValve-v0", "make a new env with gym.make"),
])
def test_an_emulated_robot_env_used_after_close_says_it_was_closed(env_id, fix):
    """Before session 15: 'bus is not connected (call connect() or use it as a context
    manager)', advice a gym user cannot follow (the env has no connect)."""
    env = gym.make(env_id, backend="emulated")
    env.reset(seed=0)
    env.close()
    n = env.action_space.shape[0]
    for call in (lambda: env.step(np.zeros(n)), lambda: env.reset(seed=1)):
        with pytest.raises(BusError) as exc:
            call()
        assert "was closed (by Robot.close() or env.close())" in str(exc.value)
        assert fix in str(exc.value)


def test_a_dclaw_robot_closed_then_connected_again_reads():
    env = gym.make(VALVE, backend="emulated")
    env.reset(seed=0)
    robot = env.unwrapped.backend.robot
    robot.close()
    robot.connect()  # what the message offers
    assert np.all(np.isfinite(robot.read().position))
    env.close()


@pytest.mark.parametrize("settings, message", [
    ({"n_iters": 5}, "unknown TVLGTrainConfig setting 'n_iters'; valid: env_id"),
    ({"algo": {"traj_opt": {"kl_stepp": 1.0}}}, "unknown TrajOptConfig setting 'kl_stepp'"),
    ({"cost": {"object_wieght": 1.0}}, "unknown TaskCostConfig setting 'object_wieght'"),
    ({"algo": {"dyn": {}}}, "unknown TVLGConfig setting 'dyn'; valid: dynamics"),
    ([1, 2], "TVLGTrainConfig settings must be a dict"),
])
def test_a_misspelt_tvlg_setting_in_a_json_config_is_named_with_the_valid_ones(settings, message):
    """TrainConfig.from_dict named a misspelt key; TVLGTrainConfig.from_dict raised the
    constructor's TypeError ('__init__() got an unexpected keyword argument')."""
    with pytest.raises(ConfigError) as exc:
        TVLGTrainConfig.from_dict(settings)
    assert message in str(exc.value)


def test_a_tvlg_config_still_round_trips_through_its_dict():
    import dataclasses

    config = TVLGTrainConfig(n_iter=3, seed=2)
    assert TVLGTrainConfig.from_dict(json.loads(json.dumps(dataclasses.asdict(config)))) == config


# ------------------------------------------------------------------------------------------------
# gym.make's robot keywords, as a JSON run config (TrainConfig.env_kwargs) or a hurried user
# writes them

ALLEGRO = "lowcostdex/AllegroTurnValve-v0"


@pytest.mark.parametrize("env_id, kwargs, message", [
    # was TypeError "replace() should be called on dataclass instances"
    (VALVE, dict(robot_config={"motion_scal": 0.5}),
     "unknown RobotConfig setting 'motion_scal'; valid: control_period, motion_scale"),
    (VALVE, dict(robot_config=0.1), "robot_config=0.1 must be a RobotConfig (or a dict"),
    (VALVE, dict(reset_config={"retries": 1}), "unknown ResetConfig setting 'retries'"),
    # was "an effect is an object with ..., not str 'l'": the name's letters read as effects
    (VALVE, dict(effects="latency"), "effects='latency' must be a list of effects"),
    (VALVE, dict(effects={"effect": "latency"}), "must be a list of effects"),
    (ALLEGRO, dict(effects="latency"), "effects='latency' must be a list of effects"),
    # was numpy's "could not broadcast input array from shape (9,) into shape (10,)"
    (VALVE, dict(start_qpos=[0.0, -1.0, 1.0] * 3),
     "start_qpos has shape (9,); this model's qpos is (10,): ff_top, ff_middle"),
    (VALVE, dict(start_qpos=[0.0, -60.0, 60.0] * 3 + [0.0]),
     "start_qpos: joint ff_middle at -60 rad is outside its range"),
    (VALVE, dict(start_qpos=[np.nan] * 10), "start_qpos has NaN/inf entries"),
    (ALLEGRO, dict(start_qpos=[0.0] * 16), "start_qpos has shape (16,); this model's qpos is "
                                           "(17,)"),
])
def test_an_emulated_robot_keyword_of_the_wrong_form_is_named(env_id, kwargs, message):
    with pytest.raises(ConfigError) as exc:
        gym.make(env_id, backend="emulated", **kwargs)
    assert message in str(exc.value)


def test_randomize_given_a_number_is_named():
    """Was TypeError "'int' object is not iterable" from inside gym.make."""
    with pytest.raises(ConfigError, match=r"randomize=5 must be effect names"):
        gym.make(VALVE, randomize=5)


def test_robot_keywords_as_json_dicts_build_the_settings():
    """A JSON run config can only hold dicts: they build the settings they name."""
    env = gym.make(VALVE, backend="emulated",
                   robot_config={"motion_scale": 0.5, "thermal": {"warn_margin": 10.0}},
                   start_qpos=[0.0, -1.0, 1.0] * 3 + [0.0])
    try:
        config = env.unwrapped.backend.robot.config
        assert config.motion_scale == 0.5 and config.thermal.warn_margin == 10.0
        assert env.reset(seed=0)[0].shape == (30,)
    finally:
        env.close()


# ------------------------------------------------------------------------------------------------
# a run of one trainer loaded with another's loader


def _npg_run_dir(path: Path) -> Path:
    """A folder holding what `train npg` writes first: its config.json."""
    import dataclasses

    path.mkdir()
    (path / "config.json").write_text(json.dumps(dataclasses.asdict(TrainConfig(algo="npg"))))
    return path


def _tvlg_run_dir(path: Path) -> Path:
    """A folder as `train tvlg` leaves it: config.json and controller.npz."""
    import dataclasses

    path.mkdir()
    (path / "config.json").write_text(json.dumps(dataclasses.asdict(TVLGTrainConfig())))
    np.savez(path / "controller.npz", **{"controller/K": np.zeros((2, 2, 2))})
    return path


def test_a_tvlg_run_given_to_load_policy_names_load_controller(tmp_path):
    """Was 'no policy here (a run directory holds policy.pt)' for the folder and 'does not load:
    corrupt or cut short (RuntimeError)' for its controller.npz, which is not corrupt."""
    from lowcostdex.algos.train import load_policy
    from lowcostdex.errors import InputError

    run = _tvlg_run_dir(tmp_path / "tvlg")
    for given in (run, run / "controller.npz"):
        with pytest.raises(InputError, match=r"is a TVLG run's controller .*load_controller"):
            load_policy(given)


def test_an_npg_run_given_to_load_controller_names_load_policy(tmp_path):
    """Was a TypeError (then 'unknown TVLGTrainConfig setting') from reading npg's config as a
    TVLG one."""
    from lowcostdex.algos.local_models.train import load_controller
    from lowcostdex.errors import InputError

    run = _npg_run_dir(tmp_path / "npg")
    with pytest.raises(InputError, match=r"is a run of 'train npg/dapg', not of 'train tvlg': "
                                         r"load its policy with .*load_policy"):
        load_controller(run)


# ------------------------------------------------------------------------------------------------
# a misspelt keyword on a settings class


@pytest.mark.parametrize("make, message", [
    (lambda: TrainConfig(algo="npg", n_iters=5), "TrainConfig has no setting 'n_iters'; did you "
                                                 "mean n_iter"),
    (lambda: NPGConfig(stepsize=0.05), "NPGConfig has no setting 'stepsize'; did you mean "
                                       "step_size?"),
    (lambda: BCConfig(epoch=5), "BCConfig has no setting 'epoch'; did you mean epochs"),
    (lambda: GapConfig(seeds=1), "GapConfig has no setting 'seeds'; did you mean seed?"),
    (lambda: TVLGTrainConfig(n_rollout=5), "TVLGTrainConfig has no setting 'n_rollout'; did you "
                                           "mean n_rollouts"),
    (lambda: __import__("lowcostdex.hardware.robot.robot", fromlist=["RobotConfig"]).RobotConfig(
        controlperiod=0.1), "RobotConfig has no setting 'controlperiod'; did you mean "
                            "control_period?"),
    (lambda: TrainConfig(algo="npg", colour="red"), "TrainConfig has no setting 'colour' (valid: "
                                                    "algo, env_id"),
    (lambda: __import__("lowcostdex.hardware.robot.guards", fromlist=["x"]).ThermalConfig(
        warn_marg=10.0), "ThermalConfig has no setting 'warn_marg'; did you mean warn_margin?"),
    (lambda: __import__("lowcostdex.sim.envs.dclaw_tasks", fromlist=["x"]).TurnConfig(
        goal_ofset=1.0), "TurnConfig has no setting 'goal_ofset'; did you mean goal_offset"),
    (lambda: __import__("lowcostdex.algos.local_models.mdgps", fromlist=["x"]).MDGPSConfig(
        iteration=3), "MDGPSConfig has no setting 'iteration'; did you mean iterations?"),
    (lambda: __import__("lowcostdex.teachers", fromlist=["x"]).ValveTeacherConfig(gian=1.0),
     "ValveTeacherConfig has no setting 'gian'"),
], ids=["TrainConfig", "NPGConfig", "BCConfig", "GapConfig", "TVLGTrainConfig", "RobotConfig",
        "no-close-match", "ThermalConfig", "TurnConfig", "MDGPSConfig", "ValveTeacherConfig"])
def test_a_misspelt_setting_names_the_closest_ones(make, message):
    """Python said "__init__() got an unexpected keyword argument 'n_iters'", without the valid
    names. The error is still a TypeError (as Python's) and a ConfigError (the CLI's one line)."""
    with pytest.raises(ConfigError) as exc:
        make()
    assert isinstance(exc.value, TypeError)
    assert message in str(exc.value)


def test_settings_classes_still_build_copy_and_pickle():
    import dataclasses
    import pickle

    config = TrainConfig(algo="dapg", demos="d.h5", n_iter=3, npg=NPGConfig(step_size=0.05))
    assert dataclasses.replace(config, n_iter=4).n_iter == 4
    assert pickle.loads(pickle.dumps(config)) == config
    assert TrainConfig.from_dict(json.loads(json.dumps(dataclasses.asdict(config)))) == config


@pytest.mark.parametrize("given", [{"algo": "npg"}, "config.json", None])
def test_train_given_something_else_than_a_config_names_the_form(given, tmp_path):
    """Was TypeError 'asdict() should be called on dataclass instances' from dataclasses."""
    with pytest.raises(ConfigError, match=r"train\(\) takes a TrainConfig, not .*from_dict"):
        train(given, tmp_path / "run")
    assert not (tmp_path / "run").exists()


def test_tvlg_train_given_a_dict_names_the_form(tmp_path):
    from lowcostdex.algos.local_models.train import train as train_tvlg

    with pytest.raises(ConfigError, match=r"takes a TVLGTrainConfig, not dict"):
        train_tvlg({"n_iter": 1}, tmp_path / "run")
