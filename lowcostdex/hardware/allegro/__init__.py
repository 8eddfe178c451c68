"""Allegro Hand v4: the CAN protocol, the driver, the emulated hand and its env backend."""
