"""``lowcostdex gap``: generate and analyze end to end (exit codes, report.json fields, report and
plots, a loadable extended model), and bad input refused with a clear message and nothing
written."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest

from lowcostdex.cli import main
from lowcostdex.gap import load_extended

REPORT_FIELDS = {
    "verdict": str, "baseline": dict, "causes": list, "extended": dict, "gain": dict,
    "noise_floor": dict, "candidates": list, "diagnostics": dict, "split": dict,
}


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    root = tmp_path_factory.mktemp("gap")
    assert main(["gap", "generate", "--rig", "bench", "--effect", "latency", "--seed", "5",
                 "--logs", "3", "--duration", "6", "--out", str(root / "data")]) == 0
    return root


def test_analyze_writes_the_report_and_the_extended_model(demo, capsys):
    data, out = demo / "data", demo / "report"
    logs = sorted(str(p) for p in data.glob("log*.csv"))
    assert main(["gap", "analyze", "--model", str(data / "model.xml"), "--log", *logs,
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "verdict: latency" in printed and "held-out RMSE" in printed
    rep = json.loads((out / "report.json").read_text())
    for key, typ in REPORT_FIELDS.items():
        assert isinstance(rep[key], typ), key
    assert rep["baseline"]["heldout_rmse"] > rep["extended"]["heldout_rmse"] > 0
    cause = rep["causes"][0]
    assert cause["effect"] == "latency" and cause["joints"] == ["arm"]
    delay = cause["params"]["delay"]
    truth = json.loads((data / "truth.json").read_text())["hidden"][0]["params"]["delay"][0]
    assert delay["value"][0] == pytest.approx(truth, rel=0.1)
    lo, hi = delay["interval"][0]
    assert lo <= delay["value"][0] <= hi and delay["unit"] == "s"
    assert cause["heldout_rmse_after"] == pytest.approx(rep["extended"]["heldout_rmse"])
    g = rep["gain"]
    # one test episode here: a bootstrap over it gave a zero-width 'interval' [x, x] that this
    # test used to accept; now there is none, and the summary says why
    assert g["episodes"] == 1 and g["ci95"] is None and g["absolute"] > 0
    assert "no interval: 1 test episode" in printed
    assert 0 < g["noise_floor"] < rep["extended"]["heldout_rmse"] * 2
    for f in ("report.md", "traces.png", "residuals.png", "candidates.png"):
        assert (out / f).stat().st_size > 1000, f
    assert "# Reality-gap report" in (out / "report.md").read_text()
    ext = load_extended(out)
    assert [e.name for e in ext.effects] == ["latency"]
    model = mujoco.MjModel.from_xml_string(next(iter(ext.extended.values())))
    assert model.actuator_delay[0] == pytest.approx(delay["value"][0], rel=1e-4)
    # no temporary folders left next to the report
    assert sorted(p.name for p in demo.iterdir()) == ["data", "report"]


@pytest.mark.parametrize("edit, message", [
    (lambda c: c.replace("qpos:arm", "qpos:elbow").replace("qvel:arm", "qvel:elbow"),
     "no joint 'elbow'"),
    (lambda c: c.replace(c.splitlines()[0], c.splitlines()[0].replace(
        "qpos:arm", "Q").replace("qvel:arm", "V").replace(":arm", ":wrist").replace(
        "Q", "qpos:arm").replace("V", "qvel:arm")), "no actuator 'wrist'"),
    (lambda c: "\n".join(c.splitlines()[:12]) + "\n", "too little data"),
    (lambda c: c.replace(c.splitlines()[5].split(",")[2], "nan", 1), "NaN"),
])
def test_bad_logs_exit_non_zero_with_a_clear_message_and_write_nothing(demo, tmp_path, capsys,
                                                                       edit, message):
    text = (demo / "data" / "log00.csv").read_text()
    bad = tmp_path / "bad.csv"
    bad.write_text(edit(text))
    out = tmp_path / "out"
    code = main(["gap", "analyze", "--model", str(demo / "data" / "model.xml"), "--log",
                 str(bad), "--out", str(out)])
    assert code == 2
    err = capsys.readouterr().err
    assert "lowcostdex gap analyze: error:" in err and message in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv"]


def test_missing_model_and_files_are_named(tmp_path, capsys):
    p = tmp_path / "x.csv"
    np.savetxt(p, np.zeros((30, 3)), delimiter=",", header="time,goal:arm,qpos:arm",
               comments="")
    assert main(["gap", "analyze", "--log", str(p), "--out", str(tmp_path / "o")]) == 2
    assert "need --model" in capsys.readouterr().err
    assert main(["gap", "analyze", "--model", str(tmp_path / "none.xml"), "--log", str(p),
                 "--out", str(tmp_path / "o")]) == 2
    assert "no such model file" in capsys.readouterr().err


def _files(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def test_analyze_never_deletes_the_users_folder(demo, tmp_path, capsys):
    """Issue 12: `--out` pointed at the folder of its own input logs, or at a user's folder with
    files, is refused before any work; every file stays byte for byte."""
    data = demo / "data"
    logs = sorted(str(p) for p in data.glob("log*.csv"))
    before = _files(data)
    assert main(["gap", "analyze", "--model", str(data / "model.xml"), "--log", *logs,
                 "--out", str(data)]) != 0
    assert "gap generate" in capsys.readouterr().err
    assert _files(data) == before
    user = tmp_path / "thesis"
    user.mkdir()
    (user / "chapter1.tex").write_text("\\chapter{Intro}")
    assert main(["gap", "analyze", "--model", str(data / "model.xml"), "--log", *logs,
                 "--out", str(user)]) != 0
    err = capsys.readouterr().err
    assert "chapter1.tex" in err and "Traceback" not in err
    assert (user / "chapter1.tex").read_text() == "\\chapter{Intro}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["thesis"]
    # generate follows the same rule
    assert main(["gap", "generate", "--rig", "bench", "--logs", "1", "--duration", "1",
                 "--out", str(user)]) != 0
    assert sorted(p.name for p in user.iterdir()) == ["chapter1.tex"]


def test_report_figures_read_at_a_glance(demo):
    """Issue 13: axis labels with units, titles, legends beside the data, on the report's
    figures (read from the figure objects)."""
    import matplotlib.pyplot as plt
    from figcheck import figure_problems

    from lowcostdex.gap import GapConfig, analyze, load_dataset
    from lowcostdex.gap.report import candidates_figure, residuals_figure, traces_figure

    data = demo / "data"
    logs = sorted(str(p) for p in data.glob("log*.csv"))
    result = analyze(load_dataset(logs, model=str(data / "model.xml")), GapConfig(seed=0))
    for make in (traces_figure, residuals_figure, candidates_figure):
        fig = make(result)
        assert figure_problems(fig) == [], make.__name__
        plt.close(fig)


def test_logs_may_be_named_by_folder_or_pattern_and_analyze_says_what_it_takes(tmp_path):
    """A user's ways to name logs: the folder ``record-log`` wrote (its marker file is not a
    log), a glob pattern the shell did not expand, a list of files: the same two logs in
    order. A pattern that matches nothing and a folder without logs are refused by name.
    ``analyze`` given the file names instead of a data set says what to call first."""
    from lowcostdex.cli import main
    from lowcostdex.gap import LogError, analyze, load_dataset

    xml, logs = tmp_path / "finger.xml", tmp_path / "logs"
    assert main(["model", "dclaw", "--station", "none", "--fingers", "ff", "--no-thermal",
                 "--out", str(xml)]) == 0
    assert main(["record-log", "--port", "emulated", "--logs", "2", "--seconds", "0.8",
                 "--out", str(logs)]) == 0
    files = [logs / "log_0.csv", logs / "log_1.csv"]
    assert sorted(p.name for p in logs.iterdir() if p.name.startswith(".")) == [
        ".lowcostdex.json"]
    reference = load_dataset([str(p) for p in files], model=str(xml))
    for named in (str(logs), logs, [logs], str(logs / "log_*.csv"), [str(logs / "*.csv")]):
        ds = load_dataset(named, model=str(xml))
        assert [t.name for t in ds.trajectories] == [t.name for t in reference.trajectories]
        for a, b in zip(ds.trajectories, reference.trajectories, strict=True):
            np.testing.assert_array_equal(a.qpos, b.qpos)
    with pytest.raises(LogError, match=r"no file matches this pattern"):
        load_dataset(str(tmp_path / "*.npz"), model=str(xml))
    (tmp_path / "empty").mkdir()
    with pytest.raises(LogError, match=r"empty: a folder without logs"):
        load_dataset(tmp_path / "empty", model=str(xml))
    with pytest.raises(TypeError, match=r"analyze takes a Dataset, not list.*load_dataset"):
        analyze([str(p) for p in files])
    with pytest.raises(TypeError, match=r"config must be a GapConfig, not dict"):
        analyze(reference, {"top_k": 2})
