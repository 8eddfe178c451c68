"""One option vocabulary for ``lowcostdex`` sub-commands and the scripts in ``demos/``.

``--backend`` (sim | emulated | hardware), ``--port`` (the serial port of a real robot),
``--env`` (a registered gymnasium id), ``--seed``, ``--out`` and ``--n-iter`` / ``--n-traj`` mean
the same everywhere; :func:`robot_selection` turns the first two into the ``backend`` and
``env_kwargs`` of a training config, refusing a combination that cannot work.
"""

from __future__ import annotations

import argparse
from typing import Any

from lowcostdex.errors import ConfigError

BACKENDS = ("sim", "emulated", "hardware")


def add_robot_options(parser: argparse.ArgumentParser, *, default_backend: str = "sim",
                      backends: tuple[str, ...] = BACKENDS, env: str | None = None) -> None:
    """``--backend``, ``--port`` and (when ``env`` is given, as its default) ``--env``."""
    parser.add_argument("--backend", choices=backends, default=default_backend,
                        help="where to run: MuJoCo (sim), the emulated robot on its Dynamixel "
                             "bus (emulated) or a real robot (hardware, needs --port)")
    parser.add_argument("--port", default=None,
                        help="serial port of a real robot, e.g. /dev/ttyUSB0 (hardware backend)")
    if env is not None:
        parser.add_argument("--env", default=env, help="gymnasium id (default %(default)s)")


def add_run_options(parser: argparse.ArgumentParser, *, out: str, n_iter: int,
                    n_traj: int | None = None) -> None:
    """``--seed``, ``--out``, ``--n-iter`` (``--iters`` is kept as an alias) and ``--n-traj``."""
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=out, help="output folder (default %(default)s)")
    parser.add_argument("--n-iter", "--iters", dest="n_iter", type=int, default=n_iter,
                        help="training iterations (default %(default)s)")
    if n_traj is not None:
        parser.add_argument("--n-traj", type=int, default=n_traj,
                            help="trajectories per iteration (default %(default)s)")


def robot_selection(backend: str, port: str | None) -> tuple[str, dict[str, Any]]:
    """``(backend, env_kwargs)`` for a training config from ``--backend`` / ``--port``.

    Raises:
      ConfigError: ``hardware`` without a port, or a port given to another backend.
    """
    if backend not in BACKENDS:
        raise ConfigError(f"unknown backend {backend!r}; valid choices: {', '.join(BACKENDS)}")
    if backend == "hardware":
        if not port:
            raise ConfigError("--backend hardware needs --port (e.g. /dev/ttyUSB0; "
                              "`lowcostdex scan` lists candidate ports)")
        return backend, {"port": port}
    if port:
        raise ConfigError(f"--port {port} is for --backend hardware; with --backend {backend} "
                          "leave it out")
    return backend, {}
