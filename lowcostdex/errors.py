"""Exception hierarchy. Every error a user can trigger derives from LowcostdexError.

The ``lowcostdex`` command prints a LowcostdexError as one line (``lowcostdex CMD: error: ...``)
and exits with code 2; any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Iterable

import numpy as np

USER_ERROR = 2
"""Exit code of a user's mistake (argparse's code for bad arguments)."""
INTERRUPTED = 130
"""Exit code after Ctrl-C (128 + SIGINT, as shells report it)."""


class LowcostdexError(Exception):
    """Root of all lowcostdex errors."""


class ConfigError(LowcostdexError, ValueError):
    """A configuration value is invalid; the message names the valid choices or bounds."""


class InputError(ConfigError):
    """A user's file or value is unusable: the message names the file (or option), the field and
    the value, in one line. The CLI prints it without a traceback and exits with code 2."""


class PathTypeError(InputError, TypeError):
    """A path given as another type (None, a number): an InputError naming the type, and a
    TypeError as ``os.fspath``'s own refusal is."""


class KeywordError(ConfigError, TypeError):
    """A settings class called with a keyword it does not have (a typo): a ConfigError naming the
    closest settings, and a TypeError as Python's own refusal of the keyword is."""


def keyword_hints(cls: type) -> type:
    """Class decorator for a settings dataclass (put it above ``@dataclass``): a keyword that is
    not one of its fields raises :class:`KeywordError` naming the closest ones (``n_iters`` ->
    "did you mean n_iter?") and listing the valid ones, instead of Python's bare TypeError."""
    import dataclasses
    import difflib
    import functools

    init = cls.__init__
    names = [f.name for f in dataclasses.fields(cls) if f.init]

    @functools.wraps(init)
    def __init__(self, *args, **kwargs):  # noqa: N807
        unknown = [k for k in kwargs if k not in names]
        if unknown:
            close = difflib.get_close_matches(unknown[0], names, n=2, cutoff=0.6)
            hint = f"; did you mean {' or '.join(close)}?" if close else ""
            raise KeywordError(f"{cls.__name__} has no setting {unknown[0]!r}{hint} (valid: "
                               f"{', '.join(names)})")
        init(self, *args, **kwargs)

    cls.__init__ = __init__
    return cls


class Interrupted(KeyboardInterrupt):
    """Ctrl-C stopped a command that keeps what it finished: the message says what is kept and
    the command that continues (the CLI prints ``interrupted (Ctrl-C); <message>``, exit 130)."""


class ClosedError(LowcostdexError, RuntimeError):
    """A simulation used after its ``close()``: the message says how to make a new one."""


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
        raise ConfigError(f"unknown {kind} {value!r}; valid choices: {listed}"
                          + did_you_mean(value, options))


def did_you_mean(value: object, choices: Iterable[object]) -> str:
    """``"; did you mean 'latency'?"`` naming the choices closest to a mistyped string (``""``
    when none is close, or ``value`` is no string): a typo is named, not only listed."""
    import difflib

    if not isinstance(value, str):
        return ""
    lower: dict[str, str] = {}  # matched case-blind: "xm430-w350" for "XM430-W350"
    for c in choices:
        if isinstance(c, str):
            lower.setdefault(c.lower(), c)
    close = ([value.lower()] if value.lower() in lower
             else difflib.get_close_matches(value.lower(), list(lower), n=2, cutoff=0.6))
    return f"; did you mean {' or '.join(repr(lower[c]) for c in close)}?" if close else ""


def check_range(name: str, value: float, low: float, high: float) -> None:
    """Raise ConfigError unless ``low <= value <= high``."""
    if not (low <= value <= high):
        raise ConfigError(f"{name}={value!r} is outside [{low}, {high}]")


def check_number(name: str, value: object, low: float = -math.inf, high: float = math.inf, *,
                 low_open: bool = False, high_open: bool = False, integer: bool = False,
                 none_ok: bool = False) -> None:
    """Raise ConfigError unless ``value`` is a finite number in the interval, listing it.

    Args:
      name: the setting, e.g. "damping".
      value: the user's value (NaN and +-inf are refused whatever the bounds).
      low, high: the bounds; ``low_open``/``high_open`` exclude them.
      integer: also require an integer type (int or a numpy integer: 2.0 is refused).
      none_ok: None is valid too.
    """
    if value is None and none_ok:
        return
    ok = isinstance(value, numbers.Integral if integer else numbers.Real) and not isinstance(
        value, bool)  # 2.0 is no count: range(2.0) fails minutes later, in the run
    if ok:
        x = float(value)  # type: ignore[arg-type]
        ok = (math.isfinite(x) and (x > low if low_open else x >= low)
              and (x < high if high_open else x <= high) and (not integer or x.is_integer()))
    if not ok:
        def bound(b: float) -> str:
            return "inf" if b == math.inf else "-inf" if b == -math.inf else f"{b:g}"

        interval = (f"{'(' if low_open or low == -math.inf else '['}{bound(low)}, "
                    f"{bound(high)}{')' if high_open or high == math.inf else ']'}")
        kind = "an integer" if integer else "a finite number"
        raise ConfigError(f"{name}={value!r} must be {kind} in {interval}"
                          + (" or None" if none_ok else ""))


def check_bool(name: str, value: object) -> None:
    """Raise ConfigError unless ``value`` is True or False (a JSON string "false" is truthy, and
    2 is not a flag)."""
    numpy_bool = type(value).__module__ == "numpy" and type(value).__name__ in ("bool", "bool_")
    if not isinstance(value, bool) and not numpy_bool:
        raise ConfigError(f"{name}={value!r} must be True or False")


def check_sizes(name: str, value: object) -> None:
    """Raise ConfigError unless ``value`` is a tuple/list of positive integers (layer widths)."""
    ok = isinstance(value, (tuple, list))
    if ok:
        for h in value:  # type: ignore[union-attr]
            ok = ok and isinstance(h, numbers.Integral) and not isinstance(h, bool) and h >= 1
    if not ok:
        raise ConfigError(f"{name}={value!r} must be positive integers (a tuple, e.g. (64, 64))")
    for h in value:  # type: ignore[union-attr]
        check_at_most(name, h, MAX_LAYER_WIDTH, "a layer that wide holds its width squared in "
                      "weights (4096 units: 17 M per layer); typical widths are 32-512")


MAX_LAYER_WIDTH = 4096
"""Widest hidden layer a config accepts."""


def check_at_most(name: str, value: float, cap: float, why: str) -> None:
    """Raise ConfigError when ``value`` exceeds ``cap``: a size no run needs whose memory or
    time would grow without end (``why`` says what grows), or a number far outside its use."""
    if value > cap:
        raise ConfigError(f"{name}={value!r} is above {cap:g}: {why}")


def check_keys(kind: str, given: Iterable[str], valid: Iterable[str]) -> None:
    """Raise ConfigError naming the first unknown key of ``given`` and listing ``valid``."""
    options = list(valid)
    unknown = [k for k in given if k not in options]
    if unknown:
        raise ConfigError(f"unknown {kind} {unknown[0]!r}; valid: {', '.join(options)}"
                          + did_you_mean(unknown[0], options))


def check_fields(config: object) -> None:
    """Check every number and flag of a dataclass config by its default's type: a field whose
    default is a bool must be True or False, an int an integral finite number, a float a finite
    number, a None-default ``float | None`` field a finite number or None. Strings from a JSON
    file, NaN and inf are refused naming ``Config.field``; the config's own range checks run
    after this with their messages."""
    import dataclasses

    kind = type(config).__name__
    for f in dataclasses.fields(config):  # type: ignore[arg-type]
        default, value, name = f.default, getattr(config, f.name), f"{kind}.{f.name}"
        if isinstance(default, bool):
            check_bool(name, value)
            continue
        scalar = isinstance(default, numbers.Real) or (
            default is None and str(f.type).replace(" ", "") in ("float|None", "int|None"))
        if not scalar or (value is None and default is None):
            continue
        integer = isinstance(default, numbers.Integral) or str(f.type).startswith("int")
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(
            float(value)) and (not integer or float(value).is_integer())  # type: ignore[arg-type]
        if not ok:
            what = "an integer" if integer else "a finite number"
            raise ConfigError(f"{name}={value!r} must be {what}"
                              + (" or None" if default is None else ""))


def check_count(name: str, value: object) -> None:
    """Raise ConfigError unless ``value`` is an integer >= 1 (int or a numpy integer; a step
    count of 2.5, "3", True, 0 or -3 is refused; an int >= 1 returns at once: hot loops)."""
    if type(value) is int and value >= 1:
        return
    check_number(name, value, 1, integer=True)


MAX_CONTROL = 1e10
"""Largest control MuJoCo takes: above it (or NaN/inf) it zeroes EVERY control of the step and
goes on (mjMAXVAL), a printed warning the only trace."""
_MAX_SQUARE = MAX_CONTROL ** 2


def check_finite_array(name: str, value: object, shapes: Iterable[tuple[int, ...]],
                       what: str | Callable[[], str]) -> None:
    """Raise ConfigError unless ``value`` has one of ``shapes`` and holds finite numbers of size
    at most ``MAX_CONTROL``. A float array passes in ~1 us (hot loops); anything else is looked
    at slowly (``shapes`` a tuple for the fast path).

    Args:
      name: the argument, e.g. "goal".
      value: an array-like the caller is about to use (never broadcast: a (1,) goal for two
        actuators would drive both to one angle without a word).
      shapes: the valid shapes, e.g. ((nu,), (nsim, nu)).
      what: what the numbers are, with their unit (or a function saying it, called only to
        refuse), e.g. "goal positions of the 2 actuators [rad]".
    """
    if (type(value) is np.ndarray and value.shape in shapes and value.dtype.kind == "f"
            and np.vdot(value, value) < _MAX_SQUARE):  # NaN compares False; every |x| < 1e10
        return
    shapes = tuple(shapes)
    _refuse_array(name, value, shapes, what)


def _refuse_array(name: str, value: object, shapes: tuple[tuple[int, ...], ...],
                  what: str | Callable[[], str]) -> None:
    def said() -> str:
        return what if isinstance(what, str) else what()

    try:
        shape: object = np.shape(value)
    except ValueError:  # a ragged list
        shape = "ragged"
    if shape not in shapes:
        valid = " or ".join(str(s) for s in dict.fromkeys(shapes))
        raise ConfigError(f"{name} of shape {shape} must have shape {valid}: {said()}")
    a = np.asarray(value) if not isinstance(value, np.ndarray) else value
    if a.dtype.kind not in "iuf":  # strings, None, objects, True/False
        raise ConfigError(f"{name} holds {_first_odd(a)!r}, not numbers: {said()}")
    bad = ~(np.abs(a) <= MAX_CONTROL)
    if bad.any():
        x = a[bad].flat[0].item()
        why = "finite numbers" if not np.isfinite(x) else f"at most {MAX_CONTROL:g} in size"
        raise ConfigError(f"{name} holds {x:g}: must be {why}, {said()}")


def _first_odd(a) -> object:
    for x in a.ravel():
        if not isinstance(x, numbers.Real) or isinstance(x, bool):
            return x.item() if hasattr(x, "item") else x
    return a.ravel()[0]


def check_rows(name: str, value: object, width: int | None, what: str,
               rows: int | None = None) -> int:
    """Raise ConfigError unless ``value`` is (n, width) finite numbers with n >= 1 (n == rows
    when given; ``width`` None: a 1-D (n,) array); returns n. For a batch of samples, whose
    length varies: a (20, 3) batch for a policy of 4 observations, or actions of one column
    for two, would fail deep in torch or be broadcast.

    Args:
      name: the argument, e.g. "demo_obs".
      value: an array-like or a CPU tensor.
      width: its columns, or None for one value per row.
      what: what the rows are, with the unit or the size they must have.
      rows: the number of rows it must have (the batch's, for a second array of one batch).
    """
    if hasattr(value, "detach"):  # a torch tensor
        value = value.detach().cpu().numpy()  # type: ignore[attr-defined]
    try:
        a = np.asarray(value)
    except ValueError:  # a ragged list
        raise ConfigError(f"{name} is a ragged list, not a table of numbers: {what}") from None
    want = ("(n,)" if width is None else f"(n, {width})") if rows is None else str(
        (rows,) if width is None else (rows, width))
    ok = a.ndim == (1 if width is None else 2) and (width is None or a.shape[1] == width)
    if not ok or (rows is not None and a.shape[0] != rows) or a.shape[0] == 0:
        cond = " with n >= 1" if rows is None else ""
        raise ConfigError(f"{name} of shape {a.shape} must have shape {want}{cond}: {what}")
    if a.dtype.kind not in "iuf":
        raise ConfigError(f"{name} holds {_first_odd(a)!r}, not numbers: {what}")
    bad = ~np.isfinite(a)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        raise ConfigError(f"{name} holds {a[bad].flat[0].item():g} (row {row}): must be finite "
                          f"numbers, {what}")
    return int(a.shape[0])


def check_indices(name: str, value: object, n: int, what: str) -> np.ndarray:
    """``value`` as an int array of indices in [0, n), else ConfigError naming the first bad
    one and ``what`` they index (a boolean mask was read as indices 0/1, -1 as the last one,
    7 of 2 a bare IndexError, 'a' int()'s ValueError)."""
    a = np.asarray(value)
    if a.size and a.dtype.kind not in "iu":
        raise ConfigError(f"{name}={value!r:.60} must be integer indices of the {n} {what} "
                          f"(0 .. {n - 1})")
    a = a.astype(int).reshape(-1) if a.ndim != 1 else a.astype(int)
    bad = a[(a < 0) | (a >= n)]
    if bad.size:
        raise ConfigError(f"{name}: index {int(bad[0])} is not one of the {n} {what} "
                          f"(0 .. {n - 1})")
    return a


def check_rng(name: str, value: object) -> object:
    """``value`` when it is None or a ``np.random.Generator``, else ConfigError saying what to
    pass (a seed 0 was kept and failed at the first draw, deep inside: 'int' object has no
    attribute 'normal')."""
    if value is not None and not isinstance(value, np.random.Generator):
        raise ConfigError(f"{name}={value!r} must be a seeded numpy Generator, e.g. "
                          "np.random.default_rng(0)")
    return value


def flag(name: str, value: object) -> bool:
    """``value`` as a bool after ``check_bool`` (a string 'no' is truthy)."""
    check_bool(name, value)
    return bool(value)
