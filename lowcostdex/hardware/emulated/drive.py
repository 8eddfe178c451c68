"""The physics behind the emulated firmware: ``PlantDrive`` drives a plant's dcmotor actuators with
the motors' setpoints and gains and reads back what encoders and sensors see; firmware behaviour
outside the effect catalogue enters as an ``Imperfection``.

Time between physics steps. The physics steps on its grid (``model.opt.timestep``, 2.5 ms for the
D'Claw), but packets arrive at any instant of the bus clock, and a real servo samples and applies
within its own ~1 ms control period. So the chain integrates the physics to a read's arrival (a
partial step, ``step(h)``) before the motors sample; a setpoint that changes part of the way into a
step drives that step for the rest of it only (the step's ctrl is the time-weighted mean of the
setpoints in force during it: the servo loop is linear in its setpoint, so this is the impulse of
switching at that instant, as ``lowcostdex.gap.replay`` replays logged goals); other instructions
see the state carried forward to their arrival at the joint velocities (``state_at``, first
order). Before, a goal acted from the last grid point before its arrival and a read returned that
point's state: a control loop phase-locked to the grid saw a hidden latency of up to one step
that changed with the packet lengths (tests/test_dxl_emulator.py, test_trace.py's noise floor).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lowcostdex.errors import MAX_CONTROL, ConfigError, check_number
from lowcostdex.sim import servo
from lowcostdex.sim.plant import Plant
from lowcostdex.sim.servo import servo_supply_voltage


@dataclass
class _State:
    """``firmware.DriveState`` as plain float lists (fast scalar access per motor)."""

    q: list[float]
    qd: list[float]
    current: list[float]
    duty: list[float]
    temperature: list[float]
    voltage: list[float]
    step: int


class ServoImperfection(Protocol):
    """Servo firmware behaviour outside the effect catalogue, bound to the drive's servos (e.g.
    a hidden robot's PWM deadband or encoder nonlinearity: ``lowcostdex.hardware.emulated.hidden_robots``).
    Arrays are per servo in drive order, joint angles [rad]."""

    def encoder(self, q: np.ndarray) -> np.ndarray:
        """What the encoders read (n,) at true joint angles ``q`` (n,)."""

    def command(self, goal: np.ndarray, q: np.ndarray) -> np.ndarray:
        """The setpoint the physics' servo loop tracks (n,) for firmware setpoints ``goal``
        (n,) [encoder frame] with the joints at true angles ``q`` (n,)."""


class Imperfection(Protocol):
    """Unbound ``ServoImperfection``: ``bind(joints)`` gives the one for those servos."""

    def bind(self, joints: Sequence[str]) -> ServoImperfection: ...


class PlantDrive:
    """The physics behind emulated firmware: servo k drives ``plant`` actuator ``actuators[k]``.

    Args:
      plant: the plant (its model's dcmotor actuators are the servos).
      actuators: actuator index per servo.
      motors: servo model per servo (for the gain mapping).
      supply_resistance: shared supply's internal resistance [Ohm]: every motor reads
        V = V_nominal - R_s * sum |i| (voltage sag). Add the ``voltage_sag`` effect to the plant if
        the physics should feel it too.
      imperfection: firmware behaviour no catalogue effect models (``ServoImperfection``), applied
        between the firmware and the physics every step; None: none.
    """

    def __init__(self, plant: Plant, actuators: Sequence[int], motors: Sequence[servo.MotorSpec],
                 supply_resistance: float = 0.0, imperfection: ServoImperfection | None = None):
        m = plant.model
        self.plant = plant
        self.acts = np.asarray(actuators, dtype=int)
        self.motors = list(motors)
        check_number("supply_resistance [Ohm]", supply_resistance, 0)  # (-1 and NaN were run)
        self.supply_resistance = supply_resistance
        self.imperfection = imperfection
        jnt = m.actuator_trnid[self.acts, 0]
        self._qadr = m.jnt_qposadr[jnt]
        self._dadr = m.jnt_dofadr[jnt]
        self._layout = servo.dcmotor_act_layout(m)
        self._integrator = self._layout[self.acts, servo.ACT_INTEGRATOR]
        self._thermal = self._layout[self.acts, servo.ACT_THERMAL]
        self._ambient = m.actuator_dynprm[self.acts, servo.DYN_TAMB].copy()
        self._v_nominal = servo_supply_voltage(m)
        if np.any(self._v_nominal[self.acts] <= 0):
            raise ConfigError("every emulated servo needs a supply voltage (servo.add_servo)")
        d = plant.data  # views stay valid: MjData/MjModel arrays are never reallocated
        self._views = {"qpos": d.qpos, "qvel": d.qvel, "force": d.actuator_force, "act": d.act,
                       "gain": m.actuator_gainprm}
        if m.na == 0:
            self._views["act"] = np.zeros(1)
        self.goal = np.array(plant.ctrl, copy=True)  # (nu,) [rad] setpoints in force now
        self._step_goal = self.goal.copy()  # (nu,) [rad] the coming step's mean setpoint
        # encoder errors the emulated robot carries (offset, noise, quantization) reach the wire
        self._observed = any(e.cls.kind in ("observation", "calibration") for e in plant.effects)
        self.steps = 0
        self._state: _State | None = None

    def set_torque(self, index: int, enabled: bool) -> None:
        a = int(self.acts[index])
        if enabled and self._integrator[index] >= 0:
            self.plant.data.act[self._integrator[index]] = 0.0
        self.plant.set_torque_enabled([a], enabled)
        self._state = None

    def set_gains(self, index: int, gains: servo.ServoGains) -> None:
        p = servo.dcmotor_params(self.motors[index], gains)
        ki = max(p.ki, servo.KI_MIN) if self._integrator[index] >= 0 else 0.0
        cols = [servo.GAIN_KP, servo.GAIN_KI, servo.GAIN_KD, servo.GAIN_VMAX]
        self.plant.set_nominal("actuator_gainprm", (int(self.acts[index]), cols),
                               [p.kp, ki, p.kd, p.vmax])
        self._state = None

    def set_goal(self, index: int, q: float, after: float = 0.0) -> None:
        """Servo ``index``'s setpoint becomes ``q`` [rad] ``after`` (0..1) of the way into the
        coming physics step: the step is driven by the time-weighted mean of the setpoints in
        force during it."""
        if not abs(q) <= MAX_CONTROL:  # (the step below is unchecked: NaN zeroes every control)
            raise ConfigError(f"servo {index}'s goal {q!r} [rad] must be a finite number")
        a = self.acts[index]
        self._step_goal[a] += (1.0 - after) * (q - self.goal[a])
        self.goal[a] = q

    def true_position(self, index: int, ahead: float = 0.0) -> float:
        """Servo ``index``'s joint angle in the physics [rad] (no encoder effects), ``ahead`` [s]
        past the last step (carried forward at the joint velocity)."""
        q = float(self._views["qpos"][self._qadr[index]])
        return q + ahead * float(self._views["qvel"][self._dadr[index]]) if ahead else q

    def voltage(self) -> np.ndarray:
        """Supply voltage at every actuator [V] (nu,)."""
        v = self._v_nominal.copy()
        if self.supply_resistance > 0:
            k = self.plant.model.actuator_gainprm[self.acts, servo.GAIN_K]
            i = self.plant.actuator_force[self.acts] / k
            v = v - self.supply_resistance * float(np.sum(np.abs(i)))
        return v

    def state(self) -> _State:
        if self._state is not None and self._state.step == self.steps:
            return self._state
        v = self._views
        a = self.acts
        qd = v["qvel"][self._dadr]
        k, r = v["gain"][a, servo.GAIN_K], v["gain"][a, servo.GAIN_R]
        current = v["force"][a] / k
        volts = self._v_nominal[a] if self.supply_resistance <= 0 else self.voltage()[a]
        duty = (r * current + k * qd) / volts
        temp = self._ambient + v["act"][self._thermal] * (self._thermal >= 0)
        qpos = self.plant.measured_qpos() if self._observed else v["qpos"]
        q = qpos[self._qadr]
        if self.imperfection is not None:
            q = self.imperfection.encoder(q)
        self._state = _State(q.tolist(), qd.tolist(), current.tolist(),
                             duty.tolist(), temp.tolist(), volts.tolist(), self.steps)
        return self._state

    def state_at(self, ahead: float) -> _State:
        """``state()`` ``ahead`` [s] (less than a step) past the last physics step: the joint
        positions carried forward at the joint velocities (first order); velocities, currents,
        duty, temperatures and voltages as at the step."""
        s = self.state()
        if ahead <= 0.0:
            return s
        return _State([q + ahead * v for q, v in zip(s.q, s.qd, strict=True)], s.qd, s.current,
                      s.duty, s.temperature, s.voltage, s.step)

    def step(self, h: float | None = None) -> None:
        """One physics step of ``h`` [s] (default the model's timestep; less: a partial step to
        an instant between two grid points) driven by the mean of the setpoints in force during it (``set_goal``;
        exogenous channels from the present readings)."""
        channels = None
        if self.plant.required_channels:
            m, d = self.plant.model, self.plant.data
            channels = {"temperature": servo.winding_temperature(m, d, self._layout),
                        "voltage": self.voltage()}
        goal = self._step_goal
        if self.imperfection is not None:
            goal = goal.copy()
            goal[self.acts] = self.imperfection.command(goal[self.acts],
                                                        self._views["qpos"][self._qadr])
        opt = self.plant.model.opt
        dt = opt.timestep
        if h is not None and h != dt:
            opt.timestep = h
        try:  # goals from set_goal (checked), an imperfection's through the checked step
            (self.plant.step if self.imperfection is not None else self.plant.step_unchecked)(
                goal, 1, channels)
        finally:
            opt.timestep = dt
        self._step_goal[:] = self.goal
        self.steps += 1
