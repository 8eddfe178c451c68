"""Emulated Dynamixel robots: the firmware model, the byte-level chain with MuJoCo behind it, the pty server, hidden robots."""
