"""MuJoCo's warnings are counted, not printed or written to MUJOCO_LOG.TXT, during an analysis.

The truth is MuJoCo's own bookkeeping: each simulation's ``warning[mjWARN_BADQACC].number``
counter (plain MuJoCo, no project code), and the files and stderr MuJoCo leaves without the handler.
"""

from __future__ import annotations

import mujoco
from mujoco import batch as mjbatch

from lowcostdex.sim.mjwarnings import collect_mujoco_warnings, warning_kind

# A motor with an absurd gear on a light link: every step's acceleration is "huge" (BADQACC).
UNSTABLE = """<mujoco><option timestep="0.002"/><worldbody><body>
<joint name="j" type="hinge" axis="0 1 0"/>
<geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.012" mass="1e-6"/></body></worldbody>
<actuator><motor joint="j" gear="1e30"/></actuator></mujoco>"""


def _step_unstable(data: mujoco.MjData, model: mujoco.MjModel, resets: int) -> int:
    """Reset and step ``resets`` times; MuJoCo's own count of BADQACC warnings raised."""
    raised = 0
    for _ in range(resets):
        mujoco.mj_resetData(model, data)
        data.ctrl[:] = 1.0
        mujoco.mj_step(model, data)
        raised += int(data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number)
    return raised


def test_warnings_are_counted_not_printed_and_no_log_file_is_written(tmp_path, monkeypatch, capfd):
    monkeypatch.chdir(tmp_path)
    model = mujoco.MjModel.from_xml_string(UNSTABLE)
    data = mujoco.MjData(model)
    before = mujoco.get_mju_user_warning()
    with collect_mujoco_warnings() as seen:
        raised = _step_unstable(data, model, 7)
    assert raised == 7  # MuJoCo counted one per reset
    assert seen.total == 7
    assert list(seen.counts) == ["Nan, Inf or huge value in QACC at DOF 0. The simulation is unstable."]
    assert "x7" in seen.summary() and seen.summary().startswith("MuJoCo warned 7 times")
    out, err = capfd.readouterr()
    assert "WARNING" not in out + err
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
    assert mujoco.get_mju_user_warning() is before  # the previous handler is back


def test_without_the_handler_mujoco_prints_and_writes_its_log(tmp_path, monkeypatch, capfd):
    """The behaviour the handler replaces (so the test above can fail)."""
    monkeypatch.chdir(tmp_path)
    model = mujoco.MjModel.from_xml_string(UNSTABLE)
    _step_unstable(mujoco.MjData(model), model, 2)
    out, err = capfd.readouterr()
    assert "Nan, Inf or huge value in QACC" in out + err
    assert (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_batch_worker_threads_are_counted(tmp_path, monkeypatch):
    """``mujoco.batch`` on 2 threads calls the handler from its workers: nothing lost."""
    monkeypatch.chdir(tmp_path)
    model = mujoco.MjModel.from_xml_string(UNSTABLE)
    batch = mjbatch.Batch(model, nsim=48, nthread=2)
    with collect_mujoco_warnings() as seen:
        for _ in range(5):
            batch.reset()
            batch.bind("ctrl")[:] = 1.0
            batch.step()
    assert seen.total == 48 * 5
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_nested_blocks_count_their_own_and_restore_the_outer_handler():
    model = mujoco.MjModel.from_xml_string(UNSTABLE)
    data = mujoco.MjData(model)
    with collect_mujoco_warnings() as outer:
        _step_unstable(data, model, 2)
        with collect_mujoco_warnings() as inner:
            _step_unstable(data, model, 3)
        _step_unstable(data, model, 1)
    assert (outer.total, inner.total) == (3, 3)


def test_the_time_stamp_is_not_part_of_the_kind():
    a = warning_kind("Inertia matrix is too close to singular at DOF 0. Check model. Time = 0.0000.")
    b = warning_kind("Inertia matrix is too close to singular at DOF 0. Check model. Time = 12.5.")
    assert a == b == "Inertia matrix is too close to singular at DOF 0. Check model."
