"""The single-servo test bench: a servo swinging an arm with a point load (BAM's pendulum rig).

Conventions follow BAM's test bench (07-measured-data.md section 4): one hinge about +x at the
origin, gravity along -z, the arm hanging along -z, so theta = 0 is the arm hanging down and
positive is counter-clockwise seen from +x. A point load ``mass`` sits at ``length`` and the arm is
a uniform rod of ``arm_mass``:

    J = mass * length^2 + arm_mass * length^2 / 3                    [kg m^2] (about the pivot)
    tau_gravity = -(mass + arm_mass / 2) * g * length * sin(theta)   [N m]

The body's inertial is explicit (total mass, centre of mass on the arm, inertia about the centre
of mass = J - M z_com^2), so MuJoCo reproduces the analytic bench exactly; geoms are visual only.
The servo is ``lowcostdex.sim.servo``'s dcmotor model; the motor's reflected rotor inertia is the
joint armature. Names: joint and actuator ``BENCH_JOINT`` ("arm").
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco

from lowcostdex.errors import ConfigError, keyword_hints
from lowcostdex.sim import servo
from lowcostdex.sim.models.common import TIMESTEP, new_spec, visual_only

BENCH_JOINT = "arm"
_MIN_INERTIA = 1e-9  # [kg m^2] a point load has none about its own centre; MuJoCo needs > 0


@keyword_hints
@dataclass(frozen=True)
class BenchConfig:
    """A servo bench setup.

    Attributes:
      motor: servo model name (``servo.MOTORS``) or a ``MotorSpec``.
      mass: point load at the arm tip [kg].
      length: pivot-to-load distance [m].
      arm_mass: uniform arm rod mass [kg].
      gains: firmware gains in device units; None = the motor's default P gain and duty ceiling.
      supply: supply voltage [V]; None = the motor's nominal voltage.
      damping: joint viscous damping besides the servo's back-EMF [N m s/rad].
      frictionloss: joint dry friction [N m].
      timestep: physics step [s].
      thermal: model winding temperature (one activation per servo).
    """

    motor: str | servo.MotorSpec = "XL330-M288"
    mass: float = 0.2
    length: float = 0.1
    arm_mass: float = 0.0
    gains: servo.ServoGains | None = None
    supply: float | None = None
    damping: float = 0.0
    frictionloss: float = 0.0
    timestep: float = TIMESTEP
    thermal: bool = False

    def __post_init__(self) -> None:
        if not self.mass > 0:
            raise ConfigError(f"bench mass must be > 0 kg, got {self.mass}")
        if not self.length > 0:
            raise ConfigError(f"bench length must be > 0 m, got {self.length}")
        for name in ("arm_mass", "damping", "frictionloss"):
            if getattr(self, name) < 0:
                raise ConfigError(f"bench {name} must be >= 0, got {getattr(self, name)}")
        if self.supply is not None and not self.supply > 0:
            raise ConfigError(f"bench supply must be > 0 V, got {self.supply}")
        if not self.timestep > 0:
            raise ConfigError(f"bench timestep must be > 0 s, got {self.timestep}")

    @property
    def motor_spec(self) -> servo.MotorSpec:
        return self.motor if isinstance(self.motor, servo.MotorSpec) else servo.motor_spec(
            self.motor)

    @property
    def pivot_inertia(self) -> float:
        """Load and arm inertia about the pivot [kg m^2] (rotor armature excluded)."""
        return self.mass * self.length**2 + self.arm_mass * self.length**2 / 3.0

    @property
    def gravity_arm(self) -> float:
        """(mass + arm_mass / 2) * length [kg m]: gravity torque = -g * this * sin(theta)."""
        return (self.mass + 0.5 * self.arm_mass) * self.length

    def servo_gains(self) -> servo.ServoGains:
        m = self.motor_spec
        g = self.gains or m.factory_gains().replace(pwm_limit=round(m.max_duty * m.pwm_max))
        if self.supply is not None:
            g = g.replace(supply_voltage=self.supply)
        return g


def build_bench(config: BenchConfig | None = None, **kwargs) -> mujoco.MjSpec:
    """Build the bench as an MjSpec (compile with ``spec.compile()``).

    Args:
      config: the setup; or pass ``BenchConfig`` fields as keyword arguments.
    """
    if config is None:
        config = BenchConfig(**kwargs)
    elif kwargs:
        raise ConfigError("pass either a BenchConfig or keyword fields, not both")
    c = config
    spec = new_spec("servo_bench", timestep=c.timestep)
    total = c.mass + c.arm_mass
    z_com = -(c.mass * c.length + 0.5 * c.arm_mass * c.length) / total
    i_com = max(c.pivot_inertia - total * z_com**2, _MIN_INERTIA)
    arm = spec.worldbody.add_body(name="arm")
    arm.explicitinertial = True
    arm.mass = total
    arm.ipos = [0.0, 0.0, z_com]
    arm.inertia = [i_com, i_com, _MIN_INERTIA]
    j = arm.add_joint(name=BENCH_JOINT, type=mujoco.mjtJoint.mjJNT_HINGE, axis=[1, 0, 0])
    j.damping[0] = c.damping
    j.frictionloss = c.frictionloss
    j.armature = 0.0  # the servo adds its reflected rotor inertia
    visual_only(arm.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.005, 0, 0],
                             fromto=[0, 0, 0, 0, 0, -c.length], rgba=[0.6, 0.6, 0.6, 1]))
    visual_only(arm.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.015, 0, 0],
                             pos=[0, 0, -c.length], rgba=[0.8, 0.3, 0.2, 1]))
    servo.add_servo(spec, BENCH_JOINT, c.motor_spec, c.servo_gains(), thermal=c.thermal)
    return spec
