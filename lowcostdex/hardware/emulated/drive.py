"""The physics behind the emulated firmware: ``PlantDrive`` drives a plant's dcmotor actuators with
the motors' setpoints and gains and reads back what encoders and sensors see; firmware behaviour
outside the effect catalogue enters as an ``Imperfection``."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.sim import servo
from lowcostdex.sim.plant import Plant, servo_supply_voltage


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
        self.goal = np.array(plant.ctrl, copy=True)  # (nu,) [rad]
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

    def set_goal(self, index: int, q: float) -> None:
        self.goal[self.acts[index]] = q

    def true_position(self, index: int) -> float:
        """Servo ``index``'s joint angle in the physics [rad] (no encoder effects)."""
        return float(self._views["qpos"][self._qadr[index]])

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

    def step(self) -> None:
        """One physics step holding ``goal`` (exogenous channels from the present readings)."""
        channels = None
        if self.plant.required_channels:
            m, d = self.plant.model, self.plant.data
            channels = {"temperature": servo.winding_temperature(m, d, self._layout),
                        "voltage": self.voltage()}
        goal = self.goal
        if self.imperfection is not None:
            goal = goal.copy()
            goal[self.acts] = self.imperfection.command(goal[self.acts],
                                                        self._views["qpos"][self._qadr])
        self.plant.step(goal, 1, channels)
        self.steps += 1
