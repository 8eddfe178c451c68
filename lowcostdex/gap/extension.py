"""The extended model: fitted effects saved so the sim, the emulator and DR can load them.

An extended model is a folder:

    effects.json            the fitted effects (``AppliedEffect.to_dict`` + intervals), which of
                            them are baked into the MJCF, and domain-randomization ranges taken
                            from the fitted intervals
    nominal_<key>.xml       each nominal model the analysis replayed (one per bench setup)
    extended_<key>.xml      the same with every MJCF-expressible effect baked in (latency as an
                            actuator delay, friction/damping/armature on the joint, gains and
                            force limits on the actuator, masses on the body)

Effects MJCF cannot express (backlash, Stribeck and load-dependent friction, position offset,
thermal derating, voltage sag, a velocity limit's torque-speed line on a force-limited actuator) live only in effects.json and act through the ``Plant``. Two ways
to use it: ``ExtendedModel.plant()`` (nominal model + every effect through the Plant: the one
source of truth; a backlash is the play hinge the analysis replayed, which adds a dof per
joint, or with ``hidden_dofs=False`` the play operator in the nominal qpos layout, which the
emulator and the envs' backends still use), or ``extended_<key>.xml`` with
``ExtendedModel.residual_effects`` for consumers that want a plain MJCF.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.outdir import user_path
from lowcostdex.sim.effects import EFFECTS, AppliedEffect, DomainRandomization, Targets, effect
from lowcostdex.sim.effects.randomization import EXTENDED_MODEL_FORMAT
from lowcostdex.sim.plant import Plant, prepare_spec

FORMAT = EXTENDED_MODEL_FORMAT
# Model-field effects MuJoCo's spec can hold (copy_back writes them; latency is an actuator delay).
MJCF_EXPRESSIBLE = ("latency", "coulomb_friction", "viscous_damping", "gain_error",
                    "torque_limit", "velocity_limit", "inertia_error", "mass_error")


def bake_mjcf(xml: str, effects: Sequence[AppliedEffect]) -> tuple[str, list[str]]:
    """Write the MJCF-expressible effects into a model.

    Args:
      xml: nominal MJCF.
      effects: fitted effects.
    Returns:
      (extended MJCF, names of the effects baked in). Effects the spec cannot hold are left out
      (they stay in effects.json).
    """
    baked: list[str] = []
    order = {name: i for i, name in enumerate(EFFECTS)}  # the Plant applies them in this order
    # a velocity limit on a torque-speed line (finite speed) and a direction-dependent Coulomb
    # level are state-dependent: Plant only
    candidates = sorted((e for e in effects if e.name in MJCF_EXPRESSIBLE
                         and not (e.cls.live and np.any(np.isfinite(e.values["speed"])))
                         and not e.cls.substep(e.values)),
                        key=lambda e: order[e.name])
    for e in candidates:
        spec = mujoco.MjSpec.from_string(xml)
        prepare_spec(spec, [e])
        model = spec.compile()
        plant = Plant(model, [e])
        try:
            spec.copy_back(plant.model)
        except ValueError:
            continue
        if e.name == "latency":
            t, (delay,) = Targets.resolve(model, e.joints).servos((), e.values["delay"])
            for a, d in zip(t.actuators, delay, strict=True):  # (a tendon's servo: once)
                spec.actuator(model.actuator(int(a)).name).delay = float(d)
        xml = spec.to_xml()
        baked.append(e.name)
    return xml, baked


def dr_ranges(effects: Sequence[AppliedEffect], intervals: dict[str, dict[str, list]] | None
              ) -> dict[str, dict[str, tuple[float, float]]]:
    """Domain-randomization ranges from fitted values and their 95 % intervals.

    Per effect parameter: the hull over joints of the intervals, widened to at least +-10 % of
    the value (an interval from one data set understates unit-to-unit spread), clipped to the
    parameter's bounds.
    """
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for e in effects:
        cls = effect(e.name)
        rng: dict[str, tuple[float, float]] = {}
        for p in cls.params:
            vals = np.asarray(e.values[p.name], float)
            iv = (intervals or {}).get(e.name, {}).get(p.name)
            lo = np.min(vals) if iv is None else min(v[0] for v in iv)
            hi = np.max(vals) if iv is None else max(v[1] for v in iv)
            pad = 0.1 * np.max(np.abs(vals))
            lo, hi = min(lo, np.min(vals) - pad), max(hi, np.max(vals) + pad)
            lo = float(np.clip(lo if math.isfinite(lo) else p.low, p.low, p.high))
            hi = float(np.clip(hi if math.isfinite(hi) else p.high, p.low, p.high))
            rng[p.name] = (lo, max(hi, lo))
        out[e.name] = rng
    return out


def save_extended(folder: str | Path, models: dict[str, str], effects: Sequence[AppliedEffect],
                  intervals: dict[str, dict[str, list]] | None = None) -> Path:
    """Write an extended-model folder (see the module docstring). ConfigError before writing
    when ``folder`` is a file or a model does not compile (before: a folder load_extended then
    refused, or FileExistsError)."""
    folder = user_path(folder)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"{folder} is a file; save_extended writes a folder")
    for key, xml in models.items():
        try:
            mujoco.MjSpec.from_string(xml).compile()
        except Exception as exc:  # mujoco raises ValueError with the parser's message
            raise ConfigError(f"model {key!r} does not compile: {exc}") from None
    folder.mkdir(parents=True, exist_ok=True)
    files = {}
    baked_all: set[str] = set()
    for i, (key, xml) in enumerate(sorted(models.items())):
        tag = _tag(key, i)
        ext, baked = bake_mjcf(xml, effects)
        baked_all.update(baked)
        (folder / f"nominal_{tag}.xml").write_text(xml)
        (folder / f"extended_{tag}.xml").write_text(ext)
        files[key] = {"nominal": f"nominal_{tag}.xml", "extended": f"extended_{tag}.xml"}
    ranges = dr_ranges(effects, intervals)
    joints = sorted({j for e in effects for j in e.joints})
    payload = {
        "format": FORMAT,
        "version": 1,
        "effects": [{**e.to_dict(), "in_mjcf": e.name in baked_all,
                     "interval": (intervals or {}).get(e.name, {})} for e in effects],
        "domain_randomization": {"effects": [e.name for e in effects], "joints": joints,
                                 "ranges": {k: {p: list(v) for p, v in r.items()}
                                            for k, r in ranges.items()}},
        "models": files,
    }
    (folder / "effects.json").write_text(json.dumps(payload, indent=2))
    return folder


def _tag(key: str, i: int) -> str:
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in key)
    return safe if len(safe) <= 60 else f"model{i}"


@dataclass
class ExtendedModel:
    """A loaded extended model.

    Attributes:
      effects: every fitted effect.
      residual_effects: the effects not baked into the extended MJCF.
      nominal: {key: nominal MJCF}.
      extended: {key: extended MJCF}.
      ranges: domain-randomization ranges {effect: {param: (low, high)}}.
      dr_joints: joints the ranges apply to.
    """

    effects: list[AppliedEffect]
    residual_effects: list[AppliedEffect]
    nominal: dict[str, str]
    extended: dict[str, str]
    ranges: dict[str, dict[str, tuple[float, float]]]
    dr_joints: tuple[str, ...]

    def key(self, key: str | None) -> str:
        if key is None:
            if len(self.nominal) != 1:
                raise ConfigError(f"several models; pass key= one of {sorted(self.nominal)}")
            return next(iter(self.nominal))
        if key not in self.nominal:
            raise ConfigError(f"unknown model {key!r}; models: {sorted(self.nominal)}")
        return key

    def plant(self, key: str | None = None, rng: np.random.Generator | None = None,
              hidden_dofs: bool = True) -> Plant:
        """A Plant of the nominal model with every fitted effect applied.

        ``hidden_dofs`` (default): a backlash is the play hinge the analysis replays (the
        model gains a ``<joint>__play`` hinge after each such joint, so its qpos layout
        differs from the nominal one; ``Plant.measured_qpos`` reads the link, joint + play).
        False: the nominal qpos layout, backlash as the massless-motor play operator on the
        goal (for consumers that share a task model's state layout).
        """
        spec = mujoco.MjSpec.from_string(self.nominal[self.key(key)])
        prepare_spec(spec, self.effects, hidden_dofs=hidden_dofs)
        return Plant(spec.compile(), self.effects, rng=rng)

    def domain_randomization(self, joints: Sequence[str] | None = None) -> DomainRandomization:
        """Randomize the fitted effects within their fitted ranges (e.g. for ``HandEnv``, which
        checks ``joints`` against its model); one string is one joint (it was read letter by
        letter)."""
        if isinstance(joints, str):
            joints = (joints,)
        return DomainRandomization(tuple(self.ranges), tuple(joints or self.dr_joints),
                                   self.ranges)


def load_extended(folder: str | Path) -> ExtendedModel:
    """Load a folder written by ``save_extended`` (or a report folder's ``extended/``; a file
    in either, e.g. its ``effects.json`` or ``report.json``, reads its folder: before, "no
    effects.json" was said of the effects.json itself)."""
    given = folder = user_path(folder)
    if folder.is_file():
        folder = folder.parent
    path = folder / "effects.json"
    if not path.exists() and (folder / "extended" / "effects.json").exists():
        folder, path = folder / "extended", folder / "extended" / "effects.json"
    if not path.exists():
        why = ("no such folder" if not given.exists() else
               f"no effects.json {'beside it' if given != folder else 'in it'}")
        raise ConfigError(f"{given}: {why} (not an extended model folder: a gap report's "
                          "extended/ holding effects.json, or the report's folder)")
    raw = json.loads(path.read_text())
    if raw.get("format") != FORMAT:
        raise ConfigError(f"{path}: not a {FORMAT} file")
    effects = [AppliedEffect.from_dict(d) for d in raw["effects"]]
    residual = [e for e, d in zip(effects, raw["effects"], strict=True) if not d["in_mjcf"]]
    nominal = {k: (folder / v["nominal"]).read_text() for k, v in raw["models"].items()}
    extended = {k: (folder / v["extended"]).read_text() for k, v in raw["models"].items()}
    dr = raw["domain_randomization"]
    ranges = {k: {p: (float(v[0]), float(v[1])) for p, v in r.items()}
              for k, r in dr["ranges"].items()}
    return ExtendedModel(effects, residual, nominal, extended, ranges, tuple(dr["joints"]))
