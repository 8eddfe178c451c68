"""Allegro Hand v4 devices: the CAN protocol, the driver (AllegroBus) and the emulated hand; its env backend is robot/allegro_backend.py."""
