"""Driver logs in the project's log format, for the gap analysis (``lowcostdex.gap``).

``TraceRecorder`` drives a ``Robot`` at its control rate and logs, at every read, the measured
joint state and the goal sent right after that read (the command in effect until the next one),
on the robot's clock: ``time`` (when the state was sampled), ``goal_time`` (when the goal had been
sent), ``goal:<actuator>``, ``qpos:<joint>``, ``qvel:<joint>``,
``current:<actuator>``, ``voltage:<actuator>``, ``temperature:<actuator>`` (actuators are named
after the joints they drive, as in the lowcostdex MJCF models). ``excite`` runs identification
excitations (steps from both sides, slow ramps, chirps) through the Robot's safety gate, so the
logged goals are what reached the motors.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.gap.log_checks import MAX_NAN_SHARE
from lowcostdex.gap.logs import Trajectory, write_log
from lowcostdex.hardware.bus import BusError, WatchdogTripped
from lowcostdex.hardware.robot.robot import Robot

log = logging.getLogger(__name__)


class TraceRecorder:
    """Logs what a ``Robot`` is told and what it reads.

    Args:
      robot: a connected robot with torque on for ``joints``.
      joints: the joints to command and log (default the action joints).
    """

    def __init__(self, robot: Robot, joints: Sequence[str] | None = None):
        self.robot = robot
        self.joints = tuple(joints or robot.action_joints)
        self._idx = robot.index(self.joints)
        self._rows: list[tuple[float, np.ndarray, object, float]] = []

    def step(self, goal: np.ndarray) -> np.ndarray:
        """Read, send ``goal`` (n,) [rad] through the safety gate, log both, wait for the tick.

        Returns the goal actually sent.
        """
        state = self.robot.read()
        sent = self.robot.send(np.asarray(goal, float), self.joints)
        self._rows.append((state.time, sent.copy(), state, self.robot.clock.now()))
        self.robot.wait()
        return sent

    def trajectory(self, name: str = "trace") -> Trajectory:
        """The rows logged so far as a gap-analysis ``Trajectory``."""
        if len(self._rows) < 2:
            raise ConfigError("a trace needs at least two logged steps")
        i = self._idx
        time = np.array([r[0] for r in self._rows])
        goal = np.stack([r[1] for r in self._rows])
        states = [r[2] for r in self._rows]
        pick = lambda attr: np.stack([getattr(s, attr)[i] for s in states])  # noqa: E731
        channels = {"current": pick("current"), "voltage": pick("voltage"),
                    "temperature": pick("temperature")}
        for key, values in list(channels.items()):
            missed = ~np.isfinite(values)
            if missed.all():  # not measured by this hand (the Allegro's current and voltage)
                del channels[key]
            elif missed.mean() > MAX_NAN_SHARE:  # a sensor that answers now and then
                del channels[key]
                log.warning("%s: the %s channel is left out of the log: %d of %d readings "
                            "missed (a sensor fault?)", name, key, int(missed.sum()), missed.size)
            elif missed.any():  # a failed read keeps its row, the reading left empty
                log.warning("%s: %d %s reading(s) missed in %d row(s), left empty in the log "
                            "(the gap analysis interpolates short gaps)", name,
                            int(missed.sum()), key, int(missed.any(axis=1).sum()))
        # the goal took effect when its packet had gone out, after the read's replies
        goal_time = np.maximum(np.array([r[3] for r in self._rows]), time)
        return Trajectory(name=name, time=time - time[0], goal=goal, qpos=pick("position"),
                          actuators=self.joints, joints=self.joints, qvel=pick("velocity"),
                          channels=channels, goal_time=goal_time - time[0])


def settle(robot: Robot, joints: Sequence[str], goal: np.ndarray, min_seconds: float = 0.3,
           max_seconds: float = 1.5, speed: float = 0.05) -> bool:
    """Hold ``goal`` (n,) [rad] on ``joints`` until they rest there (every measured |velocity|
    below ``speed`` [rad/s] after at least ``min_seconds``), at most ``max_seconds``; returns
    whether they came to rest. Nothing is logged. (``reset.move`` stops on a position stall
    over a window instead; a log that starts from it still creeps: on the effect-free emulator
    the analysis then named three spurious effects.)"""
    idx = robot.index(joints)
    start = robot.clock.now()
    while True:
        state = robot.read()
        elapsed = robot.clock.now() - start
        if elapsed >= min_seconds and np.all(np.abs(state.velocity[idx]) < speed):
            return True
        if elapsed >= max_seconds:
            return False
        robot.send(np.asarray(goal, float), joints)
        robot.wait()


def excite(robot: Robot, joints: Sequence[str], goals: np.ndarray, path: str | Path,
           name: str | None = None, on_step: Callable[[int], None] | None = None,
           rest_first: bool = True) -> Path:
    """Drive ``joints`` through ``goals`` (K, n) [rad] at the robot's rate and write the log.

    The robot's torque is switched on for ``joints`` first (goal := present, no jump). With
    ``rest_first`` the joints are first brought to rest at ``goals[0]`` (``settle``, not
    logged): a log that starts at rest on its first goal has a known initial state and goal
    history for the replay; one that starts mid-motion does not.
    """
    path = Path(path)
    return write_log(path, record(robot, joints, goals, name or path.stem, on_step, rest_first))


def record(robot: Robot, joints: Sequence[str], goals: np.ndarray, name: str = "trace",
           on_step: Callable[[int], None] | None = None, rest_first: bool = True
           ) -> Trajectory:
    """``excite`` without writing: the logged ``Trajectory`` (a missed reading: NaN in its row)."""
    robot.torque(True, joints)
    if rest_first and len(goals):
        settle(robot, joints, np.asarray(goals, float)[0])
    rec = TraceRecorder(robot, joints)
    for k, g in enumerate(np.asarray(goals, float)):
        rec.step(g)
        if on_step is not None:
            on_step(k)
    return rec.trajectory(name)


def contact_free(model: Any, joints: Sequence[str], goals: np.ndarray,
                 fixed: Mapping[str, float] | None = None, shrink: float = 0.9,
                 max_shrinks: int = 30) -> tuple[np.ndarray, int]:
    """Goals (K, n) [rad] with every pose that touches anything in ``model`` pulled toward the
    middle of the joint ranges until it does not (each row scaled by ``shrink`` about the
    centre, at most ``max_shrinks`` times).

    Identification is about the servos: a finger that hits a neighbour or the base mid-log adds
    contact forces no servo effect explains (on the D'Claw, one finger swung through 0.8 of its
    limits touches another finger or a finger base in 16 % of the box). Poses are checked
    statically (joint positions only; the other joints at ``fixed`` or at the model's qpos0).

    Args:
      model: the robot's full MJCF model (``mujoco.MjModel``).
      joints: the joints of ``goals``' columns.
      goals: the excitation.
      fixed: positions of other joints during the logs [rad] (e.g. fingers parked out of the way).

    Returns:
      (the goals, how many rows were changed).
    """
    import mujoco

    data = mujoco.MjData(model)
    adr = np.array([model.jnt_qposadr[model.joint(j).id] for j in joints])
    lo, hi = model.jnt_range[[model.joint(j).id for j in joints]].T
    centre = np.where(np.isfinite(lo + hi), 0.5 * (lo + hi), 0.0)
    base = model.qpos0.copy()
    for name, value in (fixed or {}).items():
        base[model.jnt_qposadr[model.joint(name).id]] = value
    out = np.array(goals, float)
    changed = 0
    for k, row in enumerate(out):
        q = row.copy()
        for _ in range(max_shrinks + 1):
            data.qpos[:] = base
            data.qpos[adr] = q
            mujoco.mj_kinematics(model, data)
            mujoco.mj_collision(model, data)
            if data.ncon == 0:
                break
            q = centre + shrink * (q - centre)
        if not np.array_equal(q, row):
            out[k] = q
            changed += 1
    return out, changed


PARK_TOLERANCE = 0.05
"""How close parked joints must get to their park positions [rad]."""
PARK_PROGRESS = 0.005
"""[rad] how much closer the farthest parked joint must get per settle (``settle``, up to 3 s)
for the park to keep waiting: a slow robot (a loaded host, an emulator behind its clock) is
waited for while it still moves toward the pose; one that stopped short is refused."""
PARK_MAX_SECONDS = 30.0
"""[s] the longest the park waits, however slowly the joints still move."""


def _park(robot: Robot, park: Mapping[str, float] | None) -> None:
    """Torque on for the ``park`` joints and settle them at their positions [rad], waiting as
    long as they still get closer (``PARK_PROGRESS`` per settle, at most ``PARK_MAX_SECONDS``);
    raises ConfigError when they stop short of ``PARK_TOLERANCE``."""
    if not park:
        return
    names = tuple(park)
    robot.torque(True, names)
    target = np.array([park[n] for n in names])
    idx = robot.index(names)
    start = robot.clock.now()
    best = np.inf
    while True:
        settle(robot, names, target, max_seconds=3.0)
        error = np.abs(robot.present[idx] - target)
        if np.all(error < PARK_TOLERANCE):  # NaN (no reading) fails
            return
        worst = float(np.max(error))
        progress = np.isnan(worst) or worst <= best - PARK_PROGRESS  # no reading: no verdict
        if not progress or robot.clock.now() - start >= PARK_MAX_SECONDS:
            raise ConfigError(f"the joints to park did not get there: {names} are "
                              f"{np.round(error, 3).tolist()} rad off (tolerance "
                              f"{PARK_TOLERANCE} rad); is something in the way?")
        if not np.isnan(worst):
            best = worst


def dclaw_park(hand_joints: Sequence[str], logged: Sequence[str]) -> dict[str, float]:
    """Where the D'Claw's other fingers wait while ``logged`` joints are identified: swung out
    (middle joint -1.0 rad), which clears the logged finger's workspace except for the corners
    where it reaches the other fingers' bases (< 0.5 % of a 13^3 grid over 0.8 of its limits)."""
    fingers = {j.split("_")[0] for j in logged}
    return {j: -1.0 for j in hand_joints
            if j.endswith("_middle") and j.split("_")[0] not in fingers}


def identification_logs(robot: Robot, joints: Sequence[str], out_dir: str | Path, logs: int,
                        seconds: float, rng: np.random.Generator, margin: float = 0.8,
                        on_step: Callable[[int], None] | None = None, model: Any = None,
                        park: Mapping[str, float] | None = None, missed_retries: int = 2
                        ) -> list[Path]:
    """Record ``logs`` identification logs of ``seconds`` each on ``joints`` into ``out_dir``.

    Each log is a fresh random excitation (``lowcostdex.gap.generate.excitation``: steps
    approached from both sides, slow ramps, chirps) within ``margin`` times each joint's limits,
    sent at the robot's control rate. Use a control period of 10-20 ms and a per-step motion
    bound wide enough for steps (``RobotConfig(control_period=0.02, motion_scale=10)``): the
    steps are what make latency and backlash identifiable.

    Args:
      park: other joints moved to these positions [rad] first and held there (torque on), e.g.
        ``dclaw_park``: the neighbours out of the logged finger's way.
      model: the robot's MJCF model; with it, excitation poses that would touch anything are
        pulled in (``contact_free``), the parked joints at their park positions.
      missed_retries: a log during which a position reading was missed (a reply lost or late:
        its row would hold NaN, which the gap analysis refuses) is recorded again, the same
        excitation, at most this many times.

    Raises:
      BusError: a log still missed readings after ``missed_retries`` more recordings.
    """
    from lowcostdex.gap.generate import excitation

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    idx = robot.index(joints)
    low, high = margin * robot.low[idx], margin * robot.high[idx]
    period = robot.config.control_period
    _park(robot, park)
    paths = []
    for k in range(logs):
        goals = excitation(rng, seconds, period, low, high)
        if model is not None:
            goals, _ = contact_free(model, joints, goals, park)
        path = out_dir / f"log_{k}.csv"
        trips: list[str] = []
        for _ in range(missed_retries + 1):
            try:
                traj = record(robot, joints, goals, path.stem, on_step)
            except WatchdogTripped as exc:
                # the host fell silent for longer than the Bus Watchdog (a stalled machine): the
                # motors stopped where they were. Hold the parked joints again, record again.
                trips.append(str(exc))
                log.warning("identification log %d: %s; recording it again", k, exc)
                _park(robot, park)
                continue
            if np.all(np.isfinite(traj.qpos)):  # a missed velocity read keeps its row
                break
        else:
            why = (f"; {len(trips)} of them stopped by the bus watchdog (the host was silent "
                   f"too long: a loaded machine?): {trips[-1]}") if trips else ""
            raise BusError(f"identification log {k}: readings were missed in each of "
                           f"{missed_retries + 1} recordings (the gap analysis needs every "
                           "sample; a log with gaps is recorded again). Check the cabling and "
                           "the adapter's latency (a pty or an adapter whose latency timer "
                           f"cannot be read: pass latency_ms=16){why}")
        paths.append(write_log(path, traj))
    return paths


def dclaw_identification_logs(hand: Any, joints: Sequence[str], out_dir: str | Path, logs: int,
                              seconds: float, rng: np.random.Generator, *,
                              port: str | None = None, effects: Sequence[Any] = (),
                              emulator_rng: np.random.Generator | None = None,
                              rate: float = 50.0, baudrate: int = 1_000_000,
                              latency_ms: float | None = None,
                              on_step: Callable[[int], None] | None = None) -> list[Path]:
    """``identification_logs`` of ``joints`` on a D'Claw without its station: on the real one at
    ``port``, or (``port=None``) on an emulated one carrying the servo ``effects``
    (``AppliedEffect``s; ``emulator_rng`` seeds its noise). The other fingers are parked
    (``dclaw_park``), poses that would touch anything are pulled in (``contact_free``), and the
    per-step motion bound is 10x a policy's (steps excite latency and backlash; the joint limits
    still hold). ``rate`` is the control rate [Hz]; ``latency_ms`` the USB latency timer the
    driver's timeouts assume when it cannot read it [ms] (None: the driver's default; 16 for a
    pty served by ``lowcostdex emulate`` on a loaded machine)."""
    from lowcostdex.hardware.robot.backend import make_dynamixel_bus, robot_hand
    from lowcostdex.hardware.robot.robot import RobotConfig
    from lowcostdex.sim.models.dclaw import build_dclaw

    model = build_dclaw("none", hand).compile()
    h = robot_hand(hand, model)
    if port is None:
        from lowcostdex.hardware.emulated.chain import emulated_dclaw

        chain = emulated_dclaw("none", hand=hand, effects=list(effects),
                               rng=emulator_rng or np.random.default_rng(0))
        bus_port: Any = chain.port()
    else:
        bus_port = port
    extra = {} if latency_ms is None else {"latency_ms": latency_ms}
    bus = make_dynamixel_bus(h, bus_port, model, baudrate=baudrate, **extra)
    robot = Robot(h, bus, RobotConfig(control_period=1.0 / rate, motion_scale=10.0))
    with robot:
        return identification_logs(robot, joints, out_dir, logs, seconds, rng, on_step=on_step,
                                   model=model, park=dclaw_park(hand.joint_names, joints))


def allegro_identification_logs(hand: Any, joints: Sequence[str], out_dir: str | Path,
                                logs: int, seconds: float, rng: np.random.Generator, *,
                                channel: str | None = None, interface: str = "socketcan",
                                effects: Sequence[Any] = (),
                                emulator_rng: np.random.Generator | None = None,
                                rate: float = 50.0,
                                on_step: Callable[[int], None] | None = None) -> list[Path]:
    """``identification_logs`` of ``joints`` on an Allegro hand without its station: on a real
    one on the CAN ``channel`` (python-can ``interface``), or (``channel=None``) on an emulated
    one (``allegro.emulator.emulated_allegro``, lock-step virtual time) carrying ``effects``
    (``AppliedEffect``s; ``emulator_rng`` seeds its noise). The other joints hold their
    power-up pose; poses that would touch anything are pulled in (``contact_free``); goals are
    rate-limited from the previous goal (the Allegro's soft joints, as ``ALLEGRO_ROBOT``) with a
    10x wider per-step bound than a policy's. ``rate`` is the control rate [Hz]."""
    from lowcostdex.hardware.robot.allegro_backend import ALLEGRO_ROBOT
    from lowcostdex.hardware.robot.robot import RobotConfig
    from lowcostdex.sim.models.allegro import build_allegro

    model = build_allegro("none", hand).compile()
    config = RobotConfig(control_period=1.0 / rate, motion_scale=10.0,
                         motion_reference=ALLEGRO_ROBOT.motion_reference)
    emulator = None
    if channel is None:
        from lowcostdex.hardware.allegro.emulator import emulated_allegro

        bus, emulator, _ = emulated_allegro(model, effects=list(effects), hand=hand,
                                            rng=emulator_rng or np.random.default_rng(0))
    else:
        from lowcostdex.hardware.allegro.driver import AllegroBus

        bus = AllegroBus(interface=interface, channel=channel, hand=hand)
    try:
        with Robot(hand, bus, config) as robot:
            return identification_logs(robot, joints, out_dir, logs, seconds, rng,
                                       on_step=on_step, model=model)
    finally:
        if emulator is not None:
            emulator.close()
