"""``lowcostdex gap identify --out DIR``: one vocabulary with ``gap analyze`` (the lead's careless
call: 'unrecognized arguments: --out'). The folder gets identified.json (what --json writes) and a
labelled per-log MAE figure; a user's folder with files is refused before the fit; a second run
keeps the first in previous/. Two 2 s BAM logs written here (tests/test_gap_real_odd.py's)."""

from __future__ import annotations

import json
import pathlib
import sys

import pytest

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from test_gap_real_odd import _log  # noqa: E402

from lowcostdex.cli import main  # noqa: E402


def _logs(tmp_path):
    a = _log(tmp_path / "a.json")
    b = _log(tmp_path / "b.json", kp=16, trajectory="lift_and_drop")
    return str(a), str(b)


def test_identify_writes_its_json_and_figure_into_out(tmp_path, capsys):
    a, b = _logs(tmp_path)
    out = tmp_path / "ident"
    argv = ["gap", "identify", "--log", a, b, "--holdout", b, "--restarts", "1", "--threads",
            "1", "--out", str(out)]
    assert main(argv + ["--json", str(tmp_path / "also.json")]) == 0
    printed, err = capsys.readouterr()
    # not a terminal here: progress as plain lines on stderr (the fit of 72 logs is minutes of
    # silence otherwise); the first line at the start, the last at the end
    lines = [x for x in err.splitlines() if x.startswith("[progress] gap identify")]
    assert lines and "done" in lines[-1], err
    res = json.loads((out / "identified.json").read_text())
    assert res == json.loads((tmp_path / "also.json").read_text())
    assert list(res["held_out"]) == ["b.json"] and list(res["fitted"]) == ["a.json"]
    assert f"held out b.json: identified {1e3 * res['held_out']['b.json']:.1f}" in printed
    assert (out / "mae.png").stat().st_size > 5000
    first = (out / "identified.json").read_bytes()
    assert main(argv) == 0  # again into its own output: the first kept under previous/
    kept = list((out / "previous").rglob("identified.json"))
    assert len(kept) == 1 and kept[0].read_bytes() == first


def test_identify_refuses_a_users_folder_before_fitting(tmp_path, capsys, monkeypatch):
    import lowcostdex.gap.identify as ident

    monkeypatch.setattr(ident, "identify", lambda *a, **k: pytest.fail("fitted"))
    a, b = _logs(tmp_path)
    mine = tmp_path / "thesis"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    assert main(["gap", "identify", "--log", a, b, "--out", str(mine)]) == 2
    err = capsys.readouterr().err
    assert "notes.txt" in err and "left untouched" in err and "Traceback" not in err
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]


def test_the_mae_figure_reads_at_a_glance():
    import matplotlib.pyplot as plt
    from figcheck import figure_problems

    from lowcostdex.gap.cli import mae_figure

    fig = mae_figure(["a.json", "b.json", "c.json"], [0.002, 0.004, 0.003],
                     [0.008, 0.015, 0.01], [1], "full")
    assert figure_problems(fig) == []
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_xticklabels()]
    assert labels == ["held out: b.json", "a.json", "c.json"]  # held out first
    heights = [p.get_height() for p in ax.patches]
    assert heights == pytest.approx([15, 8, 10, 4, 2, 3])  # mrad: nominal, then identified
    plt.close(fig)
