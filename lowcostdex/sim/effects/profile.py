"""A servo firmware's motion profile on the goal: ``goal_profile`` (Dynamixel Profile Velocity /
Profile Acceleration, velocity-based), on every actuator that takes a position goal.

A Dynamixel X servo with Profile Velocity (register 112, 0.229 rev/min per unit) and Profile
Acceleration (108, 214.577 rev/min^2 per unit) set does not chase a written goal at once: its
firmware moves an internal setpoint toward it at most at the profile velocity, changing speed at
most at the profile acceleration (a trapezoid; a triangle when the move is short; a rectangle
with acceleration 0; no profile with velocity 0), and its position loop acts on that setpoint
(e-manual, "Profile Velocity"; 05-dynamixel-protocol.md; 04-sysid.md section 6: "ramped response
independent of load; identical shape across loads; confusable with saturation, delay"). A log
holds the raw goal the user wrote, so an open-loop replay of the user's model steps where the
servo ramps. LeRobot and ROBEL-style code write these registers; a smooth trapezoid is a new
user's usual first setting.

The effect is of kind ``command``: each control (replay: physics) step of ``dt`` s it moves the
profile's setpoint p and speed w toward the goal g (e = g - p):

    w'   = w + clip(u - w, +-acceleration dt)  toward g, u = min(velocity, the fastest end-of-step
           speed from which braking at the acceleration still stops on g: u^2 = 2 acceleration
           (|e| - (w + u) dt / 2))
    p   <- p + (w + w') dt / 2 (a rectangle: p + w' dt), w <- w'; snapped to g (w to 0) once
           the step reaches it

and the servo receives the mean of p over the step ((p_before + p_after) / 2: the servo's law
acts on the setpoint all through the step; the end value would lead it by dt / 2). Velocity and
acceleration are in joint units (rad/s, rad/s^2); on a Dynamixel, Profile Velocity = velocity /
(0.229 x 2 pi / 60) and Profile Acceleration = acceleration / (214.577 x 2 pi / 3600). Null
(off, the registers' 0): inf; 0 is taken as off too, as on the servo.

Why not the servo model's own slew (``goal_slew``, the dcmotor's compiled ``slewmax``): MuJoCo 4
slews the goal natively only for ``dcmotor`` (and ``pid``) actuators compiled with one, a state of
the compiled model with no acceleration limit; a user's ``position`` or ``general`` actuator has
none. ``goal_slew`` scales a servo's compiled slew (a Feetech STS's Running Speed); this effect is
a profile the user's model does not have, on any actuator kind (on a dcmotor compiled with a slew
both act: the slower wins).

The profile's state is per rollout (``Plant`` keeps it; ``reset_effect_state`` forgets it). At a
(re)start it is the setpoint the servo holds (``state["setpoint"]``) at rest, or, when the joint
moves faster than ``MOVING`` rad/s (a replay window started mid-move), the joint's angle and
speed (clipped to the profile velocity): the profile leads the joint by only a tracking error.

Confusable family: ``velocity_limit`` (a torque-speed line also caps the speed, but by the torque:
slower against a load, faster with it), ``torque_limit`` (saturation: the speed plateau depends on
the load and the step), ``latency`` (a ramp looks like a lag on small steps).
"""

from __future__ import annotations

import math

import numpy as np

from lowcostdex.sim.effects.base import Effect, Param, Targets, Values

MOVING = 0.1  # rad/s: a (re)start faster than this starts the profile at the joint, not the goal


def profile_step(p: np.ndarray, w: np.ndarray, goal: np.ndarray, velocity: np.ndarray,
                 acceleration: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """One step of ``dt`` s of the velocity-based profile: setpoint ``p`` [rad] and its speed
    ``w`` [rad/s] toward ``goal`` [rad] (arrays broadcast together) at most at ``velocity``
    [rad/s] and ``acceleration`` [rad/s^2] (inf or 0: unlimited; without a velocity there is no
    profile, the acceleration is ignored: the e-manual's step profile). Returns (p, w).
    ``dt`` 0 leaves the setpoint where it is (the plant passes the step's length)."""
    vmax = np.where(np.asarray(velocity) > 0, velocity, np.inf)
    amax = np.where(np.asarray(acceleration) > 0, acceleration, np.inf)
    e = goal - p
    sign = np.where(e < 0, -1.0, 1.0)
    dist, speed = np.abs(e), sign * w      # toward the goal
    with np.errstate(invalid="ignore", over="ignore"):
        # the fastest end-of-step speed u from which braking at amax still stops on the goal:
        # u^2 <= 2 amax (dist - (speed + u) dt / 2)
        ad = amax * dt
        room = np.maximum(dist - 0.5 * speed * dt, 0.0)
        stop = np.where(np.isfinite(amax), 0.5 * (-ad + np.sqrt(ad * ad + 8.0 * amax * room)),
                        np.inf)
        want = np.minimum(vmax, stop)
        u = np.where(np.isfinite(amax), speed + np.clip(want - speed, -ad, ad), want)
        u = np.where(np.isfinite(u), u, 0.0)
        move = 0.5 * (speed + u) * dt
    move = np.where(np.isfinite(amax), move, u * dt)  # a rectangle: at once at its speed
    arrive = (move >= dist) | ~np.isfinite(vmax)
    p_new = np.where(arrive, goal, p + sign * np.where(np.isfinite(move), move, 0.0))
    w_new = sign * u
    return p_new, np.where(arrive, 0.0, w_new)


class GoalProfile(Effect):
    name = "goal_profile"
    kind = "command"
    doc = ("the servo's firmware moves its setpoint toward the written goal at most at "
           "`velocity` with at most `acceleration` (a trapezoid: Dynamixel Profile Velocity / "
           "Profile Acceleration, velocity-based); the log holds the raw goal")
    params = (Param("velocity", math.inf, 0.5, 50.0, "rad/s", (1.0, 5.0), start=3.0,
                    limit=(0.1, 500.0), doc="profile velocity (inf or 0: no profile)"),
              Param("acceleration", math.inf, 1.0, 1000.0, "rad/s^2", (5.0, 50.0),
                    limit=(0.2, 1e5), doc="profile acceleration (inf or 0: a rectangle)"))

    @classmethod
    def command(cls, t: Targets, v: Values, goal: np.ndarray, state: dict[str, np.ndarray],
                rng: np.random.Generator) -> np.ndarray:
        """``state``: "dt" [s], "setpoint", "qpos" / "qvel" (the plant's, full) in; the
        profile's "position" and "speed" kept (NaN or absent: restart, module doc)."""
        dt = float(state.get("dt", 0.0))
        vel = np.asarray(v["velocity"], float)
        p, w = state.get("position"), state.get("speed")
        if p is None or w is None or np.any(np.isnan(p)):
            hold = np.broadcast_to(np.asarray(state["setpoint"], float), goal.shape)
            p0, w0 = hold.copy(), np.zeros(goal.shape)
            if "qpos" in state and "qvel" in state:
                q = np.asarray(state["qpos"], float)[..., t.qpos]
                qd = np.asarray(state["qvel"], float)[..., t.dofs]
                moving = np.abs(qd) > MOVING
                lim = np.where(vel > 0, vel, np.inf)
                p0 = np.where(moving, q, hold)
                w0 = np.where(moving, np.clip(qd, -lim, lim), 0.0)
            p = p0 if p is None else np.where(np.isnan(p), p0, p)
            w = w0 if w is None else np.where(np.isnan(w), w0, w)
        p_new, w_new = profile_step(p, w, goal, vel, np.asarray(v["acceleration"], float), dt)
        state["position"], state["speed"] = p_new, w_new
        on = np.isfinite(vel) & (vel > 0)
        return np.where(on, 0.5 * (p + p_new), goal)  # off: the goal itself, as without it
