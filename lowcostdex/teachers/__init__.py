"""Virtual teachers: scripted closed-loop solving motions (valve, screw, flip, Allegro valve) that
map the present state to joint goals. They drive the fingers of an emulated hand while
demonstrations are recorded, reorient the flip block in the auto-reset, and serve as the
physics sanity tests of the tasks. Each needs only the simulation (models, tasks, kinematics).
"""

from __future__ import annotations

from lowcostdex.errors import ConfigError
from lowcostdex.teachers.allegro import AllegroTeacherConfig, AllegroValveTeacher
from lowcostdex.teachers.flip import FlipBlockTeacher, FlipTeacherConfig
from lowcostdex.teachers.flip_pinch import PinchFlipConfig, PinchFlipTeacher
from lowcostdex.teachers.flip_plan import FlipPlanConfig, PlannedFlipTeacher
from lowcostdex.teachers.valve import (
    ScrewTrackTeacher,
    ValveTeacherConfig,
    ValveTurnTeacher,
)

TEACHERS = {cls.__name__: cls for cls in
            (ValveTurnTeacher, ScrewTrackTeacher, FlipBlockTeacher, PlannedFlipTeacher,
             PinchFlipTeacher, AllegroValveTeacher)}
"""Teacher classes by name (the names the task tables use)."""


def teacher_class(name: str) -> type:
    """The teacher class called ``name``; ConfigError listing the valid names otherwise."""
    try:
        return TEACHERS[name]
    except KeyError:
        raise ConfigError(f"unknown teacher {name!r}; valid: {', '.join(sorted(TEACHERS))}") from None


__all__ = ["TEACHERS", "AllegroTeacherConfig", "AllegroValveTeacher", "FlipBlockTeacher",
           "FlipPlanConfig", "FlipTeacherConfig", "PinchFlipConfig", "PinchFlipTeacher",
           "PlannedFlipTeacher", "ScrewTrackTeacher",
           "ValveTeacherConfig", "ValveTurnTeacher",
           "teacher_class"]
