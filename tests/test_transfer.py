"""Hidden robots (lowcostdex.hardware.emulated.hidden_robots) and the transfer loop
(lowcostdex.transfer, ``lowcostdex transfer``).

The hidden robots stand in for real D'Claws: each must differ measurably from the nominal
model, seen by a host through the real driver path, and be the same robot under the same seed.
The firmware imperfection is checked against its physics written out here (an encoder reading
q + A sin(q + phase), a position loop that does not act on errors below its deadband).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.hands import dclaw_spec
from lowcostdex.hardware.emulated.chain import emulated_dclaw
from lowcostdex.hardware.emulated.hidden_robots import (
    FirmwareImperfection,
    ModelPerturbation,
    hidden_robot,
    hidden_robots,
    pwm_deadband_error,
)
from lowcostdex.hardware.robot.backend import make_dynamixel_bus
from lowcostdex.sim.models.dclaw import build_dclaw

HAND = dclaw_spec()
TICK = 2 * math.pi / 4096  # [rad] one encoder tick of an XH430
START = np.array([0.0, -1.0, 1.0] * 3)  # [rad] fingers bent, clear of each other
STEP = np.array([0.3, 0.3, 0.3] * 3)  # [rad] a step on every joint


def _bus(chain):
    model = build_dclaw("none", chain.hand).compile()
    return make_dynamixel_bus(chain.hand, chain.port(), model)


def _goals(q: np.ndarray) -> np.ndarray:
    return np.array([j.calibration.to_motor(v) for j, v in zip(HAND.joints, q, strict=True)])


def step_response(chain, seconds: float = 0.3, period: float = 0.01) -> np.ndarray:
    """Joint readings [rad] (k, 9) a host sees after a step from START to START + STEP, read
    through DynamixelBus on the chain's port every ``period`` [s]."""
    ids = [j.motor_id for j in HAND.joints]
    out = []
    with _bus(chain) as bus:
        bus.set_torque(True)
        bus.write_goal_positions(_goals(START), ids)
        bus.sleep(1.0)
        bus.write_goal_positions(_goals(START + STEP), ids)
        for _ in range(round(seconds / period)):
            bus.sleep(period)
            state = bus.read_state()
            out.append([j.calibration.to_joint(p) for j, p in
                        zip(HAND.joints, state.position[:9], strict=True)])
    return np.array(out)


@pytest.fixture(scope="module")
def nominal_response() -> np.ndarray:
    return step_response(emulated_dclaw("none", effects=()))


def test_every_hidden_robot_differs_from_nominal_in_every_finger(nominal_response):
    for robot in hidden_robots(3, seed=0):
        diff = np.abs(step_response(robot.chain("none")) - nominal_response).max(axis=0)
        per_finger = diff.reshape(3, 3).max(axis=1)
        # more than 3 encoder ticks in every finger, more than 10 mrad somewhere
        assert np.all(per_finger > 3 * TICK), (robot.name, per_finger)
        assert diff.max() > 0.010, (robot.name, diff)


def test_a_hidden_robot_is_deterministic_under_its_seed():
    a, b, c = hidden_robot(7), hidden_robot(7), hidden_robot(8)
    assert a.to_dict() == b.to_dict()
    assert a.to_dict() != c.to_dict()
    ra, rb = step_response(a.chain("none")), step_response(b.chain("none"))
    np.testing.assert_array_equal(ra, rb)


def test_hidden_robots_mix_effects_per_finger():
    robots = hidden_robots(3, seed=0)
    mixes = [tuple(e.name for e in r.effects) for r in robots]
    assert len(set(mixes)) == 3  # each robot its own mix
    partial = 0
    for r in robots:
        assert 3 <= len(r.effects) <= 5
        for e in r.effects:
            name, values = next(iter(e.values.items()))
            rows = values.reshape(3, 3)  # finger x joint
            carried = [row for row in rows if not np.allclose(row, e.cls.param(name).null)]
            assert carried, (r.name, e.name)
            # different per finger: no two fingers that carry the effect share values
            assert len({tuple(row) for row in carried}) == len(carried), (r.name, e.name)
            partial += len(carried) < 3
    assert partial > 0  # some effect is on some fingers only


def test_model_perturbation_edits_the_mjcf():
    p = ModelPerturbation(link_mass={"ff_link1": 1.05}, link_length={"mf": 0.97},
                          base_tilt={"th": ((1.0, 0.0, 0.0), math.radians(3.0))},
                          valve_frictionloss=0.01, valve_damping=1.5, valve_inertia=1.2)
    nominal = build_dclaw("valve").compile()
    spec = build_dclaw("valve")
    p.apply(spec)
    m = spec.compile()
    body = lambda model, n: model.body(n).id  # noqa: E731
    assert m.body_mass[body(m, "ff_link1")] == pytest.approx(
        1.05 * nominal.body_mass[body(nominal, "ff_link1")])
    assert m.body_pos[body(m, "mf_link2")][2] == pytest.approx(
        0.97 * nominal.body_pos[body(nominal, "mf_link2")][2])
    # a 3 deg tilt of the base about its x axis: the angle between the quaternions is 3 deg
    q0, q1 = nominal.body_quat[body(nominal, "th_base")], m.body_quat[body(m, "th_base")]
    assert 2 * math.degrees(math.acos(min(1.0, abs(float(np.dot(q0, q1)))))) == pytest.approx(3.0)
    j0, j1 = nominal.joint("valve"), m.joint("valve")
    assert m.dof_frictionloss[j1.dofadr[0]] == pytest.approx(
        nominal.dof_frictionloss[j0.dofadr[0]] + 0.01)
    assert m.dof_damping[j1.dofadr[0]] == pytest.approx(1.5 * nominal.dof_damping[j0.dofadr[0]])
    assert m.body_mass[body(m, "valve_body")] == pytest.approx(
        1.2 * nominal.body_mass[body(nominal, "valve_body")])
    # the station without a valve takes the same perturbation
    spec = build_dclaw("none")
    p.apply(spec)
    spec.compile()


def test_pwm_deadband_in_position_error():
    # XH430-W350 factory Position P 900: K_PP = 900 / 128 PWM units per tick of error
    assert pwm_deadband_error(900 / 128 * 3, "XH430-W350") == pytest.approx(3 * TICK)


def test_encoder_nonlinearity_reads_q_plus_a_sin_and_the_servo_tracks_its_reading():
    amp, phase = 0.01, 0.7  # [rad]
    fw = FirmwareImperfection(amplitude={"ff_middle": amp}, phase={"ff_middle": phase})
    chain = emulated_dclaw("none", effects=(), imperfection=fw)
    ids = [j.motor_id for j in HAND.joints]
    with _bus(chain) as bus:
        bus.set_torque(True)
        bus.write_goal_positions(_goals(START + 0.2), ids)
        bus.sleep(1.5)
        reading = HAND.joints[1].calibration.to_joint(bus.read_state().position[1])
    true = chain.drive.true_position(1)
    # the reading is the encoder's: q + A sin(q + phase), within a tick of quantization
    assert abs(reading - (true + amp * math.sin(true + phase))) < 1.5 * TICK
    # the servo closes its loop on that reading: it rests where the encoder says "goal"
    assert abs(reading - (START[1] + 0.2)) < 3 * TICK
    assert abs(true - (START[1] + 0.2)) > 0.5 * amp * abs(math.sin(true + phase))


def test_position_deadband_ignores_small_errors_and_acts_on_large_ones():
    band = 0.01  # [rad]
    fw = FirmwareImperfection(deadband={j.name: band for j in HAND.joints})
    moved = {}
    for name, kwargs in (("ideal", {}), ("deadband", {"imperfection": fw})):
        chain = emulated_dclaw("none", effects=(), **kwargs)
        ids = [j.motor_id for j in HAND.joints]
        with _bus(chain) as bus:
            bus.set_torque(True)
            bus.write_goal_positions(_goals(START), ids)
            bus.sleep(1.5)
            before = chain.drive.true_position(0)
            bus.write_goal_positions(_goals(START + np.r_[0.5 * band, [0.0] * 8]), ids)
            bus.sleep(1.0)
            small = chain.drive.true_position(0) - before
            bus.write_goal_positions(_goals(START + np.r_[0.1, [0.0] * 8]), ids)
            bus.sleep(1.0)
            large = chain.drive.true_position(0) - before
        moved[name] = (small, large)
    assert moved["ideal"][0] == pytest.approx(0.5 * band, abs=2 * TICK)
    assert abs(moved["deadband"][0]) < 2 * TICK  # a half-band step does not move the joint
    # a large step does, and stops within the band of its goal
    assert abs(moved["deadband"][1] - 0.1) < band + 2 * TICK
    assert moved["deadband"][1] > 0.1 - band - 2 * TICK


def test_the_training_side_importing_the_hidden_robots_breaks_a_contract(tmp_path):
    import os
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    lint = shutil.which("lint-imports", path=os.path.dirname(sys.executable))
    assert lint, "lint-imports is missing: install the dev extra"
    shutil.copytree(root / "lowcostdex", tmp_path / "lowcostdex",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(root / "pyproject.toml", tmp_path / "pyproject.toml")
    train = tmp_path / "lowcostdex" / "algos" / "dapg.py"
    train.write_text(train.read_text() + "\nimport lowcostdex.hardware.emulated.hidden_robots  # noqa\n")
    res = subprocess.run([lint, "--config", str(tmp_path / "pyproject.toml"), "--no-cache"],
                         cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(tmp_path)},
                         capture_output=True, text=True, timeout=300)
    assert res.returncode != 0
    assert "lowcostdex.algos.dapg -> lowcostdex.hardware.emulated.hidden_robots" in res.stdout


# ------------------------------------------------------------------------------------------------
# the transfer loop (lowcostdex.transfer)


IDENT = {"fingers": {"ff": {"causes": [
    {"effect": "latency", "joints": ["ff_top", "ff_middle", "ff_bottom"],
     "params": {"delay": {"value": [0.010, 0.012, 0.020],
                          "interval": [[0.0099, 0.0101], [0.011, 0.013], [0.019, 0.021]]}}},
]}, "mf": {"causes": [
    {"effect": "gain_error", "joints": ["mf_top", "mf_middle", "mf_bottom"],
     "params": {"scale": {"value": [0.8, 0.9, 1.2], "interval": None}}},
]}}}


def test_identified_conditions_load_the_fitted_values_per_joint():
    from lowcostdex.sim.effects import DomainRandomization
    from lowcostdex.transfer.loop import condition_randomize

    joints = HAND.joint_names
    fixed = DomainRandomization.from_dict(condition_randomize("identified", IDENT, joints))
    narrow = DomainRandomization.from_dict(
        condition_randomize("identified_randomized", IDENT, joints))
    assert set(fixed.effects) == {"latency", "gain_error"}
    delay = [0.010, 0.012, 0.020] + [0.0] * 6  # mf, th: not named, latency off
    scale = [1.0] * 3 + [0.8, 0.9, 1.2] + [1.0] * 3
    for _ in range(3):
        by_name = {e.name: e for e in fixed.sample(np.random.default_rng(_))}
        np.testing.assert_allclose(by_name["latency"].values["delay"], delay)
        np.testing.assert_allclose(by_name["gain_error"].values["scale"], scale)
    lo, hi = (np.asarray(x) for x in narrow.ranges["latency"]["delay"])
    # the interval, widened to at least +-10 % of the value; not-named joints stay at the null
    np.testing.assert_allclose(lo[:3], [0.009, 0.0108, 0.018])
    np.testing.assert_allclose(hi[:3], [0.011, 0.0132, 0.022])
    np.testing.assert_array_equal(lo[3:], 0.0)
    np.testing.assert_array_equal(hi[3:], 0.0)
    lo, hi = (np.asarray(x) for x in narrow.ranges["gain_error"]["scale"])
    np.testing.assert_allclose(lo[3:6], [0.72, 0.81, 1.08])  # no interval: +-10 %
    np.testing.assert_allclose(hi[3:6], [0.88, 0.99, 1.32])
    assert condition_randomize("nominal", None, joints) is None
    assert condition_randomize("identified", {"fingers": {}}, joints) is None


def test_a_velocity_limit_named_on_one_finger_leaves_the_others_unlimited():
    """velocity_limit's null is an infinite speed (no limit): named on ff only, (c) and (d)
    keep mf and th unlimited (before: (c) refused its own ranges and the run stopped; (d)
    clipped the null to 10 rad/s on every joint). Truth: the nominal env on the same actions."""
    import json

    import gymnasium as gym

    from lowcostdex.sim.effects import DomainRandomization
    from lowcostdex.transfer.loop import condition_randomize

    joints = HAND.joint_names
    ident = {"fingers": {"ff": {"causes": [{
        "effect": "velocity_limit", "joints": ["ff_top", "ff_middle", "ff_bottom"],
        "params": {"scale": {"value": 0.5, "interval": [[0.45, 0.55]] * 3},
                   "speed": {"value": 3.0, "interval": [[2.8, 3.2]] * 3}}}]}}}
    for condition in ("identified", "identified_randomized"):
        kwargs = json.loads(json.dumps(condition_randomize(condition, ident, joints)))
        dr = DomainRandomization.from_dict(kwargs)  # as a run's config reads it back
        values = dr.sample(np.random.default_rng(0))[0].values
        speed, scale = values["speed"], values["scale"]
        assert np.all((speed[:3] >= 2.7) & (speed[:3] <= 3.3)) and np.all(np.isinf(speed[3:]))
        assert np.all((scale[:3] >= 0.45) & (scale[:3] <= 0.55)) and np.all(scale[3:] == 1.0)
        trails = []
        for extra in ({}, {"randomize": kwargs}):
            env = gym.make("lowcostdex/DClawTurnValve-v0", **extra)
            env.reset(seed=3)
            for _ in range(3):
                env.step(np.full(9, 0.8))
            trails.append(env.unwrapped.data.qpos[:9].copy())
            env.close()
        # the D'Claw's dcmotors take scale (half the no-load speed on ff), not speed
        assert np.max(np.abs(trails[1][:3] - trails[0][:3])) > 1e-3
        np.testing.assert_allclose(trails[1][3:], trails[0][3:], atol=1e-6)  # mf, th as nominal


def _row(cond, robot, k, n=10, made_for=None, seed=0):
    return {"algo": "dapg", "condition": cond, "robot": robot, "seed": seed, "success": k,
            "episodes": n, "policy_robot": made_for, "final_error": [0.05] * n,
            "sim_success": n, "sim_episodes": n, "sim_final_error": [0.01, 0.02] * (n // 2),
            "policy": f"dapg/{cond}" + (f"_{made_for}" if made_for else ""),
            "train_wall_seconds": 1.0}


def test_the_table_counts_each_policy_on_its_own_robot_and_the_cross_table_the_others():
    from lowcostdex.transfer.loop import cross_markdown, summarize

    rows = [_row("nominal", "A", 3), _row("nominal", "B", 5),
            _row("identified", "A", 9, made_for="A"), _row("identified", "B", 1, made_for="A"),
            _row("identified", "A", 2, made_for="B"), _row("identified", "B", 7, made_for="B")]
    s = summarize(rows, ["A", "B"])
    # own robot only: identified A->A 9/10 and B->B 7/10; the nominal policy on both
    assert s["identified"]["per_robot"] == {"A": (9, 10), "B": (7, 10)}
    assert s["identified"]["robots"] == (16, 20)
    assert s["identified"]["sim"] == (20, 20)  # two policies, each evaluated once in its sim
    assert s["identified"]["drop"] == pytest.approx(1.0 - 0.8)
    assert s["nominal"]["robots"] == (8, 20) and s["nominal"]["sim"] == (10, 10)
    # policy-robot pairs working on at least half their episodes: 9/10 and 7/10 both; the
    # nominal policy 3/10 on A does not, 5/10 on B does (exactly half)
    assert s["identified"]["pairs"] == (2, 2) and s["nominal"]["pairs"] == (1, 2)
    text = cross_markdown(rows, ["A", "B"])
    lines = text.splitlines()
    assert lines[2].startswith("| nominal | - | 0.30 ") and "| 0.50 " in lines[2]
    assert lines[3].startswith("| identified | A | **0.90 ") and lines[3].count("0.10 [") == 1
    assert lines[4].startswith("| identified | B | 0.20 ") and "**0.70 " in lines[4]
    # pooled: own 16/20, others (1 + 2)/20
    assert "identified: own robot 0.80 " in text and "other robots 0.15 " in text


def test_the_final_error_and_the_looser_tolerance_do_not_flip_where_success_does():
    """Two conditions whose policies end 0.099 and 0.101 rad from the goal (a 0.1 rad task
    tolerance): success 1.00 vs 0.00, final error 0.099 vs 0.101, both 1.00 at 0.12 rad. A
    third over 3 seeds of 10 episodes, its final errors 0.080, 0.081, ..., 0.109 rad: the
    median is (0.094 + 0.095) / 2, the 95 % interval the 10th and 21st of the 30 sorted values
    (P(Bin(30, 1/2) <= 9) = 0.0214, P(B <= 10) = 0.0494), each seed's median the mean of its
    5th and 6th values; 20 of 30 under 0.1 rad, 30 under 0.12 rad."""
    from lowcostdex.transfer.loop import cells_json, errors_markdown, summarize

    rows = [dict(_row("nominal", "A", 10), final_error=[0.099] * 10),
            dict(_row("randomized", "A", 0), final_error=[0.101] * 10)]
    for seed in range(3):
        errors = [round(0.080 + 0.010 * seed + 0.001 * i, 4) for i in range(10)]
        rows.append(dict(_row("identified", "A", sum(e < 0.1 for e in errors), made_for="A",
                              seed=seed), final_error=errors))
    s = summarize(rows, ["A"])
    assert s["nominal"]["per_robot"]["A"] == (10, 10)
    assert s["randomized"]["per_robot"]["A"] == (0, 10)
    near, far = s["nominal"]["errors"]["A"], s["randomized"]["errors"]["A"]
    assert near["median"] == pytest.approx(0.099) and far["median"] == pytest.approx(0.101)
    assert near["loose"] == (10, 10) and far["loose"] == (10, 10)
    ident = s["identified"]["errors"]["A"]
    assert ident["median"] == pytest.approx(0.0945)
    assert ident["low"] == pytest.approx(0.089) and ident["high"] == pytest.approx(0.100)
    assert ident["coverage"] == pytest.approx(1 - 2 * 0.021387, abs=1e-5)
    assert ident["per_seed"] == pytest.approx([0.0845, 0.0945, 0.1045])
    assert ident["seeds"] == [0, 1, 2]
    assert s["identified"]["per_robot"]["A"] == (20, 30) and ident["loose"] == (30, 30)
    lines = errors_markdown(s, ["A"]).splitlines()
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    assert head == ["condition", "final error on robot A [rad]", "robot A < 0.12 rad",
                    "mean on robots < 0.12 rad"]
    cells = {x[0]: x for x in ([c.strip() for c in line.strip("|").split("|")]
                               for line in lines[2:])}
    assert cells["nominal"][1].startswith("0.099 [0.099, 0.099]")
    assert cells["randomized"][1].startswith("0.101 [0.101, 0.101]")
    assert "[0.089, 0.100]; per seed " in cells["identified"][1]
    assert all(cells[c][2].startswith("1.00 [") for c in cells)
    # transfer.json's cells carry the same numbers
    by = {c["condition"]: c for c in cells_json({"npg": s}, ["A"])}
    assert by["identified"]["success"] == 20 and by["identified"]["success_loose"] == 30
    assert by["identified"]["final_error_interval"] == pytest.approx([0.089, 0.100])
    assert by["randomized"]["success"] == 0 and by["randomized"]["success_loose"] == 10
    assert by["nominal"]["loose_tolerance"] == 0.12 and by["nominal"]["algo"] == "npg"


def test_the_cost_table_puts_identification_plus_sim_training_beside_training_on_the_robot():
    """Numbers typed here: robot A identified from 3 fingers x 30 s of logs (recording 40 s
    each, analyses 100 / 200 / 300 s wall, 50 / 60 / 70 s CPU): 90 s of robot time, 120 + 600 s
    wall, 180 s CPU; its identified policies trained 60 and 80 s (seeds 0, 1): 70 s each, the
    first policy 720 + 70 = 790 s from nothing. On robot B: 2.5 and 3.5 h of robot time, 1200
    and 1400 s. The nominal policy has a row on each robot and is one policy."""
    from lowcostdex.transfer.loop import cost_markdown

    def row(cond, robot, made_for, seed, wall, **more):
        return dict(_row(cond, robot, 5, made_for=made_for, seed=seed), samples=48000,
                    train_wall_seconds=wall, **more)

    rows = [row("nominal", "A", None, 0, 30.0, train_cpu_seconds=20.0),
            row("nominal", "B", None, 0, 30.0, train_cpu_seconds=20.0),
            row("identified", "A", "A", 0, 60.0), row("identified", "B", "A", 0, 60.0),
            row("identified", "A", "A", 1, 80.0),
            row("identified", "B", "B", 0, 50.0),  # B not identified in this run
            row("on_robot", "B", "B", 0, 1200.0, robot_hours=2.5, train_cpu_seconds=600.0),
            row("on_robot", "B", "B", 1, 1400.0, robot_hours=3.5, train_cpu_seconds=700.0),
            row("on_robot", "A", "B", 0, 1200.0, robot_hours=2.5, train_cpu_seconds=600.0)]
    fingers = {f: {"robot_seconds": 30.0, "record_wall_seconds": 40.0,
                   "analysis_wall_seconds": wall, "analysis_cpu_seconds": cpu}
               for f, wall, cpu in (("ff", 100.0, 50.0), ("mf", 200.0, 60.0), ("th", 300.0, 70.0))}
    lines = cost_markdown(rows, {"A": {"fingers": fingers}}).splitlines()
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    cells = {(x[0], x[1]): dict(zip(head, x, strict=True))
             for x in ([c.strip() for c in line.strip("|").split("|")] for line in lines[2:])}
    assert set(cells) == {("nominal", "-"), ("identified", "A"), ("identified", "B"),
                          ("on_robot", "B")}
    nominal, ident, on_robot = (cells["nominal", "-"], cells["identified", "A"],
                                cells["on_robot", "B"])
    assert nominal["policies"] == "1" and nominal["robot time per policy [h]"] == "0"
    assert nominal["training CPU per policy [s]"] == "20"
    assert nominal["wall to the first policy [s]"] == "30"
    assert ident["policies"] == "2" and ident["samples per policy"] == "48000"
    assert ident["identification per robot: robot time [s]"] == "90"
    assert ident["robot time per policy [h]"] == "0.025 (identification)"
    assert ident["identification wall: recording + analysis [s]"] == "120 + 600"
    assert ident["analysis CPU [s]"] == "180"
    assert ident["training wall per policy [s]"] == "70"
    assert ident["training CPU per policy [s]"] == "-"  # not recorded in these rows
    assert ident["wall to the first policy [s]"] == "790"
    # B's identification is not in this run: its cost is unknown, not zero
    assert cells["identified", "B"]["wall to the first policy [s]"] == "-"
    assert cells["identified", "B"]["robot time per policy [h]"] == "-"
    assert on_robot["policies"] == "2" and on_robot["robot time per policy [h]"] == "3.00"
    assert on_robot["training wall per policy [s]"] == "1300"
    assert on_robot["training CPU per policy [s]"] == "650"
    assert on_robot["wall to the first policy [s]"] == "1300"


def test_time_left_counts_only_the_pieces_still_to_run():
    """A resume: 6 pieces, 3 of them found done (the 2nd, 4th and 6th); the others take 10 s
    each. After the first, 2 pieces of 10 s are left (20 s), not 5 pieces."""
    from lowcostdex.transfer.loop import Progress

    now = [0.0]
    lines: list[str] = []
    progress = Progress(6, lines.append, found=3, clock=lambda: now[0])
    for k in range(6):
        fresh = k % 2 == 0
        now[0] += 10.0 if fresh else 0.0
        progress.step(f"piece {k}", not fresh)
    assert "1/6 pieces (17 %), 10 s elapsed, about 20 s left" in lines[0]
    assert "2/6 pieces (33 %), 10 s elapsed, about 20 s left" in lines[1]  # 10 s per piece run
    assert "3/6 pieces (50 %), 20 s elapsed, about 10 s left" in lines[2]
    assert "5/6 pieces (83 %), 30 s elapsed, about 0 s left" in lines[4]
    assert lines[5].endswith("done; piece 5 (found done)")


def test_on_robot_trains_on_the_hidden_robot_itself():
    from lowcostdex.transfer.loop import HiddenRobotEnv

    robot = hidden_robot(1, "B")
    env = HiddenRobotEnv("lowcostdex/DClawTurnValve-v0", (), 1, "B")()
    try:
        plant = env.unwrapped.backend.chain.plant
        nominal = build_dclaw("valve").compile()
        for name, factor in robot.to_dict()["model"]["link_mass"].items():
            assert plant.model.body_mass[plant.model.body(name).id] == pytest.approx(
                factor * nominal.body_mass[nominal.body(name).id], rel=1e-9)
        assert {e.name for e in plant.effects} == {e.name for e in robot.effects}
    finally:
        env.close()


def test_smoke_transfer_command_runs_end_to_end_resumes_and_keeps_user_files(tmp_path, capsys):
    import json

    from figcheck import figure_problems

    from lowcostdex.cli import main
    from lowcostdex.sim.effects import DomainRandomization
    from lowcostdex.transfer.loop import CONDITIONS, SIZES, run
    from lowcostdex.transfer.valve_fit import valve_ranges

    size = SIZES["smoke"]
    out = tmp_path / "t"
    assert main(["transfer", "--out", str(out), "--size", "smoke"]) == 0
    printed = capsys.readouterr().out
    assert "[progress] transfer: " in printed and "pieces (100 %)" in printed
    data = json.loads((out / "transfer.json").read_text())
    rows = data["rows"]
    robots = [r.name for r in hidden_robots(size.robots)]
    for algo in ("dapg", "npg"):
        for cond in CONDITIONS:
            rs = [r for r in rows if r["algo"] == algo and r["condition"] == cond]
            made_for = [None] if cond in ("nominal", "randomized") else robots
            # every policy on every robot (the cross evaluation)
            assert sorted((r["policy_robot"] or "", r["robot"]) for r in rs) == sorted(
                (m or "", x) for m in made_for for x in robots), (algo, cond)
            for r in rs:
                assert r["seed"] == 0 and r["episodes"] == size.episodes
                assert 0 <= r["success"] <= r["episodes"]
                assert len(r["final_error"]) == size.episodes
                # a looser tolerance never counts fewer successes
                assert r["success"] <= r["success_loose"] <= r["episodes"]
                assert r["samples"] == size.n_iter * size.n_traj * 40
                assert r["train_cpu_seconds"] > 0  # this process's CPU, beside the wall
    # the identified sim carries what the analysis fitted on that robot, per joint
    ident = json.loads((out / "identified.json").read_text())
    for robot in hidden_robots(size.robots):
        causes = ident[robot.name]["fingers"]["ff"]["causes"]
        truth = {e.name for e in robot.effects
                 if not np.allclose(e.values[next(iter(e.values))][:3],
                                    e.cls.params[0].null)}
        assert "latency" in truth and "latency" in {c["effect"] for c in causes}
        config = json.loads((out / "runs" / "dapg" / f"identified_{robot.name}_seed0" /
                             "config.json").read_text())
        dr = DomainRandomization.from_dict(config["env_kwargs"]["randomize"])
        lat = {e.name: e for e in dr.sample(np.random.default_rng(0))}["latency"]
        fitted = next(c for c in causes if c["effect"] == "latency")["params"]["delay"]["value"]
        np.testing.assert_allclose(lat.values["delay"][:3], fitted)
        # ... and the D'Claw edit its valve-log fit made (the robot played the valve episodes)
        fit = json.loads((out / "identify" / robot.name / "valve_fit.json").read_text())
        assert fit["episodes"] == size.valve_episodes and fit["identified"]
        assert fit["designs"] == ["playback", "fast"]  # valve_fit.DESIGNS
        assert fit["used_finger"] in size.valve_fingers
        assert fit["fits"][0]["rms_fit_mrad"] <= fit["fits"][0]["rms_start_mrad"]
        assert config["env_kwargs"]["model_edit"] == fit["model_edit"]
        # (d) holds the valve at the low end of its ranges and draws it up to the high end
        ranges = valve_ranges(fit)
        low = {k: lo for k, (lo, _) in ranges.items()}
        d_config = json.loads((out / "runs" / "dapg" / f"identified_randomized_{robot.name}"
                               "_seed0" / "config.json").read_text())["env_kwargs"]
        valve = DomainRandomization.from_dict(d_config["randomize"])
        assert valve.joints[-1] == "valve"
        fl = valve.ranges["coulomb_friction"]["frictionloss"]
        assert (fl[0][-1], fl[1][-1]) == pytest.approx(
            (0.0, ranges["valve_frictionloss"][1] - low["valve_frictionloss"]))
        for r in rows:  # each row says which MJCF its policy trained in
            if r["policy_robot"] == robot.name:
                assert r["model_edit"] == {"identified": fit["model_edit"],
                                           "identified_randomized": {**fit["model_edit"], **low}
                                           }.get(r["condition"]), r["policy"]
            elif r["policy_robot"] is None:  # nominal, randomized
                assert r["model_edit"] is None
        on_robot = json.loads((out / "runs" / "npg" / f"on_robot_{robot.name}_seed0" /
                               "config.json").read_text())
        assert on_robot["backend"] == "emulated" and on_robot["sampler"] == "serial"
    cells = data["cells"]  # one per algo, condition and robot (own-robot policies)
    assert {(c["algo"], c["condition"], c["robot"]) for c in cells} == {
        (a, c, x) for a in ("dapg", "npg") for c in CONDITIONS for x in robots}
    for c in cells:
        assert c["final_error_interval"][0] <= c["final_error_median"] <= \
            c["final_error_interval"][1]
        assert c["success"] <= c["success_loose"] <= c["episodes"] == size.episodes
    table = (out / "table.md").read_text()
    for cond in CONDITIONS:
        assert f"| {cond} |" in table
    assert "final valve error and success at 0.12 rad" in table
    assert "on every robot (bold: its own robot)" in table
    assert "the valve-log fit per robot" in table
    cost = table.split("what a policy cost")[1].split("###")[0]
    for robot in robots:  # (e)'s robot hours beside (c)'s identification and sim training
        on_robot_line = next(x for x in cost.splitlines()
                             if x.startswith(f"| on_robot | {robot} |"))
        assert float(on_robot_line.split("|")[5]) > 0
        ident_line = next(x for x in cost.splitlines()
                          if x.startswith(f"| identified | {robot} |"))
        assert "(identification)" in ident_line
        # the robot time of (c) counts the valve log beside the identification logs
        assert float(ident_line.split("|")[6]) == pytest.approx(
            size.id_logs * size.id_seconds * len(size.fingers) + 4.0 * size.valve_episodes)
        assert all(f["analysis_cpu_seconds"] > 0 for f in ident[robot]["fingers"].values())
    assert (out / "transfer.png").stat().st_size > 0

    # a second run finds every piece done, reports the same rows, keeps the old table files
    cell = out / "runs" / "dapg" / "nominal_seed0.on_A.json"
    stamp = cell.stat().st_mtime_ns
    again = run(out, size, tell=lambda s: None)
    assert again["rows"] == rows
    assert figure_problems(again["figure"]) == []
    assert cell.stat().st_mtime_ns == stamp
    kept = list((out / "previous").glob("*/transfer.json"))
    assert len(kept) == 1 and json.loads(kept[0].read_text())["rows"] == rows

    # one cell lost: the resume re-runs it alone, and once it ran nothing is left to run
    cell.unlink()
    lines: list[str] = []
    run(out, size, tell=lines.append)
    steps = [s for s in lines if s.startswith("[progress]")]
    fresh = [k for k, s in enumerate(steps) if "(found done)" not in s]
    assert len(fresh) == 1 and "nominal seed 0 on robot A" in steps[fresh[0]]
    assert all("about 0 s left" in s or "done" in s for s in steps[fresh[0]:]), steps
    assert all(" left" not in s for s in steps[:fresh[0]])  # no rate before a piece ran

    # another task cannot build on this folder; a user's folder is refused untouched
    assert main(["transfer", "--out", str(out), "--size", "smoke", "--task", "valve-near"]) == 2
    assert "task='valve'" in capsys.readouterr().err
    user = tmp_path / "mine"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    assert main(["transfer", "--out", str(user), "--size", "smoke"]) == 2
    assert sorted(p.name for p in user.iterdir()) == ["notes.txt"]
    assert (user / "notes.txt").read_text() == "mine"


def test_start_range_widens_only_the_training_starts():
    from lowcostdex.transfer.loop import TASKS

    valve = TASKS["valve"]
    assert valve.training(0.0) is valve
    assert valve.training(0.05).make_kwargs() == {"init_range": 0.05, "goal_range": 0.05}
    near = TASKS["valve-near"]  # already starts and aims within +-0.25 rad: kept
    assert near.training(0.1) is near
    assert near.training(0.5).make_kwargs() == {"init_range": 0.5, "goal_range": 0.5}


def test_training_starts_are_spread_and_the_same_under_a_seed():
    """The valve's start in the training env (the true joint angle after reset) is uniform in
    +-R (here 0.05 rad: 25x the 0.002 rad knife edge), the goal 180 deg +-R further, so the
    start lands on both sides of goal - pi (where the wrapped error flips sign); the same
    start and goal come back under the same reset seed."""
    import gymnasium as gym

    import lowcostdex.sim  # noqa: F401
    from lowcostdex.transfer.loop import TASKS

    task = TASKS["valve"].training(0.05)
    env = gym.make(task.env_id, **task.make_kwargs())

    def start(seed):
        env.reset(seed=seed)
        u = env.unwrapped
        q = float(u.data.qpos[u.task.obj_qpos])
        return q, float(u.goal["angle"]) - q - math.pi  # start, turn beyond 180 deg

    starts, past = np.array([start(s) for s in range(40)]).T
    for x in (starts, past):
        assert np.all(np.abs(x) <= 0.05) and x.min() < -0.03 and x.max() > 0.03
    assert abs(np.corrcoef(starts, past)[0, 1]) < 0.5  # drawn apart
    assert [start(s) for s in (3, 17)] == [(starts[3], past[3]), (starts[17], past[17])]
    env.close()


def test_a_policy_trained_from_random_starts_is_the_same_under_its_seed(tmp_path):
    """Start randomization is drawn from the run's seed: two trainings with one seed give the
    same policy and metrics; another seed does not."""
    import torch

    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.train import load_policy
    from lowcostdex.transfer.loop import SIZES, TASKS, read_json, train_policy

    size, task = SIZES["smoke"], TASKS["valve"].training(0.05)

    def trained(name, seed):
        d = tmp_path / name
        train_policy(d, "npg", task, None, None, size, seed)
        m = ex.read_metrics(d / ex.METRICS_FILE)
        params = [p.detach().clone() for p in load_policy(d).parameters()]
        keep = {k: v for k, v in m.items() if not k.startswith("time_")}  # wall-clock
        return keep, params, read_json(d / "config.json")

    a, b, c = trained("a", 0), trained("b", 0), trained("c", 1)
    assert a[2]["env_kwargs"]["init_range"] == a[2]["env_kwargs"]["goal_range"] == 0.05
    assert a[0].keys() == b[0].keys() and len(a[0]) > 3
    for k in a[0]:
        np.testing.assert_array_equal(a[0][k], b[0][k], err_msg=k)
    assert all(torch.equal(p, q) for p, q in zip(a[1], b[1], strict=True))
    assert not all(torch.equal(p, q) for p, q in zip(a[1], c[1], strict=True))


def test_start_range_is_a_setting_of_the_folder_and_refused_where_starts_already_vary(tmp_path):
    from lowcostdex.errors import ConfigError
    from lowcostdex.transfer.loop import SIZES, run, settings

    size = SIZES["smoke"]
    assert "start_range" not in settings(size, "valve", 0, None)  # old folders still resume
    assert settings(size, "valve", 0, None, 0.05)["start_range"] == 0.05
    with pytest.raises(ConfigError, match="valve-random already starts"):
        run(tmp_path / "t", size, "valve-random", start_range=0.05, tell=lambda s: None)
    assert not (tmp_path / "t").exists()


def test_made_for_limits_the_per_robot_policies_and_every_policy_meets_every_robot(tmp_path):
    """``--made-for B``: identification and the per-robot policies (identified,
    identified_randomized, on_robot) for robot B only; nominal and randomized policies as
    always; every policy still evaluated on robots A, B and C."""
    from lowcostdex.transfer.loop import jobs, make_robots, piece_files, size_with

    robots = make_robots(3)
    size = size_with("smoke", robots=3, algos=("dapg",))
    assert [(c, r and r.name) for c, r in jobs(size.conditions, robots, ("B",))] == [
        ("nominal", None), ("randomized", None), ("identified", "B"),
        ("identified_randomized", "B"), ("on_robot", "B")]
    assert len(jobs(size.conditions, robots)) == 2 + 3 * 3
    names = sorted(str(p.relative_to(tmp_path)) for p in piece_files(tmp_path, size, robots,
                                                                      ("B",)))
    assert [n for n in names if n.startswith("identify")] == ["identify/B/ff/finger.json",
                                                               "identify/B/valve_fit.json"]
    runs = sorted({n.split("/")[2].split(".")[0] for n in names if n.startswith("runs")})
    assert runs == ["identified_B_seed0", "identified_randomized_B_seed0", "nominal_seed0",
                    "on_robot_B_seed0", "randomized_seed0"]
    for stem in runs:  # on every robot; in its training sim unless trained on the robot
        cells = [n for n in names if n.startswith(f"runs/dapg/{stem}.")]
        expected = {f"runs/dapg/{stem}.on_{x}.json" for x in "ABC"}
        if not stem.startswith("on_robot"):
            expected.add(f"runs/dapg/{stem}.sim.json")
        assert set(cells) == expected, stem
    # with --start-range each simulated policy has one more cell: its training starts
    wide = piece_files(tmp_path, size, robots, ("B",), starts=True)
    extra = sorted(str(p.relative_to(tmp_path)) for p in set(wide) - set(
        piece_files(tmp_path, size, robots, ("B",))))
    assert extra == [f"runs/dapg/{s}.sim_starts.json" for s in runs if "on_robot" not in s]


def test_an_unknown_made_for_robot_is_refused_before_anything_is_written(tmp_path, capsys):
    from lowcostdex.cli import main

    out = tmp_path / "t"
    assert main(["transfer", "--out", str(out), "--size", "smoke", "--made-for", "B,D"]) == 2
    err = capsys.readouterr().err
    assert "unknown robot 'D'" in err and "'A', 'B'" in err
    assert main(["transfer", "--out", str(out), "--size", "smoke", "--made-for", ","]) == 2
    assert "at least one robot" in capsys.readouterr().err
    assert not out.exists()


def test_the_table_shows_the_training_starts_column_only_when_evaluated():
    from lowcostdex.transfer.loop import summarize, table_markdown

    rows = [_row("nominal", "A", 3), _row("nominal", "B", 5)]
    plain = table_markdown(summarize(rows, ["A", "B"]), ["A", "B"])
    assert "training starts" not in plain and "| in training sim (on_robot" in plain
    for r in rows:  # the one nominal policy: 7 of 20 episodes from its training starts
        r.update(sim_starts_success=7, sim_starts_episodes=20)
    rows += [_row("identified", x, 1, made_for=x) for x in "AB"]
    for r, k in zip(rows[2:], (4, 11), strict=True):  # two policies: 4/20 and 11/20
        r.update(sim_starts_success=k, sim_starts_episodes=20)
    s = summarize(rows, ["A", "B"])
    assert s["nominal"]["sim_starts"] == (7, 20) and s["identified"]["sim_starts"] == (15, 40)
    lines = table_markdown(s, ["A", "B"]).splitlines()
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    col = head.index("in training sim from its training starts")
    assert head[col - 1].startswith("in training sim from the task's start")
    nominal = [c.strip() for c in lines[2].strip("|").split("|")]
    identified = [c.strip() for c in lines[3].strip("|").split("|")]
    assert nominal[col].startswith("0.35 [") and identified[col].startswith("0.38 [")
    pairs = head.index("policy-robot pairs that work (>= half the episodes)")
    assert nominal[pairs] == "1 of 2" and identified[pairs] == "0 of 2"  # 3, 5; 1, 1 of 10
    assert len(nominal) == len(head)


def test_start_range_runs_evaluate_each_sim_policy_from_its_training_starts(tmp_path):
    """A start-range run on 2 robots, policies for robot B only: the nominal policy's extra
    cell starts its episodes at different valve angles (different final errors; from the
    task's fixed start every episode is the same), the on_robot policy has none (its training
    environment is the robot), and no policy is made for robot A."""
    import json

    from figcheck import figure_problems

    from lowcostdex.transfer.loop import run, size_with

    size = size_with("smoke", algos=("npg",), conditions=("nominal", "on_robot"))
    out = tmp_path / "t"
    result = run(out, size, start_range=0.3, made_for=("B",), tell=lambda s: None)
    runs = out / "runs" / "npg"
    assert (runs / "on_robot_B_seed0").is_dir() and not (runs / "on_robot_A_seed0").exists()
    fixed = json.loads((runs / "nominal_seed0.sim.json").read_text())
    starts = json.loads((runs / "nominal_seed0.sim_starts.json").read_text())
    assert starts["episodes"] == size.episodes == 2
    assert len(set(fixed["final_error"])) == 1 and len(set(starts["final_error"])) == 2
    assert not (runs / "on_robot_B_seed0.sim_starts.json").exists()
    rows = result["rows"]
    assert sorted((r["condition"], r["policy_robot"] or "", r["robot"]) for r in rows) == [
        ("nominal", "", "A"), ("nominal", "", "B"), ("on_robot", "B", "A"),
        ("on_robot", "B", "B")]
    for r in rows:
        if r["condition"] == "nominal":
            assert r["sim_starts_success"] == starts["successes"]
        else:
            assert r["sim_starts_success"] is None
    table = (out / "table.md").read_text()
    assert "in training sim from its training starts" in table
    # on_robot has a policy for robot B only: its mean and drop say so, the plot has no mean bar
    line = next(x for x in table.splitlines() if x.startswith("| on_robot |"))
    assert line.count("(B only)") == 2
    assert "only)" not in next(x for x in table.splitlines() if x.startswith("| nominal |"))
    assert figure_problems(result["figure"]) == []


def test_first_seed_trains_only_the_later_seeds_and_keeps_whole_lower_ones(tmp_path, capsys,
                                                                           monkeypatch):
    """``--seeds 3 --first-seed 2``: seed 2 alone is trained; seed 0, held whole by the folder,
    joins the table without running again, seed 1 (absent) does not; a seed held in part stays
    out; a first seed past the last is refused before anything is written; the
    demonstrations are seed 0's whatever the first seed (every DAPG policy learns from them)."""
    import json
    from dataclasses import replace

    from lowcostdex.cli import main
    from lowcostdex.errors import ConfigError
    from lowcostdex.transfer import loop

    size = loop.size_with("smoke", robots=1, algos=("npg",), conditions=("nominal",))
    out = tmp_path / "t"
    loop.run(out, size, tell=lambda s: None)  # seed 0
    runs = out / "runs" / "npg"
    seed0 = sorted(p.name for p in runs.iterdir())
    stamps = {p.name: p.stat().st_mtime_ns for p in runs.iterdir()}
    result = loop.run(out, replace(size, seeds=3), first_seed=2, tell=lambda s: None)
    assert sorted(p.name for p in runs.iterdir()) == sorted(
        seed0 + [n.replace("seed0", "seed2") for n in seed0])
    assert all(p.stat().st_mtime_ns == stamps[p.name] for p in runs.iterdir()
               if "seed0" in p.name)  # not run again
    assert sorted({r["seed"] for r in result["rows"]}) == [0, 2]
    assert json.loads((out / "transfer.json").read_text())["info"]["seeds"] == [0, 2]
    (runs / "nominal_seed0.sim.json").unlink()  # seed 0 now held in part: out of the table
    result = loop.run(out, replace(size, seeds=3), first_seed=2, tell=lambda s: None)
    assert {r["seed"] for r in result["rows"]} == {2}
    assert not (runs / "nominal_seed0.sim.json").exists()
    before = sorted(out.rglob("*"))
    with pytest.raises(ConfigError, match=r"first_seed must be in \[0, 2\].*--seeds 4"):
        loop.run(out, replace(size, seeds=3), first_seed=3, tell=lambda s: None)
    assert sorted(out.rglob("*")) == before
    assert main(["transfer", "--out", str(tmp_path / "u"), "--size", "smoke",
                 "--first-seed", "2"]) == 2
    assert "--seeds 3" in capsys.readouterr().err and not (tmp_path / "u").exists()

    class Recorded(Exception):
        pass

    def record(out, task, size, seed):
        raise Recorded(seed)

    monkeypatch.setattr(loop, "record_demos", record)
    with pytest.raises(Recorded) as got:  # a new DAPG folder, seed 2 alone
        loop.run(tmp_path / "d", replace(size, algos=("dapg",), seeds=3), first_seed=2,
                 tell=lambda s: None)
    assert got.value.args == (0,)


def test_each_condition_is_paired_with_nominal_on_the_same_episodes():
    """Six episodes on robot A per seed. Nominal ends 0.20, 0.15, 0.12, 0.11, 0.09, 0.05 rad
    (2 solved), identified 0.08 ... 0.03 (6 solved): 4 episodes only identified solved, none
    only nominal, exact McNemar p = (1/2)^4 = 0.0625; every one of the 6 differences is
    negative, exact Wilcoxon p = (1/2)^6 = 0.016; nearer in 2 of 2 seeds, sign test p =
    (1/2)^2. Randomized (seed 0, a cell recorded without per-episode successes) ends farther
    every episode: no McNemar, Wilcoxon p = 1, nearer in 0 of 1 seed (p = 1). A policy made
    for B on robot A is not paired (own robot only)."""
    from lowcostdex.transfer.loop import paired_markdown

    nominal = [0.20, 0.15, 0.12, 0.11, 0.09, 0.05]
    ident = [0.08, 0.07, 0.06, 0.05, 0.04, 0.03]
    far = [0.30, 0.31, 0.32, 0.33, 0.34, 0.35]

    def row(cond, errors, seed, made_for=None, solved=True):
        return dict(_row(cond, "A", sum(e < 0.1 for e in errors), n=6, made_for=made_for,
                         seed=seed), final_error=errors,
                    solved=[e < 0.1 for e in errors] if solved else None)

    rows = [row("nominal", nominal, 0), row("nominal", nominal, 1),
            row("identified", ident, 0, "A"), row("identified", ident, 1, "A"),
            row("randomized", far, 0, solved=False), row("identified_randomized", far, 0, "B")]
    lines = paired_markdown(rows, ["A", "B"]).splitlines()
    cells = [[c.strip() for c in x.strip("|").split("|")] for x in lines if x.startswith("| A")]
    assert cells == [
        ["A", "0", "randomized", "2 -> 0 of 6", "-", "-", "0.115 -> 0.325", "1"],
        ["A", "0", "identified", "2 -> 6 of 6", "4 / 0", "0.062", "0.115 -> 0.055", "0.016"],
        ["A", "1", "identified", "2 -> 6 of 6", "4 / 0", "0.062", "0.115 -> 0.055", "0.016"]]
    assert [x for x in lines if x.startswith("- ")] == [
        "- robot A, randomized: nearer the goal than nominal (median final error) in 0 of 1 "
        "seed(s), sign test p = 1",
        "- robot A, identified: nearer the goal than nominal (median final error) in 2 of 2 "
        "seed(s), sign test p = 0.25"]
    assert paired_markdown([r for r in rows if r["condition"] != "nominal"], ["A"]) == ""


def test_the_valve_log_fit_is_a_setting_only_when_on():
    """A folder made before the valve-log fit existed (no such keys in its budget) resumes
    with it off; with it on its settings are part of the budget (a resume must keep them)."""
    from lowcostdex.errors import ConfigError
    from lowcostdex.transfer.loop import size_with

    off = size_with("default", valve_episodes=0).budget()
    assert not {"valve_episodes", "valve_fingers", "valve_fit"} & set(off)
    on = size_with("default").budget()
    assert on["valve_episodes"] == 5 and on["valve_fingers"] == ["ff", "mf", "th"]
    for bad in (1, -1):
        with pytest.raises(ConfigError, match="valve_episodes"):
            size_with("smoke", valve_episodes=bad)
