"""MJCF models written from primitives: D'Claw and stations, servo bench (and Allegro)."""

from lowcostdex.sim.models.dclaw import STATIONS, build_dclaw

__all__ = ["STATIONS", "build_dclaw"]
