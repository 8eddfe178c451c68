"""The transfer loop's per-robot pieces: one finger's identification on a robot (its logs, then
``gap analyze`` on the nominal one-finger model), the analysis' causes as one per-joint table, and
the ``randomize`` argument of each simulated training condition (nominal, the project's domain
randomization, the identified model, the identified model with narrow randomization around it).
The loop that runs them is ``lowcostdex.transfer.loop``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from lowcostdex.transfer.config import NARROW_PAD, Size


def identify_finger(robot: Any, finger: str, folder: Path, size: Size, seed: int
                    ) -> dict[str, Any]:
    """Identification logs of one finger on the robot (without its valve, the other fingers
    parked), then the gap analysis on the nominal one-finger model."""
    from lowcostdex.gap import GapConfig, analyze, load_dataset, write_report
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.hardware.robot.trace import dclaw_identification_logs
    from lowcostdex.outdir import archive
    from lowcostdex.sim.models.dclaw import build_dclaw

    nominal = folder / f"nominal_{finger}.xml"
    if folder.exists():  # cut short: redone whole, the old pieces kept
        archive(folder, ["logs", "report", nominal.name])
    folder.mkdir(parents=True, exist_ok=True)
    hand = dclaw_spec(robot.motor)
    joints = tuple(j for j in hand.joint_names if j.startswith(finger + "_"))
    t0 = time.perf_counter()
    paths = dclaw_identification_logs(hand, joints, folder / "logs", size.id_logs,
                                      size.id_seconds, np.random.default_rng(seed),
                                      port=robot.identification_port(seed),
                                      latency_ms=robot.latency_ms)
    t1, c1 = time.perf_counter(), time.process_time()
    nominal.write_text(build_dclaw("none", hand, thermal=False, fingers=(finger,)).to_xml())
    dataset = load_dataset([str(p) for p in paths], model=str(nominal))
    result = analyze(dataset, GapConfig(seed=seed, **dict(size.gap)))
    write_report(result, folder / "report")
    report = json.loads((folder / "report" / "report.json").read_text())
    causes = [{"effect": c["effect"], "joints": c["joints"],
               "params": {p: {"value": v["value"], "interval": v.get("interval")}
                          for p, v in c["params"].items()}} for c in report["causes"]]
    return {"finger": finger, "joints": list(joints), "verdict": report["verdict"],
            "causes": causes, "robot_seconds": size.id_logs * size.id_seconds,
            "baseline_rmse_mrad": 1e3 * report["gain"]["baseline_rmse"],
            "extended_rmse_mrad": 1e3 * report["gain"]["extended_rmse"],
            "noise_floor_mrad": 1e3 * report["noise_floor"]["rmse"],
            "record_wall_seconds": round(t1 - t0, 1),
            "analysis_wall_seconds": round(time.perf_counter() - t1, 1),
            # CPU of this process (the wall time grows with a shared machine's load)
            "analysis_cpu_seconds": round(time.process_time() - c1, 1)}


def identified_effects(ident: dict[str, Any], joints: tuple[str, ...]
                       ) -> dict[str, dict[str, tuple[list[float], list[float], list[float]]]]:
    """The analysis' causes of every finger as one per-joint table: effect -> parameter ->
    (value, interval low, interval high) per hand joint; joints where the effect was not named
    hold its null value (its interval collapsed on it)."""
    from lowcostdex.sim.effects import effect

    table: dict[str, dict[str, tuple[list[float], list[float], list[float]]]] = {}
    for finger in ident["fingers"].values():
        for cause in finger["causes"]:
            cls = effect(cause["effect"])
            entry = table.setdefault(cls.name, {
                p.name: ([p.null] * len(joints), [p.null] * len(joints), [p.null] * len(joints))
                for p in cls.params})
            for p, v in cause["params"].items():
                values = np.broadcast_to(np.asarray(v["value"], float), (len(cause["joints"]),))
                interval = v.get("interval")
                for i, j in enumerate(cause["joints"]):
                    k = joints.index(j)
                    entry[p][0][k] = float(values[i])
                    lo, hi = (interval[i] if interval is not None and len(interval) > i
                              else (values[i], values[i]))
                    entry[p][1][k], entry[p][2][k] = float(lo), float(hi)
    return table


def condition_randomize(condition: str, ident: dict[str, Any] | None,
                        joints: tuple[str, ...]) -> Any:
    """The ``randomize`` env kwarg of a simulated training condition (JSON-serializable)."""
    from lowcostdex.sim.effects import DEFAULT_DR_EFFECTS, DomainRandomization, effect

    if condition == "nominal":
        return None
    if condition == "randomized":
        return list(DEFAULT_DR_EFFECTS)
    if condition not in ("identified", "identified_randomized"):
        raise ValueError(f"{condition!r} is not a simulated condition")
    assert ident is not None
    table = identified_effects(ident, joints)
    if not table:
        return None  # nothing named: the nominal model
    ranges: dict[str, dict[str, tuple[list[float], list[float]]]] = {}
    for name, params in table.items():
        ranges[name] = {}
        for p, (value, lo, hi) in params.items():
            if condition == "identified":
                ranges[name][p] = (value, value)
                continue
            param = effect(name).param(p)
            v, lo_, hi_ = (np.asarray(x, float) for x in (value, lo, hi))
            lo_ = np.where(np.isfinite(lo_), lo_, v)
            hi_ = np.where(np.isfinite(hi_), hi_, v)
            pad = NARROW_PAD * np.abs(v)
            named = v != param.null  # joints without the effect keep it off
            with np.errstate(invalid="ignore"):  # inf - inf where a null is inf (not named)
                low = np.where(named, np.minimum(lo_, v - pad), v)
                high = np.where(named, np.maximum(hi_, v + pad), v)
            # joints without the effect keep its null, also a non-finite one (no velocity limit)
            low = np.where(named, np.clip(low, param.low, param.high), v)
            high = np.where(named, np.clip(high, param.low, param.high), v)
            ranges[name][p] = (low.tolist(), np.maximum(high, low).tolist())
    return DomainRandomization(tuple(table), joints, ranges).to_dict()


def condition_model(condition: str, ident: dict[str, Any] | None, joints: tuple[str, ...]
                    ) -> tuple[Any, dict[str, Any] | None]:
    """The ``randomize`` and ``model_edit`` env kwargs of a simulated training condition: the
    identified ones train in the robot's valve-log fit (``ident["valve_fit"]``) when it has
    one; ``identified_randomized`` also draws the valve's friction and damping per episode
    around the fit (``valve_fit.randomized_valve``), not only the servo effects."""
    randomize = condition_randomize(condition, ident, joints)
    fit = (ident or {}).get("valve_fit")
    if fit is None or condition not in ("identified", "identified_randomized"):
        return randomize, None
    if condition == "identified":
        return randomize, fit["model_edit"]
    from lowcostdex.sim.envs.dclaw_tasks import TurnValve
    from lowcostdex.transfer.valve_fit import randomized_valve

    nominal = float(TurnValve().build_spec().joint("valve").damping[0])
    return randomized_valve(randomize, fit, nominal)
