"""The Robot: safety limits and motion bound, thermal/current guards, calibration, auto-reset, driver logs, env backends (D'Claw: backend.py, Allegro: allegro_backend.py)."""
