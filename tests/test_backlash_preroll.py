"""A replay window's backlash play state carried from the log before it (``gap.play_state``).

The truth is plain MJCF written out here (imports nothing of the analyzer's plant or effects): a
turntable (vertical axis, no gravity torque) whose position servo drives a light motor body, the
disk sitting on a hinge limited to +-width/2 beside it, at 0.25 ms. After a goal step the servo
stops the motor and the unloaded disk coasts on through the play at a few hundredths of a rad/s,
below a Dynamixel's 0.024 rad/s velocity reading, until it meets the far stop. A window that
starts during that drift reads the disk's angle and a velocity of 0: where the disk sits in the
play and how fast it moves are hidden. Replayed from the middle of the play at rest (the rule for
an unloaded link at a log's start), the model holds the disk still and misses the drift; with
the second of log before the window replayed first, it starts where that motion leaves it.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lowcostdex.gap.dataset import Window, load_dataset
from lowcostdex.gap.logs import write_log
from lowcostdex.gap.replay import Replayer
from lowcostdex.gap.trajectory import Trajectory
from lowcostdex.sim.effects import AppliedEffect

W = 0.0175  # play width [rad] (1 degree)
TICK = 2 * math.pi / 4096  # 12-bit encoder
VEL_UNIT = 0.229 * 2 * math.pi / 60  # Dynamixel present-velocity unit [rad/s] (0.229 rpm)
_ATTR = 'damping="0.05" armature="0.004"'
_ACT = '<actuator><position name="j" joint="{j}" kp="4" kv="0.12"/></actuator>'
_DISK = ('<geom type="cylinder" size="0.08 0.01" mass="0.4"/>'
         '<geom type="box" pos="0.06 0 0.02" size="0.02 0.01 0.01" mass="0.05"/>')
USER = (f'<mujoco><compiler angle="radian"/><option timestep="0.001" integrator="implicitfast"/>'
        f'<default><geom contype="0" conaffinity="0"/></default><worldbody><body pos="0 0 0.1">'
        f'<joint name="j" axis="0 0 1" {_ATTR}/>{_DISK}</body></worldbody>{_ACT.format(j="j")}'
        f'</mujoco>')
TRUTH = (f'<mujoco><compiler angle="radian"/><option timestep="0.00025" integrator="implicitfast"/>'
         f'<default><geom contype="0" conaffinity="0"/></default><worldbody><body pos="0 0 0.1">'
         f'<joint name="m" axis="0 0 1" {_ATTR}/><geom type="cylinder" size="0.008 0.004" '
         f'mass="0.002"/><body><joint name="p" axis="0 0 1" limited="true" '
         f'range="{-W / 2} {W / 2}" solreflimit="0.001 1" armature="1e-6"/>{_DISK}</body></body>'
         f'</worldbody>{_ACT.format(j="m")}</mujoco>')


def _log(tmp_path, steps=((0.0, 0.3), (1.0, -0.6), (3.0, 0.5)), duration=5.0, rate=200.0):
    """Write the truth's log (rows at ``rate``, goals ``steps`` = (time, goal) held, readings
    on 4096 ticks, velocities in Dynamixel units) and load it with the user's model."""
    m = mujoco.MjModel.from_xml_string(TRUTH)
    d = mujoco.MjData(m)
    g0 = steps[0][1]
    d.qpos[:] = [g0, 0.0]
    d.ctrl[:] = g0
    t = np.arange(int(duration * rate)) / rate
    goal = np.array([[next(g for ts, g in reversed(steps) if ts <= ti)] for ti in t])
    q, v = np.empty((len(t), 1)), np.empty((len(t), 1))
    for i, ti in enumerate(t):
        while d.time < ti - 1e-9:
            mujoco.mj_step(m, d)
        q[i] = np.round((d.qpos[0] + d.qpos[1]) / TICK) * TICK
        v[i] = np.round((d.qvel[0] + d.qvel[1]) / VEL_UNIT) * VEL_UNIT
        d.ctrl[:] = goal[i]  # the goal written right after the row was read
    (tmp_path / "model.xml").write_text(USER)
    write_log(tmp_path / "log0.csv", Trajectory(name="log0", time=t, goal=goal, qpos=q, qvel=v,
                                                joints=("j",), actuators=("j",)))
    return load_dataset([tmp_path / "log0.csv"], model=tmp_path / "model.xml")


def _rmse(ds, w, preroll, col):
    rep = Replayer(ds, ["backlash"], nthread=1)
    rep.preroll = preroll
    pred = rep.run([w], [col])[0][0]
    return float(np.sqrt(np.mean((pred - ds.trajectories[0].qpos[w.start:w.stop]) ** 2)))


PLAY = [AppliedEffect("backlash", ("j",), {"width": np.array([W]), "sensor": np.array([0.0])})]


@pytest.mark.parametrize("start", [1.6, 2.0])
def test_a_window_starting_while_an_unloaded_link_drifts_through_its_play(tmp_path, start):
    """The window starts 0.6 or 1 s after a goal step, while the disk drifts through the play
    at ~0.03 rad/s (read as one velocity unit), and holds the next step. Measured (RMSE):
    started mid-play, 3.9 / 2.6 mrad; with the second before replayed first, 0.82 / 0.84 mrad
    (the nominal model without play: 5.7 mrad; the readings' quantisation floor 0.44 mrad)."""
    ds = _log(tmp_path)
    tr = ds.trajectories[0]
    a, b = np.searchsorted(tr.time, [start, 4.0])
    assert abs(tr.qvel[a, 0]) <= VEL_UNIT * 1.01  # the drift is at the velocity's resolution
    w = Window(0, int(a), int(b), int(a))
    cold, warm = _rmse(ds, w, 0.0, PLAY), _rmse(ds, w, 1.0, PLAY)
    assert warm < 1.2e-3, warm
    assert cold > 2.5 * warm, (cold, warm)


def test_a_log_start_and_a_model_without_play_are_unchanged(tmp_path):
    """No history before a log's first sample: its window starts as before; a column without
    a play (the nominal model) replays bit for bit as without the pre-roll."""
    ds = _log(tmp_path, duration=2.5)
    tr = ds.trajectories[0]
    first = Window(0, 0, len(tr), 0)
    assert _rmse(ds, first, 1.0, PLAY) == _rmse(ds, first, 0.0, PLAY)
    mid = Window(0, 300, len(tr), 300)
    assert _rmse(ds, mid, 1.0, []) == _rmse(ds, mid, 0.0, [])


@pytest.mark.parametrize("inside", [0.8, -0.5])
def test_place_keeps_the_link_and_clips_into_the_play(inside):
    """``play_state.place`` moves the hidden motor side, not the link the encoder reads."""
    from lowcostdex.gap import play_state
    from lowcostdex.sim.plant import BatchPlant, prepare_spec

    spec = mujoco.MjSpec.from_string(USER)
    prepare_spec(spec, PLAY, hidden_dofs=True)
    p = BatchPlant(spec.compile(), 2, PLAY, nthread=1)
    p.reset(qpos=np.tile([0.3, 0.0], (2, 1)), qvel=np.tile([0.1, 0.0], (2, 1)),
            ctrl=np.full((2, 1), 0.3))
    play_state.place(p, ("j",), np.array([[inside * W / 2], [3 * W]]),
                     np.array([[0.02], [0.0]]), sims=np.array([0, 1]))
    q, v, vl = play_state.read(p, ("j",))
    assert q[:, 0] == pytest.approx([inside * W / 2, W / 2])
    assert v[:, 0] == pytest.approx([0.02, 0.0]) and vl[:, 0] == pytest.approx([0.1, 0.1])
    assert p.measured_qpos()[:, 0] == pytest.approx([0.3, 0.3])
