"""An emulated Allegro Hand v4 on python-can's ``virtual`` interface, MuJoCo behind it.

``EmulatedAllegro`` answers the v4 CAN protocol (``allegro_can``) like the hand's firmware:
HAND_INFO, SERIAL, FINGER_POSE and TEMPERATURE remote requests, SET_PERIOD, SYSTEM_ON/OFF,
SET_TORQUE, and the position stream (four FINGER_POSE frames per period, TEMPERATURE frames at
their own period if one is set). TEMPERATURE frames carry 4 bytes, one unsigned byte per joint
[deg C], as a real v4 hand's do; HAND_INFO answers with the identity of the hand in Meta's
published trace (hardware 0x0402, firmware 0x0406, right hand) unless ``info`` is changed. The
PWM it receives becomes joint torque (``pwm / 1200`` N m on a v4 hand, ``/ 800`` on a v3 hand)
applied to the model's joints through ``qfrc_applied``; the model's own actuators are switched
off (the hand is torque-driven).
A per-joint winding thermal model heats with torque squared; above its limit the firmware sets
the high-temperature status bit and drops torque until it has cooled and is switched on again.
Every torque the device applies is logged (``torque_log``) so tests check what reached it; the
log keeps the newest ``TORQUES_KEPT`` cycles (a ring buffer: an hours-long run holds bounded
memory).

Time: ``LockstepClock`` is a virtual clock: ``sleep(dt)`` runs the emulated hand period by
period and lets the driver answer each pose set, in one thread, deterministically and faster
than real time. ``serve`` runs the hand in real time in a thread instead (the driver then uses
``threaded=True``).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

import can
import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_number
from lowcostdex.hands import HandSpec, allegro_spec
from lowcostdex.hardware.allegro import protocol as proto
from lowcostdex.hardware.ringlog import RingLog
from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.plant import Plant

TORQUES_KEPT = 1 << 16
"""Cycles of applied torque ``EmulatedAllegro.torque_log`` keeps: 3.3 min of the 3 ms stream,
~20 MB (unbounded, 3 h of training would hold ~1 GB)."""


@dataclass(frozen=True)
class AllegroThermal:
    """Per-joint motor thermal model: C dT/dt = heat * tau^2 - (T - ambient) / resistance.

    Attributes:
      heat: copper loss per squared torque [W/(N m)^2].
      resistance: thermal resistance to ambient [K/W].
      capacitance: heat capacity [J/K].
      ambient: [deg C].
      limit: firmware high-temperature fault threshold [deg C].
      rearm: the fault clears below ``limit - rearm`` on the next SYSTEM_ON [K].
    """

    heat: float = 40.0
    resistance: float = 10.0
    capacitance: float = 5.0
    ambient: float = 25.0
    limit: float = 70.0
    rearm: float = 5.0

    def __post_init__(self) -> None:
        for name in ("heat", "resistance", "capacitance"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"AllegroThermal.{name} must be > 0")


class EmulatedAllegro:
    """The hand's firmware and physics behind a CAN bus.

    Args:
      model: a compiled model with the hand spec's 16 joints (any actuators are disabled).
      can_bus: the emulator's end of the bus; default a new ``virtual`` bus on ``channel``.
      channel: virtual channel name (the driver opens a bus on the same name).
      hand: the hand spec.
      device_id: the hand's 2-bit CAN id.
      effects: servo effects applied to the physics (e.g. joint friction).
      thermal: the thermal model.
      rng: generator for noise effects.
      torques_kept: cycles of applied torque ``torque_log`` keeps (the newest).
    """

    def __init__(self, model: mujoco.MjModel, *, can_bus: can.BusABC | None = None,
                 channel: str = "lowcostdex-allegro", hand: HandSpec | None = None,
                 device_id: int = 0, effects: Sequence[AppliedEffect] = (),
                 thermal: AllegroThermal = AllegroThermal(),
                 rng: np.random.Generator | None = None, torques_kept: int = TORQUES_KEPT):
        check_number("Allegro device_id (the hand's 2-bit CAN id)", device_id, 0, 3, integer=True)
        self.hand = hand or allegro_spec()
        self.plant = Plant(model, effects=effects, rng=rng)
        m = self.plant.model
        names = self.hand.joint_names
        self.dofs = np.array([m.jnt_dofadr[m.joint(n).id] for n in names])
        self.qpos_adr = np.array([m.jnt_qposadr[m.joint(n).id] for n in names])
        if m.nu:
            self.plant.set_torque_enabled(np.arange(m.nu), False)
        self.bus = can_bus or can.Bus(interface="virtual", channel=channel)
        self.channel = channel  # the virtual channel (when ``can_bus`` is None)
        self.device_id = device_id
        self.thermal = thermal
        # the identity of the v4 hand in Meta's trace (HAND_INFO 02 04 06 04 00 3C 05)
        self.info = proto.HandInfo(hardware_version=0x0402, firmware_version=0x0406, left=False,
                                   palm_temperature=int(thermal.ambient), status=0)
        self.serial = b"EMU00001"
        self.servo_on = False
        self.fault = False
        self.period_ms = (0, 0, 0)
        self.pwm = np.zeros(proto.N_JOINTS, int)
        self.temperature = np.full(proto.N_JOINTS, thermal.ambient)
        self.sensor_fault: dict[int, int] = {}  # joint -> byte a broken sensor sends instead
        self.step_hooks: list = []
        # (time [s], applied torques [N m])
        self.torque_log = RingLog(torques_kept, "EmulatedAllegro torques_kept")
        self.frames_in = 0
        self._since_temperature = 0.0
        self._owed = 0.0  # emulated time the physics has yet to step [s]

    # -- state access for tests and resets ----------------------------------------------------
    @property
    def time(self) -> float:
        """Emulated time [s]."""
        return self.plant.time

    @property
    def physics_time(self) -> float:
        """Time the physics has been stepped to [s] (the emulated time)."""
        return self.plant.time

    def add_step_hook(self, hook) -> None:
        """Call ``hook(emulator)`` at every cycle, before the motor torques are added: a hook
        writes external joint torques into ``plant.data.qfrc_applied`` (e.g. the virtual
        teacher's hand, ``lowcostdex.demonstrations.kinesthetic.VirtualTeacher``)."""
        self.step_hooks.append(hook)

    @property
    def qpos(self) -> np.ndarray:
        """Joint angles of the 16 joints [rad] (true, unquantized)."""
        return self.plant.data.qpos[self.qpos_adr].copy()

    def set_joint_positions(self, q: np.ndarray) -> None:
        """Place the joints at q (16,) [rad] at rest (test set-up)."""
        d = self.plant.data
        d.qpos[self.qpos_adr] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(self.plant.model, d)

    def _scale(self) -> tuple[float, int]:
        """(torque constant, PWM clamp) of the emulated hand's version (v4's if unknown)."""
        return proto.TORQUE_SCALES.get(self.info.major_version, proto.TORQUE_SCALES[4])

    def applied_torque(self) -> np.ndarray:
        """Torque the firmware applies now (16,) [N m]."""
        if not self.servo_on or self.fault:
            return np.zeros(proto.N_JOINTS)
        return proto.pwm_to_torque(self.pwm, self._scale()[0])

    # -- protocol -------------------------------------------------------------------------------
    def poll(self) -> None:
        """Handle every pending host frame."""
        while True:
            msg = self.bus.recv(timeout=0.0)
            if msg is None:
                return
            self.frames_in += 1
            self._handle(msg)

    def _reply(self, msg: can.Message) -> None:
        self.bus.send(msg)

    def _handle(self, msg: can.Message) -> None:
        cmd, dev = proto.split_id(msg.arbitration_id)
        if dev != self.device_id:
            return
        if msg.is_remote_frame:
            if cmd == proto.HAND_INFO:
                self._reply(proto.message(proto.HAND_INFO, self._info().pack(), dev))
            elif cmd == proto.SERIAL:
                self._reply(proto.message(proto.SERIAL, self.serial, dev))
            elif proto.FINGER_POSE <= cmd < proto.FINGER_POSE + 4:
                self._send_pose(cmd - proto.FINGER_POSE)
            elif proto.TEMPERATURE <= cmd < proto.TEMPERATURE + 4:
                self._send_temperature(cmd - proto.TEMPERATURE)
            return
        if cmd == proto.SYSTEM_ON:
            if self.fault and np.all(self.temperature < self.thermal.limit - self.thermal.rearm):
                self.fault = False
            self.servo_on = not self.fault
        elif cmd == proto.SYSTEM_OFF:
            self.servo_on = False
            self.pwm[:] = 0
        elif proto.SET_TORQUE <= cmd < proto.SET_TORQUE + 4 and len(msg.data) == 8:
            f = cmd - proto.SET_TORQUE
            lim = proto.pwm_limits(self._scale()[1])[4 * f:4 * f + 4]
            self.pwm[4 * f:4 * f + 4] = np.clip(proto.unpack4(msg.data), -lim, lim)
        elif cmd == proto.SET_PERIOD:
            self.period_ms = proto.parse_period(msg.data)

    def _info(self) -> proto.HandInfo:
        status = (proto.STATUS_SERVO_ON if self.servo_on else 0) | (
            proto.STATUS_HIGH_TEMPERATURE if self.fault else 0)
        return proto.HandInfo(self.info.hardware_version, self.info.firmware_version,
                              self.info.left, int(self.thermal.ambient), status)

    def _send_pose(self, finger: int) -> None:
        q = self.plant.measured_qpos()[self.qpos_adr[4 * finger:4 * finger + 4]]
        self._reply(proto.pose_message(finger, q, self.device_id))

    def _send_temperature(self, finger: int) -> None:
        t = self.temperature[4 * finger:4 * finger + 4]
        data = bytearray(proto.pack_temperatures(t))
        for j, byte in self.sensor_fault.items():  # a broken sensor's byte, the winding heats on
            if 4 * finger <= j < 4 * finger + 4:
                data[j - 4 * finger] = byte
        self._reply(proto.message(proto.TEMPERATURE + finger, bytes(data), self.device_id))

    # -- physics --------------------------------------------------------------------------------
    @property
    def cycle_period(self) -> float:
        """Length of one emulated cycle [s]: the pose period, or 3 ms when not streaming."""
        return (self.period_ms[0] or 3) * 1e-3

    def cycle(self) -> None:
        """One period: apply the torques, step the physics, update temperatures, stream."""
        dt = self.cycle_period
        m, d = self.plant.model, self.plant.data
        # whole physics steps that keep the physics in step with the wire (3 ms cycles of
        # 2.5 ms steps: 1, 1, 2, 1, 1, 2, ...)
        self._owed += dt
        nstep = int(math.floor(self._owed / m.opt.timestep + 0.5))
        self._owed -= nstep * m.opt.timestep
        tau = self.applied_torque()
        self.torque_log.append((self.time, tau.copy()))
        d.qfrc_applied[:] = 0.0
        for hook in self.step_hooks:
            hook(self)
        d.qfrc_applied[self.dofs] += tau
        if nstep > 0:
            self.plant.step(d.ctrl.copy(), nstep)
            self._heat(tau, nstep * m.opt.timestep)
        if self.period_ms[0] > 0:
            for f in range(proto.N_FINGERS):
                self._send_pose(f)
        if self.period_ms[2] > 0:
            self._since_temperature += dt
            if self._since_temperature >= self.period_ms[2] * 1e-3 - 1e-9:
                self._since_temperature = 0.0
                for f in range(proto.N_FINGERS):
                    self._send_temperature(f)

    def _heat(self, tau: np.ndarray, dt: float) -> None:
        th = self.thermal
        power = th.heat * tau * tau
        self.temperature += dt * (power - (self.temperature - th.ambient) / th.resistance) \
            / th.capacitance
        if np.any(self.temperature >= th.limit):
            self.fault = True
            self.servo_on = False

    # -- real time ------------------------------------------------------------------------------
    def serve(self, stop: threading.Event) -> None:
        """Run in real time until ``stop`` is set (call from a thread)."""
        next_t = time.monotonic()
        while not stop.is_set():
            self.poll()
            self.cycle()
            next_t += self.cycle_period
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.monotonic()

    def close(self) -> None:
        self.bus.shutdown()


class LockstepClock:
    """Virtual clock for an emulated Allegro and its driver(s) in one thread.

    ``sleep(dt)`` runs whole emulated cycles: the hand applies the torques it holds, steps the
    physics and streams poses; each driver handles the poses and answers with torques; the hand
    takes them for the next cycle (one period of actuation delay, as on the wire).
    """

    def __init__(self, emulator: EmulatedAllegro, drivers: Sequence = ()):
        self.emulator = emulator
        self.drivers = list(drivers)
        self._t = 0.0
        self._debt = 0.0

    def attach(self, driver) -> None:
        self.drivers.append(driver)

    def now(self) -> float:
        return self._t

    def sleep(self, seconds: float) -> None:
        if not seconds > 0 or not math.isfinite(seconds):
            return
        self._t += seconds
        self._debt += seconds
        period = self.emulator.cycle_period
        while self._debt >= period - 1e-12:
            self._debt -= period
            self.emulator.poll()
            self.emulator.cycle()
            for drv in self.drivers:
                drv.poll()
            self.emulator.poll()


def emulated_allegro(model: mujoco.MjModel | None = None, *, channel: str | None = None,
                     effects: Sequence[AppliedEffect] = (),
                     thermal: AllegroThermal = AllegroThermal(),
                     rng: np.random.Generator | None = None, **bus_kwargs):
    """An ``AllegroBus`` wired to an ``EmulatedAllegro`` on a private virtual channel.

    Returns (bus, emulator, clock); the bus is not connected yet; ``rng`` feeds noise effects.
    ``model`` defaults to the
    Allegro of ``lowcostdex.sim.models.allegro`` without a station (its position actuators are
    switched off: the emulated firmware applies the host's torques).
    """
    import inspect

    from lowcostdex.hardware.allegro.driver import AllegroBus

    taken = set(inspect.signature(AllegroBus).parameters) - {"can_bus", "threaded", "clock",
                                                               "own_bus"}
    unknown = sorted(set(bus_kwargs) - taken)
    if unknown:  # before any CAN bus opens: refused afterwards, two virtual buses were left open
        raise TypeError(f"emulated_allegro() got an unexpected keyword argument '{unknown[0]}'")
    if model is None:
        from lowcostdex.sim.models.allegro import build_allegro

        model = build_allegro("none").compile()
    channel = channel or f"lowcostdex-allegro-{id(model):x}-{time.monotonic_ns()}"
    emulator = EmulatedAllegro(model, channel=channel, hand=bus_kwargs.get("hand"),
                               device_id=bus_kwargs.get("device_id", 0),  # (was always 0)
                               effects=effects, thermal=thermal, rng=rng)
    clock = LockstepClock(emulator)
    host = can.Bus(interface="virtual", channel=channel)
    try:
        bus = AllegroBus(host, threaded=False, clock=clock, own_bus=True, **bus_kwargs)
    except Exception:  # a refused setting: no virtual bus left open
        host.shutdown()
        emulator.bus.shutdown()
        raise
    clock.attach(bus)
    return bus, emulator, clock
