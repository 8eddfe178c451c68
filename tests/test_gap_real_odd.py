"""Odd BAM logs a user brings (issue 11 item 2): a header without the supply voltage, a motor
written with its vendor's name, a missing gain. Each gives a sensible default said in the notes or
a message naming the field and what it means. The logs are written here, numbers typed in."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from lowcostdex.gap.bam_logs import bam_motor, read_bam
from lowcostdex.gap.trajectory import LogError


def _log(path, drop=(), volts=74, **header):
    t = np.arange(400) * 0.005 + 0.002
    entries = [{"timestamp": float(ti), "position": float(0.3 * math.sin(2 * ti)),
                "speed": float(0.6 * math.cos(2 * ti)), "load": 0, "input_volts": volts,
                "temp": 30, "goal_position": float(0.3 * math.sin(2 * ti)),
                "torque_enable": True} for ti in t]
    raw = {"mass": 0.2, "length": 0.1, "kp": 32, "vin": 7.4, "motor": "sts3032",
           "trajectory": "sin_sin", "entries": entries, **header}
    for k in drop:
        del raw[k]
    path.write_text(json.dumps(raw))
    return path


def test_missing_vin_is_the_median_measured_supply_and_said(tmp_path):
    # Feetech's Present Voltage register counts 0.1 V (STS3032 memory table): 74 -> 7.4 V
    tr, cfg = read_bam(_log(tmp_path / "a.json", drop=("vin",), volts=74))
    assert cfg.servo_gains().supply_voltage == pytest.approx(7.4)
    assert any("lacks 'vin'" in n and "7.40 V" in n for n in tr.meta["notes"])
    # volts already in V (Dynamixel logs as BAM writes them)
    tr, cfg = read_bam(_log(tmp_path / "b.json", drop=("vin",), volts=5.0, motor="xl330",
                            kp=100))
    assert cfg.servo_gains().supply_voltage == pytest.approx(5.0)


def test_missing_vin_without_measured_volts_names_the_field(tmp_path):
    p = _log(tmp_path / "a.json", drop=("vin",))
    raw = json.loads(p.read_text())
    for e in raw["entries"]:
        del e["input_volts"]
    p.write_text(json.dumps(raw))
    with pytest.raises(LogError, match=r"lacks 'vin' \(the nominal supply voltage, V\).*"
                                       r"add \"vin\""):
        read_bam(p)


def test_a_header_with_vin_is_not_second_guessed(tmp_path):
    tr, cfg = read_bam(_log(tmp_path / "a.json", volts=62))  # header 7.4 V, measured 6.2 V
    assert cfg.servo_gains().supply_voltage == pytest.approx(7.4)
    assert not any("vin" in n for n in tr.meta.get("notes", []))


@pytest.mark.parametrize("field, meaning", [
    ("kp", "firmware position P gain"), ("mass", "load at the arm tip, kg"),
    ("length", "distance from pivot to load, m")])
def test_missing_header_field_says_what_it_is(tmp_path, field, meaning):
    with pytest.raises(LogError, match=rf"lacks fields: '{field}' \(the {meaning}"):
        read_bam(_log(tmp_path / "a.json", drop=(field,)))


@pytest.mark.parametrize("name, bam", [
    ("Dynamixel XL330-M288-T", "xl330"), ("ROBOTIS Dynamixel XL330-M288", "xl330"),
    ("Feetech STS3032", "sts3032"), ("feetech_sts3250", "sts3250"), ("MX-64(1.0)", "mx64"),
    ("Dynamixel XL330-M077", None), ("Feetech", None), ("dynamixel", None)])
def test_vendor_prefixed_motor_names(name, bam):
    assert bam_motor(name) == bam


def test_vendor_prefixed_motor_reads_as_the_motor(tmp_path):
    _, cfg = read_bam(_log(tmp_path / "a.json", motor="Feetech STS3032"))
    assert cfg.motor == "STS3032"


def test_gap_identify_prints_what_loading_did_before_fitting(tmp_path, monkeypatch, capsys):
    """The user's path: `gap identify` says the supply default and the cut at a 0.5 s hole in the
    log before the fit starts (they were dropped on BAM's 5 ms grid and never printed)."""
    import lowcostdex.gap.identify as ident
    from lowcostdex.cli import main

    p = _log(tmp_path / "a.json", drop=("vin",))
    raw = json.loads(p.read_text())
    raw["entries"] = raw["entries"][:150] + raw["entries"][250:]  # 0.5 s without samples
    p.write_text(json.dumps(raw))

    class Stop(Exception):
        pass

    def stop(*a, **k):
        raise Stop

    monkeypatch.setattr(ident, "identify", stop)
    with pytest.raises(Stop):
        main(["gap", "identify", "--log", str(p)])
    out = capsys.readouterr().out
    assert "lacks 'vin'" in out and "7.40 V" in out
    # the log is cut at its hole (rows 0.002 + 5 ms steps; row 149 at 0.747 s, next 1.252 s)
    assert "0.505 s after 0.747 s (row 149)" in out and "split into" in out


def test_a_piece_after_a_time_hole_starts_its_grid_at_its_own_first_sample(tmp_path):
    """A log cut at a time hole keeps its clock; BAM's grid from t = 0 extrapolated the second
    piece's first two samples back over 1.25 s (a Rhoban chirp holed at 2.7 s started at 7.7 rad
    and -136 rad/s). The piece's grid now starts at its first sample, which it reproduces; a
    whole log still starts at 0 as BAM's does (first sample 2 ms in)."""
    from lowcostdex.gap import bam_measure as bm
    from lowcostdex.gap.dataset import load_dataset

    p = _log(tmp_path / "a.json")
    raw = json.loads(p.read_text())
    raw["entries"] = raw["entries"][:150] + raw["entries"][250:]  # 0.5 s without samples
    p.write_text(json.dumps(raw))
    ds = bm.grid_dataset(load_dataset([p], timestep=bm.BAM_DT))
    first, second = ds.trajectories
    assert first.time[0] == 0.0  # the whole log's start: BAM's grid
    # row 250 of the written log: t = 1.252 s, position 0.3 sin(2.504), speed 0.6 cos(2.504)
    assert second.time[0] == pytest.approx(1.252)
    assert second.qpos[0, 0] == pytest.approx(0.3 * math.sin(2.504), abs=1e-9)
    assert second.qvel[0, 0] == pytest.approx(0.6 * math.cos(2.504), abs=1e-9)
    assert np.all(np.abs(second.qpos) <= 0.3 + 1e-9)  # nothing extrapolated beyond the arm's swing


def test_a_log_on_wall_clock_time_is_gridded_from_its_first_sample(tmp_path):
    p = _log(tmp_path / "a.json")
    raw = json.loads(p.read_text())
    for e in raw["entries"]:
        e["timestamp"] += 1.7e9  # Unix time stamps
    p.write_text(json.dumps(raw))
    from lowcostdex.gap import bam_measure as bm
    from lowcostdex.gap.dataset import load_dataset

    tr = bm.grid_dataset(load_dataset([p], timestep=bm.BAM_DT)).trajectories[0]
    assert len(tr.time) <= 400 and tr.time[0] == pytest.approx(1.7e9 + 0.002)


# BAM's acquisition as it is today (Rhoban/bam @1b5a1ce, 2026-07-24): bam/dynamixel/record.py
# writes the header key "arm-mass" (hyphen) and bam/logs.py reads it as arm_mass; bam/actuators.py
# knows the motors mx64, mx106, xl320, xl330, xl330i, erob80_100, erob80_50, sts3215, unitree_go1.

def test_the_dynamixel_recorder_s_hyphenated_arm_mass_is_the_arm_s_mass(tmp_path):
    """Read as 0 kg before: the arm's own weight (here 0.05 kg at half of 0.1 m: 0.0245 N m of
    gravity torque) silently left out of the model of every log BAM's Dynamixel recorder wrote."""
    _, cfg = read_bam(_log(tmp_path / "a.json", motor="xl330", kp=200, vin=5.0, volts=5.0,
                           **{"arm-mass": 0.05}))
    assert cfg.arm_mass == pytest.approx(0.05)
    _, same = read_bam(_log(tmp_path / "b.json", motor="xl330", kp=200, vin=5.0, volts=5.0,
                            arm_mass=0.05))
    assert same == cfg
    # as BAM's loader: arm_mass wins when a file has both
    _, both = read_bam(_log(tmp_path / "c.json", motor="xl330", kp=200, vin=5.0, volts=5.0,
                            arm_mass=0.02, **{"arm-mass": 0.05}))
    assert both.arm_mass == pytest.approx(0.02)


def test_an_sts3215_log_reads_as_lerobot_s_servo(tmp_path):
    """The SO-100/SO-101 arms' servo, BAM's "sts3215" (bam/feetech/all_record.py records kp 4, 8,
    16, 32 at 7.4 V); its P coefficient is one byte (Feetech STS memory table, address 21)."""
    _, cfg = read_bam(_log(tmp_path / "a.json", motor="sts3215", kp=8))
    assert cfg.motor == "STS3215" and cfg.servo_gains().position_p == 8
    assert bam_motor("Feetech STS3215") == "sts3215"
    with pytest.raises(LogError, match=r"'kp' 300 is beyond the STS3215's P gain register; "
                                       r"valid: 1 to 254"):
        read_bam(_log(tmp_path / "b.json", motor="sts3215", kp=300))


@pytest.mark.parametrize("motor, said", [
    ("xl330i", "current-based position control"), ("xl320", "1024 ticks over 300 deg"),
    ("erob80_100", "BAM's own PD controller"), ("unitree_go1", "Unitree Go1")])
def test_bam_motors_not_modelled_here_are_refused_by_name(tmp_path, motor, said):
    with pytest.raises(LogError, match=rf"BAM motor '{motor}' is .*{said}.*can be analysed "
                                       r"here: .*sts3215 \(STS3215\)"):
        read_bam(_log(tmp_path / "a.json", motor=motor))


@pytest.mark.parametrize("command", [["gap", "identify"], ["gap", "analyze", "--out", "rep"]])
def test_logs_of_two_servo_models_are_not_fitted_as_one_servo(tmp_path, monkeypatch, capsys,
                                                            command):
    """An XL330 log and an STS3032 log in one call were fitted as one servo (one gear friction,
    one armature for both; BAM fits one actuator at a time). Refused, naming each motor."""
    from lowcostdex.cli import main

    monkeypatch.chdir(tmp_path)
    _log(tmp_path / "sts.json")
    _log(tmp_path / "xl.json", motor="xl330", kp=200, vin=5.0, volts=5.0)
    code = main([*command, "--log", "sts.json", "xl.json"])
    err = capsys.readouterr().err
    assert code == 2
    assert ("these logs are of 2 servo models: STS3032 (sts.json), XL330-M288 (xl.json)"
            in err), err
    assert not (tmp_path / "rep").exists()


def test_one_servo_model_under_two_spellings_is_one_motor(tmp_path):
    from lowcostdex.gap.bam_logs import check_one_motor

    a, _ = read_bam(_log(tmp_path / "a.json", motor="sts3032", kp=32))
    b, _ = read_bam(_log(tmp_path / "b.json", motor="Feetech STS3032", kp=8, mass=0.1))
    check_one_motor([a, b])  # gains and masses differ, the servo is the same: no error
