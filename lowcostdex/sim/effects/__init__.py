"""Unmodeled servo effects as first-class objects, one catalogue for every layer.

The simulator, the emulated bus, domain randomization and the gap analysis all use these classes:
an effect has a canonical name, named parameters with a null value (effect absent), fit bounds and
a domain-randomization range, and knows how to extend a servo-driven MuJoCo model. How it acts:

  ``model``       writes MjModel fields (damping, frictionloss, gains, delay, mass, ...), relative
                  to the nominal values, per simulation when the plant is batched;
  ``friction``    adds a state-dependent dry-friction level every physics substep
                  (Stribeck, load-dependent);
  ``command``     transforms the goal position before it reaches the servo (action noise; backlash
                  without its play hinge);
  structural      (backlash) adds degrees of freedom to a model prepared with hidden dofs
                  (``prepare``; the qpos layout changes) and writes their fields (``apply``);
  ``observation`` transforms what the encoder reports (offset, noise, quantization);
  ``calibration`` both: the servo's own encoder frame is shifted from the model's joint, so the
                  servo holds goals in its frame and reports readings in it (mounting offset);
  ``exogenous``   rescales gains from a measured channel each control step (temperature, voltage).

Values are arrays over the effect's targets (actuated joints): shape (n,) for one simulation or
(nsim, n) for a batch. Effects never hold state; the ``Plant`` (``lowcostdex.sim.plant``) owns
per-rollout state (the play operator's setpoint) and calls these pure functions; a backlash's
play hinge is physical state of the model (see ``Backlash``).

Magnitudes: ``Param.dr`` holds plausible D'Claw ranges (04-sysid.md section 6; ROBEL
RandomDynamics; OpenAI Table 1); ``low``/``high`` are wider fit bounds covering real-world sizes
(issue 11: latency to 80 ms, offsets to +-0.2 rad, gains 0.3-3x, ...); ``limit`` is the physical
hard limit a fit may widen its range to when it lands on ``low``/``high`` (latency 0.25 s; offsets
+-0.8 rad; scale factors 0.02-50 ... 0.1-10; friction shares below 1).
"""


from lowcostdex.sim.effects.base import (
    DEFAULT_REFERENCE_TEMPERATURE,
    Effect,
    Fields,
    Param,
    Targets,
    Values,
)
from lowcostdex.sim.effects.catalogue import (
    CAUSES,
    EFFECTS,
    OPT_IN,
    ActionNoise,
    Backlash,
    CoulombFriction,
    Deadband,
    GainError,
    GearboxFriction,
    GoalProfile,
    InertiaError,
    Latency,
    LoadDependentFriction,
    MassError,
    MotorStrength,
    MountingOffset,
    ObservationNoise,
    PositionOffset,
    Quantization,
    StribeckFriction,
    ThermalDerating,
    TorqueLimit,
    VelocityLimit,
    ViscousDamping,
    VoltageSag,
    effect,
)
from lowcostdex.sim.effects.randomization import (
    DEFAULT_DR_EFFECTS,
    AppliedEffect,
    DomainRandomization,
    SampleFn,
)
from lowcostdex.sim.effects.sensor_scale import SensorScale

__all__ = [
    "CAUSES", "DEFAULT_DR_EFFECTS", "DEFAULT_REFERENCE_TEMPERATURE", "EFFECTS", "ActionNoise",
    "AppliedEffect", "Backlash", "CoulombFriction", "Deadband", "DomainRandomization", "Effect", "Fields",
    "GainError", "GearboxFriction", "InertiaError", "Latency", "LoadDependentFriction", "MassError",
    "GoalProfile",
    "MotorStrength", "MountingOffset", "OPT_IN", "ObservationNoise", "Param", "PositionOffset",
    "Quantization",
    "SampleFn", "SensorScale", "StribeckFriction", "Targets", "ThermalDerating", "TorqueLimit",
    "VelocityLimit",
    "ViscousDamping", "Values", "VoltageSag", "effect",
]
