"""The main job's flip (issue 15's "done when"): ``lowcostdex main --task flip`` records its
demonstrations with the pinched flip teacher on the emulated D'Claw, trains on them, and shows a
rollout figure of the block's orientation over time. The figure's curves are checked against the
block's tilt computed here from the recorded free-joint quaternions (the rotation of the body z
axis written out), not with the task's own ``tilt``."""

from __future__ import annotations

import json
import pathlib
import sys

import numpy as np
import pytest

from lowcostdex.cli import main

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from figcheck import figure_problems  # noqa: E402

SUCCESS_DEG = np.degrees(0.4)  # FlipConfig.success_angle: within 0.4 rad of the goal


@pytest.fixture(scope="module")
def flip(tmp_path_factory):
    out = tmp_path_factory.mktemp("main_flip")
    assert main(["main", "--size", "smoke", "--task", "flip", "--out", str(out),
                 "--stages", "bus,demos,train"]) == 0
    return out, json.loads((out / "results.json").read_text())


def tilt_deg(quat_wxyz: np.ndarray) -> np.ndarray:
    """Angle between the block's z axis and the world's up [deg]: the z component of R e_z for
    the unit quaternion (w, x, y, z) is 1 - 2 (x^2 + y^2)."""
    q = quat_wxyz / np.linalg.norm(quat_wxyz, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(1 - 2 * (q[..., 1] ** 2 + q[..., 2] ** 2), -1, 1)))


def block_quaternion_columns(out):
    """Columns of qpos holding the block's free-joint quaternion, read from the compiled model
    of the recorded env (the last free joint's qpos address + 3)."""
    import gymnasium as gym
    import mujoco

    import lowcostdex  # noqa: F401

    env = gym.make("lowcostdex/DClawFlipBlock-v0")
    m = env.unwrapped.model
    free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    env.close()
    assert len(free) == 1
    adr = int(m.jnt_qposadr[free[0]])
    return slice(adr + 3, adr + 7)


def test_flip_demonstrations_come_from_the_pinched_teacher(flip):
    out, r = flip
    d = r["demos"]
    assert d["teacher"] == "PinchFlipTeacher"
    # smoke: 4 successful demos within 3 x 4 episodes (measured 4 of 6 on seed 0)
    assert d["successful"] == 4 and d["episodes"] <= 12
    assert (out / d["file"]).stat().st_size > 0


def test_flip_report_shows_the_blocks_orientation_over_time(flip):
    from lowcostdex.demonstrations.file import read_episodes
    from lowcostdex.main_job.stages import flip_rollout_figure

    out, r = flip
    ro = r["train"]["rollout"]
    assert (out / ro["plot"]).stat().st_size > 5000
    data = np.load(out / ro["data"])
    period = float(data["period"])
    assert period == pytest.approx(0.1)  # DClawFlipBlock's control period (10 Hz)
    policy_q, demo_q = data["qpos_0"], data["qpos_1"]
    assert len(policy_q) == ro["steps"] + 1
    # the recorded demonstration is the first successful one of demos.h5, unchanged
    demo = next(e for e in read_episodes(out / "demos.h5") if e.length and e.success[-1])
    np.testing.assert_array_equal(demo_q, demo.qpos)

    import gymnasium as gym

    import lowcostdex  # noqa: F401

    env = gym.make("lowcostdex/DClawFlipBlock-v0")
    task = env.unwrapped.task
    env.close()
    fig = flip_rollout_figure(task, period, {"DAPG policy (mean action)": (policy_q, demo.goal),
                                             "a demonstration": (demo_q, demo.goal)})
    assert figure_problems(fig) == []
    tilt_ax, err_ax = fig.axes[:2]
    assert "[deg]" in tilt_ax.get_ylabel() and "[s]" in tilt_ax.get_xlabel()
    assert "[deg]" in err_ax.get_ylabel() and "[s]" in err_ax.get_xlabel()
    assert fig._suptitle.get_text()
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == ["DAPG policy (mean action)", "a demonstration", "success threshold"]
    cols = block_quaternion_columns(out)
    for line, q in zip(tilt_ax.get_lines(), (policy_q, demo_q), strict=True):
        t, y = line.get_xydata().T
        np.testing.assert_allclose(t, np.arange(len(q)) * period)
        np.testing.assert_allclose(y, tilt_deg(q[:, cols]), atol=1e-6)
    # the demonstration flipped the block: it starts upright and ends upside down within the
    # success angle, and its error curve ends below the dashed threshold line
    demo_tilt = tilt_ax.get_lines()[1].get_ydata()
    assert demo_tilt[0] < 15 and demo_tilt[-1] > 180 - SUCCESS_DEG
    threshold = err_ax.get_lines()[-1].get_ydata()[0]
    assert threshold == pytest.approx(SUCCESS_DEG)
    assert err_ax.get_lines()[1].get_ydata()[-1] < threshold
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_flip_report_links_the_rollout(flip):
    out, r = flip
    text = (out / "report.md").read_text()
    assert "![flip rollout](flip_rollout.png)" in text
    assert f"final orientation error {r['train']['rollout']['final_orientation_error_deg']} deg" in text
