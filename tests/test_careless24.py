"""Careless calls, session 27 (issues 13, 11): each test failed on the code before its fix. The
physics a test needs is written out here in plain MuJoCo; a command is run as a user types it."""

from __future__ import annotations

import pytest

from lowcostdex.cli import USER_ERROR, main
from lowcostdex.errors import ConfigError


@pytest.mark.parametrize("extra,named", [(["--bc-epochs", "50"], "--bc-epochs"),
                                         (["--bc-log-std", "keep"], "--bc-log-std")])
def test_npg_refuses_clone_settings_without_a_clone(tmp_path, capsys, extra, named):
    # before: npg without --demos --bc-init made no clone and dropped the option unsaid
    out = tmp_path / "run"
    code = main(["train", "npg", "--out", str(out), "--n-iter", "1", "--no-progress", *extra])
    err = capsys.readouterr().err
    assert code == USER_ERROR, err
    assert f"{named}: settings of the behaviour clone, which npg makes only with --demos PATH " \
           "--bc-init" in err
    assert "Traceback" not in err and not out.exists()


_ARM = """<mujoco><worldbody><body><joint name="j" type="hinge" damping="0.1"/>
<geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0" mass="0.1"/></body></worldbody>
<actuator><position name="a" joint="j" kp="2"/></actuator></mujoco>"""


def test_a_randomization_on_a_joint_the_env_has_not_is_named_even_with_no_effects(tmp_path):
    # before: an extended model with no effect fitted gave a DomainRandomization on joint 'x'
    # that the valve env took without a word (with an effect it was refused), and one string
    # was read letter by letter
    import gymnasium as gym

    import lowcostdex  # noqa: F401  (registers the envs)
    from lowcostdex.gap.extension import load_extended, save_extended

    ext = load_extended(save_extended(tmp_path / "ext", {"arm": _ARM}, []))
    assert ext.domain_randomization("ff_top").joints == ("ff_top",)
    dr = ext.domain_randomization(joints=["x"])
    with pytest.raises(ConfigError, match=r"unknown joint in randomization.joints 'x'; valid "
                                          r"choices: 'ff_top', .*'valve'"):
        gym.make("lowcostdex/DClawTurnValve-v0", randomize=dr)
    gym.make("lowcostdex/DClawTurnValve-v0", randomize=ext.domain_randomization(["ff_top"])
             ).close()


@pytest.mark.parametrize("actuator,kind", [
    ('<position joint="j" kp="2"/>', "position"),
    ('<intvelocity joint="j" kp="2" actrange="-1 1"/>', "position"),
    ('<velocity joint="j" kv="1"/>', "velocity"),
    ('<motor joint="j" gear="3"/>', "force"),
    ('<general joint="j" gainprm="1"/>', "force"),
    ('<muscle joint="j" lengthrange="0.1 1"/>', "muscle"),
])
def test_what_an_actuators_input_is_has_one_predicate(actuator, kind):
    # before: load_dataset found the force actuators whose goals --units deg leaves alone by the
    # leading words of a message ('a motor', 'a muscle'); the input kind is now asked of one
    # predicate, and the message is said from it
    import mujoco

    from lowcostdex.gap.log_units import actuator_input, not_a_position_servo

    model = mujoco.MjModel.from_xml_string(_ARM.replace(
        '<position name="a" joint="j" kp="2"/>', actuator))
    assert actuator_input(model, 0) == kind
    assert bool(not_a_position_servo(model, 0)) == (kind != "position")
