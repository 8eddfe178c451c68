"""Pure pieces under the Robot: the command gate, the thermal and current guards, the rate timer."""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.hardware.robot.guards import (
    CurrentConfig,
    CurrentGuard,
    PauseRecord,
    ThermalConfig,
    ThermalGuard,
)
from lowcostdex.hardware.robot.robot import RobotConfig
from lowcostdex.hardware.robot.safety import UnsafeCommand, check_finite, clip_goal
from lowcostdex.hardware.timing import Rate
from lowcostdex.motors import MOTORS


class FakeClock:
    def __init__(self):
        self.t = 0.0
        self.slept = []

    def now(self):
        return self.t

    def sleep(self, s):
        if s > 0:
            self.slept.append(s)
            self.t += s


def test_clip_goal_motion_bound_then_limits():
    low, high = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])
    present = np.array([0.0, 0.95, 1.3])  # the last joint is outside its limits
    r = clip_goal(np.array([0.5, 2.0, 1.5]), low, high, present, np.full(3, 0.2))
    np.testing.assert_allclose(r.goal, [0.2, 1.0, 1.0])
    np.testing.assert_array_equal(r.motion_clipped, [True, True, False])
    np.testing.assert_array_equal(r.limit_clipped, [False, True, True])
    assert np.all(r.goal <= high) and np.all(r.goal >= low)


def test_check_finite_names_the_bad_joints_and_shape():
    names = ("a", "b", "c")
    with pytest.raises(UnsafeCommand, match=r"b=nan, c=inf"):
        check_finite(np.array([0.0, np.nan, np.inf]), names)
    with pytest.raises(UnsafeCommand, match=r"shape \(2,\)"):
        check_finite(np.zeros(2), names)
    np.testing.assert_array_equal(check_finite([1, 2, 3], names), [1.0, 2.0, 3.0])


def test_thermal_guard_warns_pauses_and_relaxes_at_critical_once():
    g = ThermalGuard(ThermalConfig(), limit=80.0, names=("a", "b"))
    assert (g.warn, g.resume, g.critical) == (65.0, 50.0, 73.0)
    assert not g.update(np.array([40.0, 64.9])).any() and not g.pause_pending
    assert not g.update(np.array([40.0, 65.0])).any() and g.pause_pending
    hot = g.update(np.array([73.5, 66.0]))
    np.testing.assert_array_equal(hot, [True, False])
    assert not g.update(np.array([74.0, 66.0])).any()  # not repeated while relaxed
    assert g.relaxations == 1 and g.max_seen[0] == 74.0
    assert not g.cooled(np.array([49.0, np.nan]))  # unknown is not cool
    assert not g.cooled(np.array([49.0, 50.0]))
    assert g.cooled(np.array([49.0, 49.9]))


def test_thermal_config_validates_margins():
    with pytest.raises(ConfigError, match="resume_margin > warn_margin"):
        ThermalConfig(warn_margin=10.0, resume_margin=5.0)
    with pytest.raises(ConfigError, match="thermal pause mode"):
        ThermalConfig(pause_mode="nap")


def test_current_guard_needs_a_sustained_overload_and_expires():
    g = CurrentGuard(CurrentConfig(window=3, relax_steps=2), limit=np.array([1.0, 1.0]))
    for _ in range(2):
        assert not g.update(np.array([1.5, 0.1])).any()
    assert not g.update(np.array([0.5, 0.1])).any()  # a dip resets the count
    for _ in range(2):
        g.update(np.array([-1.5, np.nan]))
    np.testing.assert_array_equal(g.update(np.array([1.5, np.nan])), [True, False])
    assert g.events == 1 and g.relaxed[0]
    g.tick()
    g.tick()
    assert not g.relaxed.any()


def test_rate_sleeps_to_the_tick_and_counts_overruns_without_catch_up():
    clock = FakeClock()
    rate = Rate(0.1, clock)
    clock.t += 0.03  # work
    assert rate.wait() == 0.0
    assert clock.t == pytest.approx(0.1)
    clock.t += 0.25  # an overrun of 0.15 s
    assert rate.wait() == pytest.approx(0.15)
    assert rate.stats.overruns == 1
    before = clock.t
    rate.wait()  # re-anchored: a full period, not an immediate catch-up tick
    assert clock.t - before == pytest.approx(0.1)
    assert rate.stats.ticks == 3


def test_goal_referenced_rate_limit_bounds_the_lead_over_the_present_position():
    low, high = np.full(2, -2.0), np.full(2, 2.0)
    last_goal, present = np.array([0.5, 0.5]), np.array([0.45, 0.0])  # joint 1 is blocked
    r = clip_goal(np.array([1.5, 1.5]), low, high, last_goal, np.full(2, 0.1), present,
                  np.full(2, 0.4))
    np.testing.assert_allclose(r.goal, [0.6, 0.4])  # rate limit; lead bound on the blocked one


# -- edges a user relies on (issue 19: mutants that survived the suite) -------------------------


def test_a_goal_below_the_lower_limit_is_clipped_to_it():
    low, high = np.array([-0.5, -1.0]), np.array([0.5, 1.0])
    present = np.array([-0.45, -0.95])
    r = clip_goal(np.array([-3.0, -0.9]), low, high, present, np.full(2, 0.2))
    np.testing.assert_allclose(r.goal, [-0.5, -0.9])  # -0.45 - 0.2 = -0.65 is below -0.5
    np.testing.assert_array_equal(r.limit_clipped, [True, False])
    np.testing.assert_array_equal(r.motion_clipped, [True, False])


def test_a_goal_far_below_the_present_position_moves_one_step_down():
    low, high = np.full(3, -2.0), np.full(3, 2.0)
    present = np.array([0.5, 0.0, -1.0])
    r = clip_goal(np.array([-1.5, -0.15, -1.9]), low, high, present, np.array([0.2, 0.2, 0.3]))
    np.testing.assert_allclose(r.goal, [0.3, -0.15, -1.3])
    np.testing.assert_array_equal(r.motion_clipped, [True, False, True])
    assert not r.limit_clipped.any()


def test_goal_referenced_lead_bound_below_the_present_position():
    low, high = np.full(2, -2.0), np.full(2, 2.0)
    last_goal, present = np.array([-0.5, -0.5]), np.array([-0.45, 0.0])  # joint 1 blocked
    r = clip_goal(np.array([-1.5, -1.5]), low, high, last_goal, np.full(2, 0.1), present,
                  np.full(2, 0.4))
    np.testing.assert_allclose(r.goal, [-0.6, -0.4])  # -0.5 - 0.1; 0.0 - 0.4


def test_thermal_guard_relaxes_at_exactly_the_critical_temperature():
    g = ThermalGuard(ThermalConfig(), limit=80.0, names=("a", "b"))  # critical 80 - 7 = 73
    assert not g.update(np.array([72.99, 20.0])).any()
    np.testing.assert_array_equal(g.update(np.array([73.0, 20.0])), [True, False])
    assert g.relaxations == 1 and g.pause_pending


def test_thermal_guard_warns_at_exactly_the_warn_temperature_once():
    g = ThermalGuard(ThermalConfig(), limit=70.0, names=("a",))  # warn 70 - 15 = 55
    g.update(np.array([54.99]))
    assert not g.pause_pending and g.warnings == 0
    g.update(np.array([55.0]))
    g.update(np.array([56.0]))
    assert g.pause_pending and g.warnings == 1


def test_a_second_critical_motor_does_not_release_the_first():
    g = ThermalGuard(ThermalConfig(), limit=80.0, names=("a", "b", "c"))
    np.testing.assert_array_equal(g.update(np.array([74.0, 60.0, 30.0])), [True, False, False])
    np.testing.assert_array_equal(g.update(np.array([74.0, 75.0, 30.0])), [False, True, False])
    np.testing.assert_array_equal(g.relaxed, [True, True, False])
    assert not g.update(np.array([74.0, 75.0, 30.0])).any()  # neither is reported again
    assert g.relaxations == 2


def test_the_end_of_a_pause_is_recorded_and_clears_pending_and_relaxed():
    g = ThermalGuard(ThermalConfig(), limit=80.0, names=("a", "b"))
    g.update(np.array([74.0, 66.0]))
    assert g.pause_pending and g.relaxed[0]
    record = PauseRecord(start=12.0, duration=300.0, peak=74.0, hottest="a", end_max=49.0)
    g.end_pause(record)
    assert g.pauses == [record] and not g.pause_pending and not g.relaxed.any()
    assert g.pause_pending is False  # a bool, as telemetry reports it (pause_pending: bool)
    np.testing.assert_array_equal(g.update(np.array([74.0, 20.0])), [True, False])  # again
    assert g.relaxations == 2


def test_an_overload_relaxation_lasts_exactly_relax_steps_control_steps():
    g = CurrentGuard(CurrentConfig(window=2, relax_steps=3), limit=np.array([1.0]))
    assert not g.update(np.array([1.0])).any()  # at the limit is not above it
    g.update(np.array([1.01]))
    assert g.update(np.array([1.01]))[0]
    for _ in range(2):
        g.tick()
        assert g.relaxed[0]
        assert not g.update(np.array([1.01])).any()  # still overloaded: not a new event
    g.tick()
    assert not g.relaxed[0]
    assert g.update(np.array([1.01]))[0] and g.events == 2  # still over after it: a new one


def test_thermal_config_boundaries():
    ThermalConfig(critical_margin=0.0)  # relax at the firmware limit itself: allowed
    ThermalConfig(warn_margin=7.5, critical_margin=7.0, resume_margin=7.6)
    for bad in (dict(critical_margin=-0.1), dict(warn_margin=7.0),
                dict(resume_margin=15.0), dict(poll_interval=0.0), dict(max_pause=0.0)):
        with pytest.raises(ConfigError):
            ThermalConfig(**bad)


def test_current_config_boundaries():
    CurrentConfig(fraction=1.0, window=1, relax_steps=1, relaxed_step=1e-6)
    CurrentConfig(limit=1e-3)
    for bad in (dict(limit=0.0), dict(fraction=0.0), dict(fraction=1.01), dict(window=0),
                dict(relax_steps=0), dict(relaxed_step=0.0)):
        with pytest.raises(ConfigError):
            CurrentConfig(**bad)


def test_robot_config_boundaries():
    RobotConfig(max_lead=1.0, max_invalid_reads=0, max_reboots=0)
    for bad in (dict(control_period=0.0), dict(motion_scale=0.0), dict(max_lead=0.99),
                dict(max_invalid_reads=-1), dict(max_reboots=-1),
                dict(motion_reference="previous")):
        with pytest.raises(ConfigError):
            RobotConfig(**bad)


def test_config_errors_name_the_field_and_small_positive_values_pass():
    """The messages a user reads name what to fix (message-dropping mutants survived before);
    sub-second poll intervals and pauses are valid."""
    ThermalConfig(poll_interval=0.01, max_pause=0.5)
    CurrentConfig(fraction=0.001, relaxed_step=0.001)
    with pytest.raises(ConfigError, match="pause mode.*'torque_off'"):
        ThermalConfig(pause_mode="freeze")
    with pytest.raises(ConfigError, match="resume_margin > warn_margin > critical_margin"):
        ThermalConfig(warn_margin=40.0)
    with pytest.raises(ConfigError, match="poll_interval and max_pause"):
        ThermalConfig(max_pause=-1.0)
    with pytest.raises(ConfigError, match="limit must be > 0"):
        CurrentConfig(limit=-1.0)
    with pytest.raises(ConfigError, match=r"fraction must be in \(0, 1\]"):
        CurrentConfig(fraction=2.0)
    with pytest.raises(ConfigError, match="window, relax_steps >= 1"):
        CurrentConfig(window=0)


def test_stuck_rise_must_exceed_one_whole_degree():
    """Readings are whole degrees: a flat reading can hide up to 1 K of real rise, so the
    model's rise that calls a sensor stuck must be above 1 K (ThermalConfig's docstring)."""
    ThermalConfig(stuck_rise=1.01)
    ThermalConfig(stuck_rise=1.5)
    for bad in (1.0, 0.5, 0.0):
        with pytest.raises(ConfigError):
            ThermalConfig(stuck_rise=bad)


def test_config_errors_read_in_full():
    """The whole message a user reads, the field names in their own case (the tests above match
    a fragment, so a message wrapped in XX...XX or lower-cased passed them)."""
    cases = [
        (dict(pause_mode="freeze"),
         "unknown thermal pause mode 'freeze'; valid choices: 'torque_off', 'hold'"),
        (dict(stuck_rise=1.0),
         "ThermalConfig.stuck_rise must be > 1 K (readings are whole degrees), got 1.0"),
        (dict(warn_margin=40.0), "ThermalConfig: need resume_margin > warn_margin > "
                                 "critical_margin >= 0, got 30.0, 40.0, 7.0"),
        (dict(poll_interval=0.0), "ThermalConfig: poll_interval and max_pause must be > 0"),
    ]
    for kwargs, message in cases:
        with pytest.raises(ConfigError) as err:
            ThermalConfig(**kwargs)
        assert str(err.value) == message
    for kwargs, message in [
        (dict(limit=0.0), "CurrentConfig.limit must be > 0"),
        (dict(fraction=0.0), "CurrentConfig.fraction must be in (0, 1]"),
        (dict(relaxed_step=0.0), "CurrentConfig: window, relax_steps >= 1 and relaxed_step > 0"),
    ]:
        with pytest.raises(ConfigError) as err:
            CurrentConfig(**kwargs)
        assert str(err.value) == message


def test_a_stuck_sensor_neither_holds_a_pause_open_nor_ends_it():
    """A stuck reading says nothing about its winding: the cool-down test leaves it out (the
    guards' docstring), whether it reads hot or cool; the other motors still count. Stuck
    here at 60 deg C, above resume (50): 1 A in the XH430-W350's winding heats it
    (I^2 R (1 + 0.0039 x 35 K) - 35 K / 12 K/W) / 8 J/K = 1.55 K/s (R = 13.5 Ohm), so its
    model is 5 K above the flat reading after ~3.2 s."""
    spec = MOTORS["XH430-W350"]
    g = ThermalGuard(ThermalConfig(), limit=80.0, names=("a", "b"), motor=spec)
    t = 0.0
    while not g.stuck[0] and t < 60.0:
        g.update(np.array([60.0, 40.0]), current=np.array([1.0, 0.0]), time=t)
        t += 0.5
    assert g.stuck.tolist() == [True, False] and 2.0 < t < 6.0
    assert g.cooled(np.array([60.0, 40.0]))  # the stuck 60 does not hold the pause open
    assert not g.cooled(np.array([60.0, 55.0]))  # the other motor, still warm, does
    assert not g.cooled(np.array([60.0, np.nan]))  # and an unknown reading of it too


def _stuck_run(g, readings, currents, period=0.5):
    """Feed reads (each (n,) deg C) with currents (n,) [A] every ``period`` s."""
    for k, t in enumerate(readings):
        g.update(np.asarray(t, float), current=np.asarray(currents, float), time=k * period)


def test_a_sensor_flickering_a_whole_degree_is_alive_and_an_unknown_current_heats_nothing():
    """Stuck means "has not moved by a whole degree" while the model rose 5 K (the guards'
    docstring). A reading flickering between 60 and 61 (a real winding near 60.5 deg C) moves a
    whole degree every read: alive, however hot the model says the winding is (1 A: 1.55 K/s,
    stuck after ~3 s if the flicker were ignored). A NaN current is unknown: no heat, no
    verdict, over the same 30 s."""
    spec = MOTORS["XH430-W350"]
    g = ThermalGuard(ThermalConfig(), limit=80.0, names=("a", "b"), motor=spec)
    flicker = [[60.0 + k % 2, 40.0] for k in range(60)]
    _stuck_run(g, flicker, [1.0, np.nan])
    assert not g.stuck.any() and not g.sensor_fault.any()
    # control: the same current with a flat reading is found stuck within seconds
    h = ThermalGuard(ThermalConfig(), limit=80.0, names=("a", "b"), motor=spec)
    _stuck_run(h, [[60.0, 40.0]] * 60, [1.0, np.nan])
    assert h.stuck.tolist() == [True, False]


def test_a_second_stuck_sensor_does_not_clear_the_first():
    """Both stay flagged for the session (stuck, sensor_fault) and relaxed at every read."""
    spec = MOTORS["XH430-W350"]
    g = ThermalGuard(ThermalConfig(), limit=80.0, names=("a", "b"), motor=spec)
    # a at 1 A is stuck after ~3 s, b at 0.5 A (I^2: a quarter of the heat) much later
    _stuck_run(g, [[60.0, 45.0]] * 120, [1.0, 0.5])
    assert g.stuck.tolist() == [True, True]
    assert g.sensor_fault.tolist() == [True, True]
    assert g.relaxed.tolist() == [True, True] and g.relaxations == 2


def test_check_finite_returns_floats_and_its_shape_message_lists_the_joints():
    names = ("a", "b", "c")
    g = check_finite([1, 2, 3], names)  # "the goal as a float array" (its docstring)
    assert g.dtype == np.float64
    with pytest.raises(UnsafeCommand) as err:
        check_finite(np.zeros(2), names)
    assert str(err.value) == "goal has shape (2,), expected (3,) for joints a, b, c; nothing sent"


def test_a_faulty_sensor_is_left_out_of_the_cool_down_while_faulty_and_stays_flagged():
    """The bus says which readings are no temperature (an Allegro byte >= 0x80 reads NaN): the
    pause does not wait for them; a recovered sensor counts again but stays on the record."""
    g = ThermalGuard(ThermalConfig(), limit=80.0, names=("a", "b"))
    g.update(np.array([np.nan, 40.0]), sensor_fault=np.array([True, False]))
    assert g.sensor_fault.tolist() == [True, False]
    assert g.cooled(np.array([np.nan, 40.0]))  # b is cool; a's reading is no temperature
    g.update(np.array([55.0, 40.0]), sensor_fault=np.array([False, False]))  # a recovered
    assert not g.cooled(np.array([55.0, 40.0]))  # and counts again: 55 is above resume 50
    assert g.sensor_fault.tolist() == [True, False]  # flagged for the session


def test_a_guard_without_a_motor_spec_makes_no_stuck_verdict():
    # the Allegro: no motor spec, so no thermal model; currents and times change nothing
    g = ThermalGuard(ThermalConfig(), limit=80.0, names=("a",))
    for k in range(20):
        g.update(np.array([60.0]), current=np.array([1.0]), time=0.5 * k)
    assert not g.stuck.any() and not g.relaxed.any()


def test_each_pause_request_is_counted():
    g = ThermalGuard(ThermalConfig(), limit=80.0, names=("a",))
    g.update(np.array([66.0]))
    g.end_pause(PauseRecord(start=0.0, duration=60.0, peak=66.0, hottest="a", end_max=49.0))
    g.update(np.array([66.0]))
    assert g.pause_pending and g.warnings == 2


def test_a_lead_bound_applies_only_when_both_present_and_max_lead_are_given():
    # clip_goal's docstring: "then (if given) to present +- max_lead"; the Robot passes the
    # present position with max_lead None when no lead bound is configured
    low, high = np.full(2, -1.0), np.full(2, 1.0)
    goal, ref, step = np.array([0.5, -0.5]), np.zeros(2), np.full(2, 0.3)
    plain = clip_goal(goal, low, high, ref, step)
    for present, lead in ((np.array([0.2, -0.2]), None), (None, np.full(2, 0.01))):
        r = clip_goal(goal, low, high, ref, step, present=present, max_lead=lead)
        np.testing.assert_array_equal(r.goal, plain.goal)
        np.testing.assert_array_equal(r.goal, [0.3, -0.3])


def test_stuck_is_called_at_the_first_read_where_the_model_has_risen_5_k():
    """ThermalConfig's docstring: 5 K of model rise over a flat reading (room for a model 5x too
    hot). The model integrated here by hand (explicit Euler at the read interval, the dcmotor
    heating checked against MuJoCo in test_robot_faults) says when: not a read earlier or later."""
    spec, period, amps, flat = MOTORS["XH430-W350"], 0.5, 1.0, 60.0
    model, k_expected = flat, 0
    while model - flat < 5.0:
        model += period * float(spec.winding_heating(amps, model))
        k_expected += 1
    g = ThermalGuard(ThermalConfig(), limit=80.0, names=("a",), motor=spec)
    for k in range(k_expected):
        g.update(np.array([flat]), current=np.array([amps]), time=k * period)
        assert not g.stuck[0]
    g.update(np.array([flat]), current=np.array([amps]), time=k_expected * period)
    assert g.stuck[0] and k_expected == 7


def test_current_guard_defaults_overload_after_5_reads_and_hold_it_20_steps():
    # CurrentConfig's documented defaults as a user meets them: window 5 reads, relax_steps 20
    g = CurrentGuard(CurrentConfig(), limit=np.array([1.0]))
    for _ in range(4):
        assert not g.update(np.array([1.5])).any()
    assert g.update(np.array([1.5]))[0]
    for _ in range(19):
        g.tick()
        assert g.relaxed[0]
    g.tick()
    assert not g.relaxed[0]
