"""The servo update period (``sim.servo.ServoClock`` through ``Plant``/``BatchPlant``): a servo's
firmware samples its position law every period and holds the force between updates.

Truth here is plain MuJoCo written out in the test: a ``motor`` actuator whose ctrl is the P-D
law ``clip(kp (goal - q) - kv qdot, +-tmax)`` evaluated every period, as a Dynamixel/Feetech
firmware does at ~1 kHz (reference 05/07: the X-series and STS position loops run at 1 kHz)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.sim.plant import BatchPlant, Plant

KP, KV, TMAX = 7.5, 0.05, 1.5  # N m/rad, N m s/rad, N m (a 1.5 N m servo, kp 2.5x its nominal 3)


def _xml(actuator: str, dt: float) -> str:
    return (f'<mujoco><option timestep="{dt}" integrator="implicitfast"/><worldbody>'
            '<body pos="0 0 0.3"><joint name="q" type="hinge" axis="1 0 0" armature="0.002" '
            'damping="0.01"/><inertial pos="0 0 -0.06" mass="0.15" diaginertia="2e-5 2e-5 1e-6"/>'
            f'</body></worldbody><actuator>{actuator}</actuator></mujoco>')


POSITION = f'<position name="servo" joint="q" kp="{KP}" kv="{KV}" forcerange="{-TMAX} {TMAX}"/>'
MOTOR = f'<motor name="servo" joint="q" ctrlrange="{-TMAX} {TMAX}" ctrllimited="true"/>'


def _goals(n_ctrl: int) -> np.ndarray:
    t = np.arange(n_ctrl) * 0.01
    return np.where(t < 0.3, 0.0, 0.8) + 0.3 * np.sin(2 * np.pi * 1.5 * t) * (t > 0.6)


def _firmware_truth(dt: float, period: float, goals: np.ndarray, nstep: int) -> np.ndarray:
    m = mujoco.MjModel.from_xml_string(_xml(MOTOR, dt))
    d = mujoco.MjData(m)
    every = int(round(period / dt))
    out, i = [], 0
    for g in goals:
        for _ in range(nstep):
            if i % every == 0:
                d.ctrl[0] = np.clip(KP * (g - d.qpos[0]) - KV * d.qvel[0], -TMAX, TMAX)
            mujoco.mj_step(m, d)
            i += 1
        out.append(d.qpos[0])
    return np.array(out)


def _plant_run(plant, goals: np.ndarray, nstep: int) -> np.ndarray:
    out = []
    for g in goals:
        plant.step(np.broadcast_to([g], plant.ctrl.shape), nstep)
        out.append(np.array(plant.qpos[..., 0]))
    return np.array(out)


@pytest.mark.parametrize("dt,period", [(0.00025, 0.001), (0.0005, 0.001), (0.001, 0.001)])
def test_a_held_position_law_is_the_firmware_driving_a_motor(dt, period):
    goals, nstep = _goals(150), int(round(0.01 / dt))
    truth = _firmware_truth(dt, period, goals, nstep)
    model = mujoco.MjModel.from_xml_string(_xml(POSITION, dt))
    plant = Plant(model, servo_period=period)
    plant.reset(ctrl=np.zeros(1))
    got = _plant_run(plant, goals, nstep)
    assert np.max(np.abs(got - truth)) < 1e-9
    assert plant.servo_period == pytest.approx(period)
    # and the batch, two simulations stepped together, holds the same law
    bp = BatchPlant(model, 2, servo_period=period, nthread=1)
    bp.reset(ctrl=np.zeros((2, 1)))
    got2 = _plant_run(bp, goals, nstep)
    assert np.max(np.abs(got2 - truth[:, None])) < 1e-9


def test_period_zero_is_the_continuous_law_and_the_period_matters():
    dt, goals = 0.00025, _goals(150)
    model = mujoco.MjModel.from_xml_string(_xml(POSITION, dt))
    d = mujoco.MjData(model)
    cont = []
    for g in goals:
        d.ctrl[0] = g
        mujoco.mj_step(model, d, nstep=40)
        cont.append(d.qpos[0])
    plant = Plant(model)
    plant.reset(ctrl=np.zeros(1))
    assert np.array_equal(_plant_run(plant, goals, 40), np.array(cont))
    held = _firmware_truth(dt, 0.001, goals, 40)
    # the 1 ms hold moves the response by far more than the integrator's rounding
    assert np.max(np.abs(held - np.array(cont))) > 1e-3


def test_a_held_force_honours_torque_off_and_a_period_can_be_removed():
    dt = 0.00025
    model = mujoco.MjModel.from_xml_string(_xml(POSITION, dt))
    plant = Plant(model, servo_period=0.001)
    plant.reset(ctrl=np.zeros(1))
    plant.step(np.array([0.5]), 2)  # mid-period, pushing toward 0.5
    assert plant.data.actuator_force[0] > 0.5
    plant.set_torque_enabled([0], False)
    plant.step(np.array([0.5]), 1)
    assert plant.data.actuator_force[0] == 0.0  # a free-wheeling bridge: no held torque
    plant.set_torque_enabled([0], True)
    plant.set_servo_period(0.0)
    assert plant.servo_period == 0.0
    assert list(plant.model.actuator_forcerange[0]) == [-TMAX, TMAX]


@pytest.mark.parametrize("bad", [-0.001, float("nan"), 0.5])
def test_a_bad_period_is_refused(bad):
    model = mujoco.MjModel.from_xml_string(_xml(POSITION, 0.00025))
    with pytest.raises(ConfigError, match="servo period"):
        Plant(model, servo_period=bad)


def test_the_gap_replay_holds_the_law_for_a_data_set_with_a_servo_period():
    """A log of the firmware truth (motor + P-D law every 1 ms, above) replayed by the gap
    analysis on the user's ``position`` model: with ``Dataset.servo_period`` 1 ms the replay
    is the truth; continuous, it is off by far more than an encoder tick."""
    from lowcostdex.gap.bam_measure import whole_logs
    from lowcostdex.gap.dataset import Dataset
    from lowcostdex.gap.replay import Replayer
    from lowcostdex.gap.trajectory import Trajectory

    dt, goals = 0.00025, _goals(150)
    truth = _firmware_truth(dt, 0.001, goals, 40)
    # row k: goal k written at t_k = 10 ms k, reading at t_k (before the goal acts)
    t = np.arange(len(goals)) * 0.01
    q = np.concatenate([[0.0], truth[:-1]])
    tr = Trajectory(name="fw", time=t, goal=goals[:, None], qpos=q[:, None], actuators=("servo",),
                    joints=("q",), qvel=np.zeros((len(t), 1)))
    err = {}
    for period in (0.0, 0.001):
        ds = Dataset({"model": _xml(POSITION, dt)}, [tr], servo_period=period)
        ((pred,),), _ = Replayer(ds, nthread=1).run(whole_logs(ds), [[]])
        err[period] = float(np.max(np.abs(pred[:, 0] - q)))
    assert err[0.001] < 1e-9, err
    assert err[0.0] > 2 * np.pi / 4096, err
