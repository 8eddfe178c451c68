"""The family choice passes over a family whose fit puts a catalogue constant on a search bound
unless the held-back logs tell it (``gap.identify_select.untold``), on the fits of two real
splits typed in, measured 2026-11-29 (bench/RESULTS.md gap-real23): STS3032 with the 0.10 m arm
held out (48 training logs, 24 held out: the held-back logs cannot tell) and Rhoban XL330's BAM
split (kp 100 + 400 fitted, 200 + 800 held out: they can); and (gap-real24) Rhoban XL330 with its
four up_and_down logs held out (12 training logs: the held-back logs tell the back-driven share
held, 8.3 % below the catalogue's constants)."""

from __future__ import annotations

from lowcostdex.gap import identify_select as sel

# (family, restart): (least-squares cost, fitted logs' MAE [rad], held-back logs' MAE [rad],
# at a bound); the held-out MAE of each in the comment [mrad]
ARM = {("free", 0): (0.0053622, 0.01070, 0.02140, ["gearbox_friction.velocity",
                                                   "gearbox_friction.backdrive"]),  # 25.6
       ("free", 1): (0.0052592, 0.01066, 0.02436, ["gearbox_friction.backdrive"]),  # 28.7
       ("free", 2): (0.0056886, 0.01260, 0.02508, ["voltage_sag.weight"]),  # 35.0
       ("held", 0): (0.0051412, 0.01121, 0.01979, ["voltage_sag.weight"]),  # 35.1
       ("held", 1): (0.0058339, 0.01323, 0.02380, []),  # 49.3
       ("held", 2): (0.0048915, 0.01086, 0.01968, ["voltage_sag.weight"]),  # 40.7: chosen before
       ("nominal_motor", 0): (0.0059323, 0.01221, 0.02074, ["gearbox_friction.backdrive"]),  # 25.0
       ("nominal_motor", 1): (0.0059450, 0.01228, 0.02035, ["gearbox_friction.backdrive"]),  # 25.3
       ("nominal_motor", 2): (0.0059621, 0.01229, 0.02054, ["gearbox_friction.backdrive"])}  # 25.3
RHOBAN = {("free", 0): (0.0020886, 0.0228, 0.02789, ["gearbox_friction.backdrive",
                                                     "voltage_sag.weight"]),  # 30.1
          ("free", 1): (0.0020918, 0.0231, 0.03127, ["gearbox_friction.backdrive",
                                                     "voltage_sag.weight"]),  # 30.6
          ("free", 2): (0.0020744, 0.0227, 0.02705, ["gearbox_friction.backdrive",
                                                     "voltage_sag.weight"]),  # 30.9: chosen
          ("held", 0): (0.0040199, 0.0286, 0.02321, []),  # 34.0
          ("held", 1): (0.0040209, 0.0286, 0.02322, []),  # 34.0
          ("held", 2): (0.0039408, 0.0282, 0.02315, []),  # 34.0
          ("nominal_motor", 0): (0.0033006, 0.0287, 0.04409, ["gearbox_friction.velocity"]),
          ("nominal_motor", 1): (0.0032759, 0.0280, 0.04152, ["gearbox_friction.velocity"]),  # 49.4
          ("nominal_motor", 2): (0.0032781, 0.0281, 0.04151, ["gearbox_friction.velocity"])}
UP_DOWN = {("free", 0): (0.0057010, 0.02587, 0.04180, ["voltage_sag.weight"]),  # 26.3
           ("free", 1): (0.0056689, 0.02564, 0.03879, ["voltage_sag.weight"]),  # 33.7
           ("free", 2): (0.0058350, 0.02638, 0.03415, ["gearbox_friction.backdrive"]),  # 43.8
           ("held", 0): (0.0063102, 0.02612, 0.04341, ["voltage_sag.weight"]),  # 22.4
           ("held", 1): (0.0070273, 0.02846, 0.02763, ["voltage_sag.weight"]),  # 47.7
           ("held", 2): (0.0068776, 0.02745, 0.02898, []),  # 54.9
           ("nominal_motor", 0): (0.0106426, 0.03746, 0.04429, ["gearbox_friction.velocity",
                                                                "gearbox_friction.backdrive"]),
           ("nominal_motor", 1): (0.0110748, 0.03677, 0.04260, ["gearbox_friction.backdrive"]),
           ("nominal_motor", 2): (0.0094863, 0.03560, 0.04736, ["gearbox_friction.velocity"])}
MOTOR = frozenset({("velocity_limit", "scale"), ("motor_strength", "scale"),
                   ("supply_resistance", "resistance"), ("voltage_sag", "weight")})
HELD = {"free": frozenset(), "held": frozenset({("gearbox_friction", "backdrive")}),
        "nominal_motor": MOTOR}
N_FREE = {"free": 14, "held": 13, "nominal_motor": 10}


def _choose(fits, **kw):
    return sel.choose({k: v[0] for k, v in fits.items()}, {k: v[1] for k, v in fits.items()},
                      {k: N_FREE[k[0]] for k in fits}, **kw)


def _rule(fits):
    return dict(at_bound={k: v[3] for k, v in fits.items()}, held=HELD,
                val_mae={k: v[2] for k, v in fits.items()})


def test_a_motor_constant_on_a_bound_the_held_back_logs_do_not_tell_is_passed_over():
    fam, kept = _choose(ARM)  # the rule before: held, its drive fall with the duty at 1.5
    assert fam == "held" and kept["held"] == ("held", 2)
    # held.2's held-back MAE is 5.1 % below nominal_motor.0's: not told; free.1's bound is its
    # back-driven share, which held (fewer free parameters) holds at 1, and free.1 is 17 %
    # ABOVE nominal_motor.0 on the held-back logs: not told either (gap-real24; until then
    # only the smallest family's held parameters counted and free.1 was chosen: 28.7 mrad);
    # nominal_motor is chosen (25.0 mrad held out)
    fam, kept = _choose(ARM, **_rule(ARM))
    assert fam == "nominal_motor" and kept["nominal_motor"] == ("nominal_motor", 0)
    assert sel.untold(kept, {k: N_FREE[k[0]] for k in ARM}, **_rule(ARM)) == {"held", "free"}


def test_a_motor_constant_on_a_bound_the_held_back_logs_tell_is_kept():
    # Rhoban: free's drive term on its bound, but 35 % below nominal_motor on the held-back logs
    assert _choose(RHOBAN)[0] == "free"
    assert _choose(RHOBAN, **_rule(RHOBAN))[0] == "free"
    kept = sel.lowest_cost({k: v[0] for k, v in RHOBAN.items()})
    assert sel.untold(kept, {k: N_FREE[k[0]] for k in RHOBAN}, **_rule(RHOBAN)) == set()
    # without the held-back margin it would be passed over (and nominal_motor chosen: 49.4)
    assert sel.untold(kept, {k: N_FREE[k[0]] for k in RHOBAN}, **_rule(RHOBAN),
                      margin=0.5) == {"free"}


def test_bounds_the_smallest_family_does_not_hold_change_nothing():
    n = {("free", 0): 14, ("held", 0): 13, ("nominal_motor", 0): 10}
    kept = {f: (f, 0) for f in HELD}
    val = {k: 0.02 for k in n}
    # a friction on its bound: no family holds it
    assert sel.untold(kept, n, {("held", 0): ["gearbox_friction.mu"]}, HELD, val) == set()
    # the smallest family is never passed over for its own bounds
    assert sel.untold(kept, n, {("nominal_motor", 0): ["voltage_sag.weight"]}, HELD,
                      val) == set()


def test_a_bound_the_held_back_logs_tell_by_more_than_the_margin_is_kept():
    # Rhoban, up_and_down held out: held.0's drive term on its bound, 8.3 % below nominal_motor.2
    # on the held-back logs (told at UNTOLD_MARGIN 0.07; at gap-real23's 0.10 it was passed over
    # and free.1, 1.8 % lower on the fitted logs, chosen: held out 22.4 -> 33.7 mrad)
    assert _choose(UP_DOWN)[0] == "held"  # no rule: held.0 (22.4 mrad held out)
    fam, kept = _choose(UP_DOWN, **_rule(UP_DOWN))
    assert fam == "held" and kept["held"] == ("held", 0)
    assert sel.untold(kept, {k: N_FREE[k[0]] for k in UP_DOWN}, **_rule(UP_DOWN)) == set()
    assert sel.untold(kept, {k: N_FREE[k[0]] for k in UP_DOWN}, **_rule(UP_DOWN),
                      margin=0.10) == {"held"}
