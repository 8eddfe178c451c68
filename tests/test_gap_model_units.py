"""A user's MJCF whose joint ranges are in degrees (MJCF's default unit) while the log is in rad.

MuJoCo's XML reference: `compiler/angle` "[radian, degree], 'degree'" - a hinge's `range` is read
in degrees unless the model says `<compiler angle="radian"/>`, so `range="-1.6 1.6"` written as
radians becomes +-0.0279 rad (1.6 * pi / 180). The log must be refused with that named, and the
same model with the compiler line must be accepted.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lowcostdex.cli import main
from lowcostdex.gap.logs import check_against_model, read_log

MJCF = """<mujoco>{compiler}
  <worldbody><body pos="0 0 0.2">
    <joint name="j" type="hinge" axis="0 1 0" range="-1.6 1.6"/>
    <geom type="capsule" fromto="0 0 0 0.05 0 0" size="0.01" mass="0.05"/>
  </body></worldbody>
  <actuator><position name="j" joint="j" kp="3"/></actuator>
</mujoco>"""


def _write(tmp_path, compiler: str):
    model = tmp_path / "model.xml"
    model.write_text(MJCF.format(compiler=compiler))
    t = np.arange(0.0, 10.0, 0.01)
    goal = 0.8 * np.sign(np.sin(2 * np.pi * 0.5 * t))
    q = goal * (1 - np.exp(-((t % 1.0) / 0.05)))  # a servo settling on each step, rad
    log = tmp_path / "log0.csv"
    np.savetxt(log, np.column_stack([t, goal, q]), delimiter=",", comments="",
               header="time,goal:j,qpos:j")
    return model, log


def test_degree_range_is_read_as_mujoco_documents_it(tmp_path):
    model, _ = _write(tmp_path, "")
    m = mujoco.MjModel.from_xml_path(str(model))
    assert m.jnt_range[0] == pytest.approx([-1.6 * math.pi / 180, 1.6 * math.pi / 180])


def test_a_range_written_in_rad_but_read_in_degrees_is_named(tmp_path, capsys):
    model, log = _write(tmp_path, "")
    code = main(["gap", "analyze", "--model", str(model), "--log", str(log),
                 "--out", str(tmp_path / "report")])
    err = capsys.readouterr().err
    assert code == 2
    assert 'angle="radian"' in err and "degrees" in err
    assert not (tmp_path / "report").exists()


def test_the_same_model_in_radians_passes_the_check(tmp_path):
    model, log = _write(tmp_path, '<compiler angle="radian"/>')
    m = mujoco.MjModel.from_xml_path(str(model))
    check_against_model(read_log(log), m)  # no LogError
