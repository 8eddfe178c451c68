"""argparse types for numbers: finite and in range, refused at parse time with the option named.

    p.add_argument("--min-gain", type=number(0, 1, open_low=True, open_high=True), default=0.05)
    p.add_argument("--threads", type=integer(0, 1024), default=0)

A bad value stops the command before it reads or writes anything, in one line:
``lowcostdex gap analyze: error: argument --min-gain: 'nan' is not a finite number in (0, 1)``.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable


def _fmt(x: float) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def _interval(low: float | None, high: float | None, open_low: bool, open_high: bool) -> str:
    if low is None and high is None:
        return ""
    if high is None:
        return f" {'>' if open_low else '>='} {_fmt(low)}"
    if low is None:
        return f" {'<' if open_high else '<='} {_fmt(high)}"
    return (f" in {'(' if open_low else '['}{_fmt(low)}, {_fmt(high)}"
            f"{')' if open_high else ']'}")


def _inside(x: float, low, high, open_low: bool, open_high: bool) -> bool:
    if low is not None and (x < low or (open_low and x == low)):
        return False
    return not (high is not None and (x > high or (open_high and x == high)))


UNIT_SLIPS = {  # unit -> (one of the unit users mistake it for, in this unit; the words)
    "s": (1e-3, "in seconds: {t} ms is {v:g}"),
    "ms": (1e3, "in milliseconds: {t} s is {v:g}"),
    "rad": (math.pi / 180, "in radians: {t} deg is {v:.4g}"),
    "fraction": (1e-2, "a fraction: {t} % is {v:g}"),
}
"""What a value outside an option's range most often is: the other unit (``--servo-period 1``
meant 1 ms, ``--latency-ms 0.016`` 16 ms, ``--start-range 30`` 30 deg, ``--min-gain 5`` 5 %)."""


_SUFFIXES = {  # a unit typed after the number -> (the option unit it converts to, factor)
    "s": ("s", 1.0), "sec": ("s", 1.0), "ms": ("s", 1e-3), "us": ("s", 1e-6),
    "min": ("s", 60.0), "deg": ("rad", math.pi / 180), "rad": ("rad", 1.0), "%": ("fraction", 1e-2),
}
_IN_UNIT = {"s": "in seconds", "ms": "in milliseconds", "rad": "in radians",
            "fraction": "as a fraction"}


def _typed_unit(text: str, unit: str | None) -> str:
    """The hint for a number typed with its unit (``10s``, ``30 deg``, ``5%``): the number
    alone, converted to the option's ``unit`` when that is known ('' when ``text`` is not a
    number and a unit)."""
    import re

    m = re.fullmatch(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zA-Z%]+)\s*", text)
    if not m:
        return ""
    value, suffix = float(m.group(1)), m.group(2).lower()
    kind, factor = _SUFFIXES.get(suffix, (None, 1.0))
    if unit is not None and kind == "s" and unit in ("s", "ms"):
        return (f"; give the number alone, {_IN_UNIT[unit]}: "
                f"{value * factor * (1e3 if unit == 'ms' else 1.0):g}")
    if unit is not None and kind == unit:
        return f"; give the number alone, {_IN_UNIT[unit]}: {value * factor:.4g}"
    return f"; give the number alone, without {m.group(2)!r}"


def number(low: float | None = None, high: float | None = None, *, open_low: bool = False,
           open_high: bool = False, unit: str | None = None) -> Callable[[str], float]:
    """A finite float in the interval (bounds closed unless ``open_low``/``open_high``).
    ``unit`` (a key of ``UNIT_SLIPS``): a value outside whose conversion from the unit users
    mistake it for lies inside is refused with that conversion named."""
    where = _interval(low, high, open_low, open_high)
    if unit is not None and unit not in UNIT_SLIPS:
        raise ValueError(f"unit {unit!r}; valid: {', '.join(UNIT_SLIPS)}")

    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            x = math.nan
        if not math.isfinite(x) or not _inside(x, low, high, open_low, open_high):
            hint = _typed_unit(text, unit)
            if unit is not None and math.isfinite(x):
                scale, words = UNIT_SLIPS[unit]
                if _inside(x * scale, low, high, open_low, open_high):
                    hint = "; " + words.format(t=text, v=x * scale)
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number{where}{hint}")
        return x

    parse.__name__ = "number"
    return parse


def integer(low: int | None = None, high: int | None = None) -> Callable[[str], int]:
    """An integer in [low, high]."""
    where = _interval(low, high, False, False)

    def parse(text: str) -> int:
        try:
            x = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer{where}"
                                             + _typed_unit(text, None)) from None
        if not _inside(x, low, high, False, False):
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer{where}")
        return x

    parse.__name__ = "integer"
    return parse


def width(text: str) -> int:
    """One hidden layer's width for ``--hidden`` (``nargs="*"``): widths typed with commas
    ('32,32') are named with the words to type (was "invalid int value: '32,32'"); the range
    is the policy config's check."""
    if "," in text:
        words = " ".join(p.strip() for p in text.split(",") if p.strip())
        typed = (f"type --hidden {words}" if not text.rstrip().endswith(",") else
                 "e.g. --hidden 64 64 for two layers of 64")
        raise argparse.ArgumentTypeError(f"{text!r}: the widths are separated by spaces, not "
                                         f"commas: {typed}")
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None


def home(text: str) -> str:
    """``text`` with a leading ``~`` or ``~user`` read as that home folder, as the shell reads it.
    The shell leaves ``--out=~/runs`` and ``--out "~/runs"`` alone, and pathlib too: the output
    went to a folder named ``~`` in the working folder (whose ``rm -r ~`` removes the home)."""
    return os.path.expanduser(text) if text.startswith("~") else text


def path(text: str) -> str:
    """A path that is not empty: "" (``--out "$OUT"`` with OUT unset) is the current folder to
    pathlib, where a run would be written beside the user's own files. A leading ``~`` is the
    home folder (:func:`home`)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is an empty path (an unset shell "
                                         "variable?); give a path")
    return home(text)


def names(text: str, option: str) -> tuple[str, ...]:
    """``"dapg,npg"`` -> ``("dapg", "npg")``: the comma-separated names an option takes
    (``--algos``, ``--stages``, ``--candidates``, ``--fingers``, ``--joints``, ``--made-for``).
    Spaces around a name and a trailing comma (``latency,``) are dropped. An empty item between
    two names (``dapg,,npg``: a name deleted or left out) and a name given twice are refused with
    the option named and what to type; before, ``dapg,,npg`` ran as ``dapg,npg`` without a word
    and ``dapg,dapg`` was taken as given. Names separated by spaces (``"dapg npg"``) are refused
    with the comma list to type. The caller checks the names themselves and refuses an
    empty list in its own words."""
    from lowcostdex.errors import ConfigError

    items = [s.strip() for s in text.split(",")]
    spaced = [s for s in items if len(s.split()) > 1]
    if spaced:  # "ff_top ff_middle" was looked up as one name ("did you mean 'ff_middle'?")
        fixed = ",".join(w for s in items for w in s.split())
        raise ConfigError(f"{option} {text!r}: names are separated by commas, not spaces; type "
                          f"{option} {fixed}")
    while items and not items[-1]:
        items.pop()  # "latency," or "latency, " is latency
    kept = tuple(s for s in items if s)
    fix = f"; type {option} {','.join(dict.fromkeys(kept))}" if kept else ""
    if "" in items and kept:
        raise ConfigError(f"{option} {text!r} has an empty name (two commas together: a name "
                          f"left out?){fix}")
    twice = sorted({s for s in kept if kept.count(s) > 1})
    if twice:
        raise ConfigError(f"{option} {text!r} names {', '.join(twice)} more than once; name "
                          f"each once{fix}")
    return kept


def bit_rate(text: str) -> int:
    """``--baud``: bit/s as an integer, or written as people write rates: ``1M``, ``1e6``,
    ``57.6k``, ``1_000_000`` (before: "invalid int value: '1M'", no word of what to type).
    Which rates a bus takes is checked where the bus is opened."""
    words = text.strip().replace("_", "").replace(",", "")
    scale = {"k": 1e3, "K": 1e3, "m": 1e6, "M": 1e6}.get(words[-1:], 1.0)
    try:
        x = float(words[:-1] if scale != 1.0 else words) * scale
    except ValueError:
        x = math.nan
    if not math.isfinite(x) or x != round(x):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a bit rate: give bit/s, e.g. 1000000 (1M, the Dynamixel default) "
            "or 57600 (57.6k, a new motor's factory rate)")
    return int(round(x))


class JoinRepeats(argparse.Action):
    """A comma-separated names option (default None) given twice keeps both:
    ``--joints ff_top --joints ff_middle`` is ``"ff_top,ff_middle"`` (argparse kept the last
    alone, and the first was dropped without a word)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: object, option_string: str | None = None) -> None:
        before = getattr(namespace, self.dest, None)
        setattr(namespace, self.dest, values if before is None else f"{before},{values}")


SEED = integer(0)
"""A seed for ``numpy.random.default_rng`` (which refuses negative ones)."""
