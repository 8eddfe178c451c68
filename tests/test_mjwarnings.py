"""MuJoCo's warnings are recorded, not printed or written to MUJOCO_LOG.TXT, and a Ctrl-C during
a warning never aborts the process.

The truth is MuJoCo's own behaviour: each simulation's ``warning[mjWARN_BADQACC].number`` counter
(plain MuJoCo, no project code), the files and output MuJoCo leaves without the handler, and the
exit status of a process interrupted while MuJoCo warns.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

import mujoco
from mujoco import batch as mjbatch

from lowcostdex.sim.mjwarnings import MujocoWarnings, collect_mujoco_warnings, warning_kind

# A motor with an absurd gear on a light link: the first step's acceleration is "huge" (BADQACC).
UNSTABLE = """<mujoco><option timestep="0.002"/><worldbody><body>
<joint name="j" type="hinge" axis="0 1 0"/>
<geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.012" mass="1e-6"/></body></worldbody>
<actuator><motor joint="j" gear="1e30"/></actuator></mujoco>"""
BADQACC = "Nan, Inf or huge value in QACC at DOF 0. The simulation is unstable."


def _step_unstable(data: mujoco.MjData, model: mujoco.MjModel, resets: int,
                   steps_before: int = 0) -> int:
    """Reset, coast ``steps_before`` steps, push; MuJoCo's own count of BADQACC warnings."""
    raised = 0
    for _ in range(resets):
        mujoco.mj_resetData(model, data)
        for _ in range(steps_before):
            mujoco.mj_step(model, data)
        data.ctrl[:] = 1.0
        mujoco.mj_step(model, data)
        raised += int(data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number)
    return raised


def test_warnings_are_recorded_not_printed_and_no_log_file_is_written(tmp_path, monkeypatch, capfd):
    monkeypatch.chdir(tmp_path)
    model = mujoco.MjModel.from_xml_string(UNSTABLE)
    data = mujoco.MjData(model)
    before = mujoco.get_mju_user_warning()
    with collect_mujoco_warnings() as seen:
        raised = _step_unstable(data, model, 3) + _step_unstable(data, model, 2, steps_before=5)
    assert raised == 5  # MuJoCo counted one per reset
    assert seen.as_dict() == {BADQACC: 2}  # at t = 0 and at t = 5 steps: 2 distinct times
    assert seen.summary().startswith(f"MuJoCo warned (recorded, not printed): '{BADQACC}' (at 2 ")
    out, err = capfd.readouterr()
    assert "WARNING" not in out + err
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()
    assert mujoco.get_mju_user_warning() is before  # the previous handler is back
    assert MujocoWarnings().summary() == ""


def test_without_the_handler_mujoco_prints_and_writes_its_log(tmp_path, monkeypatch, capfd):
    """The behaviour the handler replaces (so the test above can fail)."""
    monkeypatch.chdir(tmp_path)
    model = mujoco.MjModel.from_xml_string(UNSTABLE)
    _step_unstable(mujoco.MjData(model), model, 2)
    out, err = capfd.readouterr()
    assert "Nan, Inf or huge value in QACC" in out + err
    assert (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_batch_worker_threads_are_recorded(tmp_path, monkeypatch, capfd):
    """``mujoco.batch`` on 2 threads calls the handler from its workers."""
    monkeypatch.chdir(tmp_path)
    model = mujoco.MjModel.from_xml_string(UNSTABLE)
    batch = mjbatch.Batch(model, nsim=48, nthread=2)
    with collect_mujoco_warnings() as seen:
        for _ in range(5):
            batch.reset()
            batch.bind("ctrl")[:] = 1.0
            batch.step()
    assert seen.as_dict() == {BADQACC: 1}
    out, err = capfd.readouterr()
    assert "WARNING" not in out + err and not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_nested_blocks_record_their_own_and_restore_the_outer_handler():
    model = mujoco.MjModel.from_xml_string(UNSTABLE)
    data = mujoco.MjData(model)
    with collect_mujoco_warnings() as outer:
        _step_unstable(data, model, 1)
        with collect_mujoco_warnings() as inner:
            _step_unstable(data, model, 1, steps_before=3)
        _step_unstable(data, model, 1, steps_before=7)
    assert (len(outer.messages), len(inner.messages)) == (2, 1)


def test_the_time_stamp_is_not_part_of_the_kind():
    a = warning_kind("Inertia matrix is too close to singular at DOF 0. Check model. Time = 0.0000.")
    b = warning_kind("Inertia matrix is too close to singular at DOF 0. Check model. Time = 12.5.")
    assert a == b == "Inertia matrix is too close to singular at DOF 0. Check model."


CHILD = textwrap.dedent(f"""
    import sys, time, mujoco
    from lowcostdex.sim.mjwarnings import collect_mujoco_warnings
    m = mujoco.MjModel.from_xml_string({UNSTABLE!r})
    d = mujoco.MjData(m)
    with collect_mujoco_warnings():
        print("ready", flush=True)
        t0 = time.time()
        try:
            while time.time() - t0 < 20:  # MuJoCo warns on every pass
                mujoco.mj_resetData(m, d); d.ctrl[:] = 1.0; mujoco.mj_step(m, d)
        except KeyboardInterrupt:
            sys.exit(130)
    sys.exit(3)
""")


def test_ctrl_c_while_mujoco_warns_interrupts_cleanly():
    """A Python warning handler aborts the whole process when a KeyboardInterrupt lands inside it
    (the exception cannot unwind through MuJoCo's C code: 'libc++abi: terminating', SIGABRT;
    3 of 3 with a handler doing a little Python work). The recorded handler runs no Python code."""
    for _ in range(3):
        proc = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(0.3)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, (proc.returncode, err[-300:])


def test_one_description_for_the_console_and_the_report():
    from lowcostdex.sim.mjwarnings import describe_warnings

    kinds = {"a": 5, "b": 2, "c": 1}
    assert describe_warnings({}) == ""
    assert describe_warnings(kinds, 1) == ("MuJoCo warned (recorded, not printed): 'a' (at 5 distinct "
                                           "simulation times); and 2 other kinds")
    assert describe_warnings(kinds, None).count("distinct simulation times") == 3
    assert "other kinds" not in describe_warnings(kinds, None)
