"""Issue 19 item 1: a fail-safe mid-swerve in offboard is a stop the contract covers (lock-step).

On f5862c5 the daemon answered it with Hold at once; PX4's Hold and ArduPilot's Brake start from the
acceleration the vehicle has (the SITL personalities do the same) and ramp it out at the jerk limit, so
the swerve carried on: 10.4 m travelled where the stop contract bounds 8.1 m (Mambo, seed 1), 15.8 m
for 8.5 m (X500, seed 1). Now the daemon streams its own braking stop, then hands over to Hold."""

import pytest

from tests.failsafe_stop import fly


def check(r):
    assert not r["collided"], r
    assert r["travelled_m"] <= r["bound_m"], r  # within the stop contract's distance from that speed
    assert r["v_after_max"] <= 1.02 * r["limit"], r  # never faster than the limit in force
    assert r["v_end"] < 0.3, r
    rig = r["rig"]
    off = rig.log.named("offboard")
    assert ("braking", "off") == (off[-2]["to"], off[-1]["to"]) and off[-1]["reason"] == "stopped: hold"
    assert rig.log.named("mode_change")[-1]["to"] == "hold"  # handed over to Hold at rest


@pytest.mark.parametrize("vehicle", ["mambo", "x500"])
@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_a_failsafe_mid_swerve_is_a_stop_within_the_stop_contract(personality, vehicle):
    for seed in (1, 2):
        check(fly(seed, personality, vehicle))


@pytest.mark.slow
@pytest.mark.xfail(reason="issue 19 item 1, open: X500 seeds 3 and 4 overrun the daemon's hard stop and are pulled "
                          "back to its end (8.16 m for 8.16, 9.60 m for 7.76 m; 29 of 32 within the bound, none collide)",
                   strict=False)
def test_thirty_two_seeded_failsafes_mid_swerve_all_stop_within_the_stop_contract():
    out = [fly(seed, pers, veh) for seed in range(1, 9) for pers in ("px4", "ardupilot") for veh in ("mambo", "x500")]
    for r in out:
        check(r)
