"""Training logs without a torque-off swing (``gap.torque_off.no_swing_warning``):
the user is told plainly, in the identification's notes and by ``gap identify`` before fitting,
that the back-driven friction and the armature cannot be told from torque-on logs. Real case:
STS3032, 5 drawn kp 32 logs without a torque-off one (seed 2) fitted the inertia scale to its 0.1
floor (bench/RESULTS.md gap-real22, gap-real23)."""

from __future__ import annotations

import numpy as np

from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.identify import IdentifyConfig, identify
from lowcostdex.gap.logs import Trajectory
from lowcostdex.gap.torque_off import no_swing_warning
from lowcostdex.sim import servo
from lowcostdex.sim.models.bench import BENCH_JOINT, BenchConfig, build_bench

DT = 0.005
J = (BENCH_JOINT,)


def test_the_warning_names_what_torque_on_logs_cannot_tell():
    assert no_swing_warning(True) is None
    text = no_swing_warning(False)
    assert text.startswith("WARNING: no training log has the torque off")
    assert "armature" in text and "back-driven friction" in text


def _ds(on_off: bool) -> Dataset:
    # a bench arm following a slow sine with the nominal servo (no effects: the fit has nothing
    # to find), the torque on throughout, or off for the last second
    cfg = BenchConfig(motor="XL330-M288", mass=0.3, length=0.1, timestep=DT,
                      gains=servo.ServoGains(position_p=400, supply_voltage=7.4))
    xml = build_bench(cfg).to_xml()
    t = np.arange(0.0, 1.0, DT)
    q = (0.3 * np.sin(3.0 * t))[:, None]
    trs = []
    for k in range(2):
        tr = Trajectory(f"log{k}", t, q.copy(), q.copy(), J, J, model="bench",
                        meta={"kp": 400, "trajectory": "sin"})
        tr.channels["torque_enable"] = ((t < 0.7) if on_off and k == 0 else np.ones_like(t)
                                        ).astype(float)[:, None]
        trs.append(tr)
    return Dataset({"bench": xml}, trs)


def test_identify_warns_first_when_no_training_log_has_the_torque_off():
    cfg = IdentifyConfig(effects=("viscous_damping",), max_rounds=2, restarts=1, select="train")
    res = identify(_ds(False), [0], [1], cfg)
    assert res.notes[0] == no_swing_warning(False)
    res = identify(_ds(True), [0], [1], cfg)
    assert not any(n.startswith("WARNING") for n in res.notes)


def test_gap_identify_command_warns_before_fitting(tmp_path, capsys, monkeypatch):
    # one BAM-format truth log (tests/gap_bam_truth.py) with the torque on throughout; the fit
    # itself is stopped at its start: the warning must come before it
    import gap_bam_truth as truth

    from lowcostdex.cli import main
    from lowcostdex.gap import identify as idm

    truth.write_set("sts3215", tmp_path, kps=(32,), trajectories=("sin_sin",),
                    benches=truth.STS3215_BENCHES[:1])

    class Stop(Exception):
        pass

    def stop(*a, **k):
        raise Stop

    monkeypatch.setattr(idm, "identify", stop)
    try:
        main(["gap", "identify", "--log", str(next(tmp_path.glob("*.json")))])
    except Stop:
        pass
    out = capsys.readouterr().out
    assert "lowcostdex gap identify: " + no_swing_warning(False) in out
