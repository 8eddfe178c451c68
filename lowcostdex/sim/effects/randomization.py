"""Effects bound to joints (``AppliedEffect``) and domain randomization over the catalogue."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lowcostdex.errors import ConfigError, check_choice, check_keys, keyword_hints
from lowcostdex.sim.effects.catalogue import Effect, effect


@dataclass(frozen=True)
class AppliedEffect:
    """An effect bound to joints with parameter values.

    Attributes:
      name: canonical effect name.
      joints: joints it acts on.
      values: parameter name -> value per joint, shape (n_joints,) or a scalar for all.
    """

    name: str
    joints: tuple[str, ...]
    values: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        cls = effect(self.name)
        # one joint typed as a string ("elbow") is that joint, not five one-letter joints
        joints = (self.joints,) if isinstance(self.joints, str) else tuple(self.joints)
        for j in joints:
            if not isinstance(j, str) or not j:
                raise ConfigError(f"effect {self.name}: joints must be joint names, got {j!r} "
                                  f"in {self.joints!r} (type e.g. joints=('elbow',))")
        object.__setattr__(self, "joints", tuple(str(j) for j in joints))
        n = len(self.joints)
        if n == 0:
            raise ConfigError(f"effect {self.name}: no joints given")
        vals: dict[str, np.ndarray] = {}
        for p in cls.params:
            raw = self.values.get(p.name, p.null)
            arr = np.broadcast_to(np.asarray(raw, dtype=float), (n,)).copy()
            vals[p.name] = arr
        unknown = set(self.values) - {p.name for p in cls.params}
        if unknown:
            check_choice(f"{self.name} parameter", sorted(unknown)[0], [p.name for p in cls.params])
        object.__setattr__(self, "values", vals)

    @property
    def cls(self) -> type[Effect]:
        return effect(self.name)

    def to_dict(self) -> dict:
        """JSON-safe: a parameter at an infinite null on every joint (a velocity limit's
        speed on a dcmotor servo) is left out; ``from_dict`` restores it."""
        nulls = {p.name: p.null for p in self.cls.params}
        return {"effect": self.name, "joints": list(self.joints),
                "params": {k: v.tolist() for k, v in self.values.items()
                           if not (np.isinf(nulls[k]) and np.all(v == nulls[k]))}}

    @classmethod
    def from_dict(cls, d: Mapping) -> AppliedEffect:
        """The effect ``to_dict()`` wrote: {"effect": name, "joints": [...], "params": {name:
        value or one value per joint}}; raises ConfigError naming what is wrong."""
        if not isinstance(d, Mapping):
            raise ConfigError(f"an effect is an object with effect, joints and params, not "
                              f"{type(d).__name__} {str(d)[:40]!r}")
        # in_mjcf, interval: what an extended model's effects list adds (gap.extension)
        check_keys("effect key", d, ("effect", "joints", "params", "in_mjcf", "interval"))
        for key in ("effect", "joints"):
            if key not in d:
                raise ConfigError(f"an effect needs {key!r} (to_dict() writes effect, joints "
                                  "and params)")
        joints, params = d["joints"], d.get("params", {})
        if isinstance(joints, str) or not all(isinstance(j, str) for j in joints):
            raise ConfigError(f"effect {d['effect']}: 'joints' must be a list of joint names, "
                              f"got {joints!r}")
        if not isinstance(params, Mapping):
            raise ConfigError(f"effect {d['effect']}: 'params' must be an object, got "
                              f"{params!r}")
        values = {}
        for k, v in params.items():
            try:
                values[k] = np.asarray(v, float)
            except (TypeError, ValueError):
                raise ConfigError(f"effect {d['effect']}: parameter {k!r} must be a number or "
                                  f"a list of numbers, got {v!r}") from None
            if not np.all(np.isfinite(values[k])):
                raise ConfigError(f"effect {d['effect']}: parameter {k!r} must be finite, got "
                                  f"{v!r}")
        out = cls(d["effect"], tuple(joints), values)
        out.check_values(params)
        return out

    def check_values(self, given: Mapping | None = None) -> None:
        """ConfigError for a parameter value a user gave that no servo has: not finite (but
        at a non-finite null: the effect off) or outside its hard limits (``Param.hard``): a
        value in ms or degrees would ask for a buffer or a force no servo has. ``given``: the
        values as the user wrote them (the message quotes them); default ``values``."""
        given = self.values if given is None else given
        for k in given:
            par, v = self.cls.param(k), self.values[k]
            off = v == par.null
            if not np.all(np.isfinite(v) | off):
                raise ConfigError(f"effect {self.name}: parameter {k!r} must be finite, got "
                                  f"{v.tolist()!r}")
            bottom, top = par.hard
            if np.any(((v < bottom) | (v > top)) & ~off):
                shown = given[k].tolist() if isinstance(given[k], np.ndarray) else given[k]
                raise ConfigError(f"effect {self.name}: parameter {k!r} = {shown!r} "
                                  f"[{par.unit}] is outside its limits [{bottom:g}, {top:g}] "
                                  f"{par.unit} (SI units: s, rad, N m, ...)")

    @classmethod
    def coerce(cls, e: AppliedEffect | Mapping) -> AppliedEffect:
        """``e`` itself, or the effect its ``to_dict()`` mapping describes (JSON configs); a
        user's values checked either way (``check_values``: before, an AppliedEffect with a
        NaN delay made the emulator's simulation unstable and failed its reset four times)."""
        if isinstance(e, AppliedEffect):
            e.check_values()
            return e
        return cls.from_dict(e)


SampleFn = Callable[[np.random.Generator], list[AppliedEffect]]


@keyword_hints
@dataclass(frozen=True)
class DomainRandomization:
    """Which effects to randomize on which joints; samples AppliedEffects from ``Param.dr``.

    Attributes:
      effects: canonical effect names to randomize (each independently per joint).
      joints: joints the effects act on.
      ranges: optional overrides {effect: {param: (low, high)}} (e.g. from a gap-analysis fit);
        ``low`` and ``high`` are scalars or one value per joint (an identified robot whose
        joints differ; ``low == high`` holds a value fixed).
    """

    effects: tuple[str, ...]
    joints: tuple[str, ...]
    ranges: Mapping[str, Mapping[str, tuple[float, float]]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for field_name in ("effects", "joints"):
            value = getattr(self, field_name)
            if isinstance(value, str) or not isinstance(value, (tuple, list)):
                example = (value,) if isinstance(value, str) else (
                    ("latency",) if field_name == "effects" else ("ff_top",))
                raise ConfigError(f"DomainRandomization.{field_name}={value!r} must be a tuple "
                                  f"of names, e.g. {example!r} (a string is not a tuple)")
        for name in self.effects:
            effect(name)
        n = len(self.joints)
        for name, params in self.ranges.items():
            cls = effect(name)
            if name not in self.effects:  # else its ranges are silently never drawn
                raise ConfigError(f"ranges for {name}, which is not in effects "
                                  f"{tuple(self.effects)}: add it, e.g. effects="
                                  f"{(*self.effects, name)}")
            for p, pair in params.items():
                cls.param(p)
                if not isinstance(pair, (tuple, list, np.ndarray)) or len(pair) != 2:
                    raise ConfigError(f"range of {name}.{p}: {pair!r} must be a (low, high) pair; "
                                      f"to hold it fixed give ({pair!r}, {pair!r})")
                lo, hi = pair
                lo, hi = np.asarray(lo, float), np.asarray(hi, float)
                if lo.shape not in ((), (n,)) or hi.shape not in ((), (n,)):
                    raise ConfigError(f"range of {name}.{p}: low and high must be scalars or "
                                      f"one value per joint ({n}), got shapes {lo.shape}, "
                                      f"{hi.shape}")
                # a joint held at a non-finite null (the effect off there, e.g. no velocity
                # limit: speed inf) is the one non-finite range allowed
                off = (lo == hi) & (lo == cls.param(p).null)
                if not (np.all(np.isfinite(lo) | off) and np.all(np.isfinite(hi) | off)):
                    raise ConfigError(f"range of {name}.{p}: low {lo.tolist()} and high "
                                      f"{hi.tolist()} must be finite (or both the "
                                      f"parameter's null {cls.param(p).null}: off)")
                if not np.all(lo <= hi):
                    raise ConfigError(f"range of {name}.{p}: low {lo.tolist()} above high "
                                      f"{hi.tolist()}")
                par = cls.param(p)
                bottom, top = par.hard
                if np.any((lo < bottom) & ~off) or np.any((hi > top) & ~off):
                    raise ConfigError(f"range of {name}.{p} [{par.unit}]: ({lo.tolist()}, "
                                      f"{hi.tolist()}) outside the parameter's limits "
                                      f"[{bottom:g}, {top:g}] {par.unit} (SI units: s, rad, "
                                      "N m, ...)")

    def to_dict(self) -> dict:
        """JSON form (training configs' env kwargs; ``from_dict`` reads it back)."""
        return {"effects": list(self.effects), "joints": list(self.joints),
                "ranges": {k: {p: [np.asarray(lo, float).tolist(), np.asarray(hi, float).tolist()]
                               for p, (lo, hi) in r.items()} for k, r in self.ranges.items()}}

    @classmethod
    def from_dict(cls, d: Mapping) -> DomainRandomization:
        if not isinstance(d, Mapping):
            raise ConfigError(f"a DomainRandomization dict (to_dict()) is a mapping, not "
                              f"{type(d).__name__}")
        check_keys("DomainRandomization key", d, ("effects", "joints", "ranges"))
        for key in ("effects", "joints"):
            if key not in d:
                raise ConfigError(f"a DomainRandomization dict needs {key!r} (to_dict() "
                                  "writes effects, joints and ranges)")
        ranges = {k: {p: (v[0], v[1]) for p, v in r.items()}
                  for k, r in dict(d.get("ranges", {})).items()}
        def names(v: Any) -> Any:  # a string stays one, for __post_init__ to refuse
            return v if isinstance(v, str) else tuple(v)

        return cls(names(d["effects"]), names(d["joints"]), ranges)

    def sample(self, rng: np.random.Generator) -> list[AppliedEffect]:
        """Draw one set of effect values (seeded by ``rng``)."""
        out = []
        n = len(self.joints)
        for name in self.effects:
            cls = effect(name)
            vals = cls.sample(rng, (n,))
            given = self.ranges.get(name, {})
            # in the effect's parameter order, not the mapping's: a config written with sorted
            # keys (json sort_keys) and read back draws the same values
            for p in [q.name for q in cls.params if q.name in given]:
                lo, hi = (np.broadcast_to(np.asarray(x, float), (n,)) for x in given[p])
                fixed = ~np.isfinite(lo)  # held off at a non-finite null (checked above)
                draw = rng.uniform(np.where(fixed, 0.0, lo), np.where(fixed, 0.0, hi), size=n)
                vals[p] = np.where(fixed, lo, draw)
            out.append(AppliedEffect(name, self.joints, vals))
        return out


# ROBEL RandomDynamics / OpenAI-style defaults for the D'Claw's servos.
DEFAULT_DR_EFFECTS: tuple[str, ...] = (
    "coulomb_friction", "viscous_damping", "gain_error", "latency", "backlash", "inertia_error",
    "mass_error", "observation_noise", "action_noise",
)


EXTENDED_MODEL_FORMAT = "lowcostdex.extended_model"
"""The ``format`` of a gap report's ``extended/effects.json`` (``lowcostdex.gap.extension``)."""


def read_effects(path: str) -> list[AppliedEffect]:
    """The effects in a JSON file (a list of ``AppliedEffect.to_dict()`` objects, or the
    ``effects`` of a gap report's ``extended/effects.json``; the report's folder, its
    ``report.json`` or its ``extended/`` folder read that file), as the ``--effects FILE``
    options take them; raises InputError naming the file and the entry."""
    import json

    from lowcostdex.errors import InputError

    folder = Path(path)
    if folder.is_file() and folder.name == "report.json":  # a gap report: its extended/'s
        folder = folder.parent
    for inner in ("effects.json", "extended/effects.json"):  # a report or extended/ folder
        if folder.is_dir() and (folder / inner).is_file():
            path = str(folder / inner)  # before: "[Errno 21] Is a directory" / "got dict"
            break
    else:
        if folder.is_dir():
            raise InputError(f"--effects {path}: a folder without effects.json; give the JSON "
                             "file, or a gap report's folder (its extended/effects.json)")
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except FileNotFoundError:
        raise InputError(f"--effects {path}: no such file") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"--effects {path}: not a readable JSON file ({exc}); it holds a list "
                         'of effects like [{"effect": "latency", "joints": ["ff_top"], '
                         '"params": {"delay": 0.02}}]') from None
    if (isinstance(data, dict) and data.get("format") == EXTENDED_MODEL_FORMAT
            and isinstance(data.get("effects"), list)):
        data = data["effects"]  # a gap report's extended/effects.json: the effects it named
    if not isinstance(data, list):
        raise InputError(f"--effects {path}: must hold a JSON list of effects (or be a gap "
                         f"report's extended/effects.json), got {type(data).__name__}")
    out = []
    for i, d in enumerate(data):
        try:
            out.append(AppliedEffect.from_dict(d))
        except ConfigError as exc:
            raise InputError(f"--effects {path}: entry {i}: {exc}") from None
    return out
