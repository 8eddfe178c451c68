"""Exception hierarchy. Every error a user can trigger derives from LowcostdexError.

The ``lowcostdex`` command prints a LowcostdexError as one line (``lowcostdex CMD: error: ...``)
and exits with code 2; any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations

from collections.abc import Iterable


class LowcostdexError(Exception):
    """Root of all lowcostdex errors."""


class ConfigError(LowcostdexError, ValueError):
    """A configuration value is invalid; the message names the valid choices or bounds."""


class InputError(ConfigError):
    """A user's file or value is unusable: the message names the file (or option), the field and
    the value, in one line. The CLI prints it without a traceback and exits with code 2."""


class PhysicsError(LowcostdexError, RuntimeError):
    """The simulation diverged (NaN/inf state or MuJoCo warning that invalidates the step)."""


def check_choice(kind: str, value: object, choices: Iterable[object]) -> None:
    """Raise ConfigError unless ``value`` is one of ``choices``, listing them.

    Args:
      kind: what is being chosen, e.g. "motor model".
      value: the user's value.
      choices: the valid values.
    """
    options = list(choices)
    if value not in options:
        listed = ", ".join(repr(c) for c in options)
        raise ConfigError(f"unknown {kind} {value!r}; valid choices: {listed}")


def check_range(name: str, value: float, low: float, high: float) -> None:
    """Raise ConfigError unless ``low <= value <= high``."""
    if not (low <= value <= high):
        raise ConfigError(f"{name}={value!r} is outside [{low}, {high}]")
