"""One option vocabulary for ``lowcostdex`` sub-commands and the scripts in ``demos/``.

``--backend`` (sim | emulated | hardware), ``--port`` (the serial port of a real robot),
``--env`` (a registered gymnasium id), ``--seed``, ``--out`` and ``--n-iter`` / ``--n-traj`` mean
the same everywhere; :func:`robot_selection` turns the first two into the ``backend`` and
``env_kwargs`` of a training config, refusing a combination that cannot work.
"""

from __future__ import annotations

import argparse
from typing import Any

from lowcostdex.argtypes import SEED, integer, number, path
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
        parser.add_argument("--env", type=env_id, default=env,
                            help="gymnasium id (default %(default)s)")


def env_id(name: str) -> str:
    """``--env``: a gymnasium id; ``DClawTurnValve-v0`` is read as ``lowcostdex/DClawTurnValve-v0``
    when only that one is registered (as ``train tvlg`` always read it; before, ``train npg``
    refused it). Unknown ids are left for ``check_env_id`` to name."""
    import gymnasium as gym

    import lowcostdex  # noqa: F401  (registers the lowcostdex/... ids)

    ours = f"lowcostdex/{name}"
    return ours if name not in gym.registry and "/" not in name and ours in gym.registry else name


def add_run_options(parser: argparse.ArgumentParser, *, out: str, n_iter: int,
                    n_traj: int | None = None) -> None:
    """``--seed``, ``--out``, ``--n-iter`` (``--iters`` is kept as an alias) and ``--n-traj``."""
    parser.add_argument("--seed", type=SEED, default=0, help="run seed (default %(default)s)")
    parser.add_argument("--out", type=path, default=out,
                        help="output folder (default %(default)s)")
    parser.add_argument("--n-iter", "--iters", dest="n_iter", type=integer(1), default=n_iter,
                        help="training iterations (default %(default)s)")
    if n_traj is not None:
        parser.add_argument("--n-traj", type=integer(1), default=n_traj,
                            help="trajectories per iteration (default %(default)s)")


def robot_selection(backend: str, port: str | None, hand: str = "dclaw"
                    ) -> tuple[str, dict[str, Any]]:
    """``(backend, env_kwargs)`` for a training config from ``--backend`` / ``--port``
    (``hand``: "dclaw" or "allegro", the env's hand).

    Raises:
      ConfigError: ``hardware`` without a port, or a port given to another backend.
    """
    if backend not in BACKENDS:
        raise ConfigError(f"unknown backend {backend!r}; valid choices: {', '.join(BACKENDS)}")
    if backend == "sim":
        if port:
            raise ConfigError(f"--port {port} is for --backend hardware; with --backend sim "
                              "leave it out")
        return backend, {}
    device = robot_port(backend, port, hand)  # the robot backends' one rule
    return backend, ({} if device == "emulated" else {"port": device})

ROBOT_BACKENDS = ("emulated", "hardware")


def add_robot_port_options(parser: argparse.ArgumentParser, port_help: str | None = None
                           ) -> None:
    """``--backend emulated|hardware`` and ``--port`` for commands that drive a robot (never sim).

    ``--port emulated`` is still understood (it was these commands' way to ask for the emulated
    robot); :func:`robot_port` resolves the pair.
    """
    parser.add_argument("--backend", choices=ROBOT_BACKENDS, default=None,
                        help="the emulated D'Claw or a real robot (default: hardware when "
                             "--port names a device, else emulated)")
    parser.add_argument("--port", default=None,
                        help=port_help or "serial device or pty path of a real robot "
                                          "(hardware backend)")


def add_latency_option(parser: argparse.ArgumentParser) -> None:
    """``--latency-ms``: the USB latency timer [ms] the Dynamixel driver's status timeouts assume
    when it cannot read the adapter's from sysfs (a pty, a non-FTDI adapter). One name and one
    range for every command that talks to a D'Claw over a serial port."""
    parser.add_argument("--latency-ms", type=number(0.5, 1000, unit="ms"), default=None,
                        help="with --port: the USB latency timer the driver's timeouts assume "
                             "when it cannot read it from sysfs [ms] (a pty served by "
                             "`lowcostdex emulate`: 16; default: the driver's 1 ms)")


def latency_kwargs(latency_ms: float | None) -> dict[str, float]:
    """The bus keyword for ``--latency-ms``: ``{}`` when not given (the driver's default)."""
    return {} if latency_ms is None else {"latency_ms": float(latency_ms)}


def robot_port(backend: str | None, port: str | None, hand: str = "dclaw") -> str:
    """``"emulated"`` or the serial port (the Allegro's: its CAN channel), from ``--backend`` /
    ``--port``; ``hand``: "dclaw" or "allegro" (the port to name when it is missing).

    Raises:
      ConfigError: ``hardware`` without a device, or ``emulated`` with one.
    """
    device = None if port in (None, "", "emulated") else port
    if backend is None:
        backend = "hardware" if device else "emulated"
    if backend not in ROBOT_BACKENDS:
        raise ConfigError(f"unknown backend {backend!r}; valid choices: "
                          f"{', '.join(ROBOT_BACKENDS)}")
    if backend == "hardware":
        if device is None and port == "emulated":  # both typed: they contradict each other
            raise ConfigError("--port emulated is the emulated robot, --backend hardware a real "
                              "one: drop --backend hardware to run on the emulated robot, or "
                              "give --port the " + ("CAN channel (e.g. can0)" if hand == "allegro"
                                                    else "serial device (e.g. /dev/ttyUSB0)"))
        if device is None:
            if hand == "allegro":  # not a serial port: scan lists Dynamixel buses only
                raise ConfigError("--backend hardware needs --port, the Allegro's CAN channel "
                                  "(e.g. can0; `ip link` lists them)")
            raise ConfigError("--backend hardware needs --port (e.g. /dev/ttyUSB0; "
                              "`lowcostdex scan` lists candidate ports)")
        return device
    if device is not None:
        raise ConfigError(f"--port {device} is for --backend hardware; the emulated robot "
                          "needs no port")
    return "emulated"
