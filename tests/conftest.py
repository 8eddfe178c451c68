"""Shared fixtures: small inline models so tests need no files."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from lowcostdex.sim import servo

HINGE_XML = """
<mujoco>
  <option timestep="0.0025" integrator="implicitfast" noslip_iterations="1"/>
  <worldbody>
    <body name="arm">
      <joint name="j" type="hinge" axis="0 1 0" damping="0.0"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="0.1"/>
    </body>
  </worldbody>
</mujoco>
"""


def hinge_spec(gravity: bool = False) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_string(HINGE_XML)
    if not gravity:
        spec.option.gravity = [0, 0, 0]
    return spec


def hinge_servo_model(motor: str = "XM430-W350", gains: servo.ServoGains | None = None,
                      gravity: bool = False, thermal: bool = True) -> mujoco.MjModel:
    spec = hinge_spec(gravity)
    m = servo.motor_spec(motor)
    servo.add_servo(spec, "j", m, gains or servo.ServoGains(position_p=m.default_p),
                    thermal=thermal)
    return spec.compile()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


@pytest.fixture
def one_torch_thread():
    """Small networks: one thread is fastest and immune to a busy machine (the caller's thread
    count is restored). Files use it with ``pytestmark = pytest.mark.usefixtures(...)``."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def pytest_addoption(parser):
    group = parser.getgroup("lowcostdex hardware")
    group.addoption("--dxl-port", default=None,
                    help="serial port of a real D'Claw for the `hardware` acceptance tests")
    group.addoption("--can-channel", default=None,
                    help="CAN channel of a real Allegro hand for the `hardware` acceptance tests")


# ------------------------------------------------------------------------------------------------
# README's test command runs on two pytest-xdist workers, one test file at a time per worker
# (`-n 2 --dist loadfile`). xdist hands files out by number of tests, most first, so a heavy file
# with few tests (test_gap_hidden.py: 7 tests, ~170 CPU-s) started near the end and one worker ran
# on alone for minutes (CI at 26fee1b: 126 % CPU over 27:34). The files below go first, heaviest
# first (longest-processing-time-first); every other file keeps xdist's order. Seconds per file:
# the wall of each of CI's 15 slowest files (session 21, 67c45dd: setup + call + teardown summed,
# conftest's "slowest 15 test files" summary; CPU was ~0.67 x wall there): only the order
# matters, not the accuracy. Files below the 15th (43 wall-s) are not listed.
HEAVY_FILES = {
    "test_gap_independent_bench.py": 364,
    "test_main_job.py": 305,
    "test_gap_independent_finger.py": 262,
    "test_gap_hidden.py": 194,
    "test_gap_independent_wide.py": 146,
    "test_transfer.py": 136,
    "test_gap_redteam.py": 126,
    "test_gap_decisions.py": 124,
    "test_gap_redteam7.py": 104,
    "test_flip_main_job.py": 68,
    "test_identify.py": 52,
    "test_gap_timestep.py": 51,
    "test_robot_faults.py": 49,
    "test_gap_actuator_kinds.py": 44,
    "test_demos_recording.py": 43,
}


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadfile`` with the files of ``HEAVY_FILES`` handed out first, heaviest first."""
    if config.getvalue("dist") != "loadfile":
        return None
    try:
        from xdist.scheduler import LoadFileScheduling
    except ImportError:  # pragma: no cover - a future xdist without it: its own scheduling
        return None
    # the order leans on xdist's internals (3.5-3.8: an OrderedDict ``workqueue`` of files and
    # ``_assign_work_unit``); an xdist without them keeps its own order instead of failing the run
    if not hasattr(LoadFileScheduling, "_assign_work_unit"):  # pragma: no cover
        return None

    class HeaviestFirst(LoadFileScheduling):
        def _assign_work_unit(self, node):
            queue = getattr(self, "workqueue", None)
            if queue and hasattr(queue, "move_to_end"):
                # move the heaviest listed file still waiting to the front of the queue
                scope = max(queue, key=lambda s: HEAVY_FILES.get(str(s).rsplit("/", 1)[-1], 0))
                queue.move_to_end(scope, last=False)
            super()._assign_work_unit(node)

    return HeaviestFirst(config, log)


def pytest_terminal_summary(terminalreporter):
    """On a run of 20 files or more: the wall seconds of the slowest files (setup + call +
    teardown summed) and, under xdist, per worker, so the next rebalance has CI's numbers."""
    per_file: dict[str, float] = {}
    per_worker: dict[str, float] = {}
    for reports in terminalreporter.stats.values():
        for rep in reports:
            if not hasattr(rep, "duration") or not hasattr(rep, "nodeid"):
                continue
            f = rep.nodeid.split("::")[0]
            per_file[f] = per_file.get(f, 0.0) + rep.duration
            node = getattr(rep, "node", None)
            if node is not None:
                wid = node.gateway.id
                per_worker[wid] = per_worker.get(wid, 0.0) + rep.duration
    if len(per_file) < 20:
        return
    tr = terminalreporter
    tr.write_sep("=", "slowest 15 test files (wall s)")
    for f, s in sorted(per_file.items(), key=lambda kv: -kv[1])[:15]:
        tr.write_line(f"{s:8.1f}  {f}")
    if per_worker:
        tr.write_line("per worker (wall s): " + ", ".join(
            f"{w} {s:.0f}" for w, s in sorted(per_worker.items())))


@pytest.fixture
def home_and_cwd(tmp_path, monkeypatch):
    """(home, cwd): a fresh HOME (what '~' means) and a working folder with a space in its name,
    the test's cwd; for the careless tests of '~' in paths."""
    home, cwd = tmp_path / "home", tmp_path / "work dir"
    home.mkdir()
    cwd.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(cwd)
    return home, cwd
