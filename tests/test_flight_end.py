"""Why a flight ended, and its failsafes counted where they happened: in the review and in the demo's summary.

A heavily loaded demo stopped at x = 12 m of 270 after its link flapped (the state went to failsafe 20 times);
its summary said `failsafes: 0` and not why the flight ended."""

import pytest

from companion.ground.review import format_report, summarise


def ev(t, name, **f):
    return {"kind": "event", "t": t, "event": name, **f}


def st(t, x, mode="offboard", state="active"):
    return {"kind": "state", "t": t, "x": x, "y": 0.0, "mode": mode, "state": state, "ground_speed": 2.0,
            "v_cmd": 3.0, "v_safe": 4.0, "v_max": 3.0, "d_od": 7.0, "e_tr": 0.5}


def flapping_flight(flaps=20):
    """Offboard flying, then the link lost and restored `flaps` times, the daemon braking to a fail-safe Hold."""
    recs = [ev(0.1, "state_change", **{"from": "standby", "to": "failsafe", "reason": "no autopilot heartbeat yet"}),
            ev(0.4, "link", status="up"),
            ev(2.0, "offboard", **{"from": "entering", "to": "flying", "reason": "autopilot in offboard"})]
    recs += [st(2.0 + 0.1 * k, 0.2 * k) for k in range(50)]
    t = 7.0
    for _ in range(flaps):
        recs += [ev(t, "link", status="down"),
                 ev(t, "state_change", **{"from": "active", "to": "failsafe", "reason": "autopilot heartbeat lost"}),
                 ev(t + 0.5, "link", status="up"),
                 ev(t + 0.5, "state_change", **{"from": "failsafe", "to": "standby", "reason": "link restored"})]
        t += 1.0
    recs += [ev(t, "failsafe", cause="bad navigation estimate", action="hold"),
             ev(t, "offboard", **{"from": "flying", "to": "braking", "reason": "fail-safe: the daemon brakes"}),
             ev(t + 1.0, "offboard", **{"from": "braking", "to": "held", "reason": "stopped: fail-safe Hold"}),
             st(t + 1.0, 12.0, mode="hold", state="holding")]
    return recs


def test_the_review_counts_failsafe_state_entries_and_says_why_the_flight_ended():
    rep = summarise(flapping_flight())
    assert rep["failsafe_count"] == 21 and rep["failsafe_state_entries"] == 20  # "no heartbeat yet" is no failsafe
    end = rep["flight_end"]
    assert end["why"].startswith("offboard held after bad navigation estimate") and end["t"] == pytest.approx(28.0)
    assert "flight ended: offboard held after bad navigation estimate" in format_report(rep)


def test_a_completed_route_and_a_resumed_hold_end_as_they_did():
    done = flapping_flight(flaps=1)[:-4] + [
        ev(20.0, "offboard", **{"from": "flying", "to": "done", "reason": "route flown"})]
    assert summarise(done)["flight_end"]["why"] == "route complete"
    resumed = flapping_flight(flaps=1) + [
        ev(12.0, "offboard", **{"from": "held", "to": "flying", "reason": "engaged"})]
    assert summarise(resumed)["flight_end"] is None  # it flew on: nothing ended it


def test_the_demo_summary_counts_failsafes_where_they_happened_and_says_why_it_ended(tmp_path):
    from companion.ground.demo import format_summary, summarise_flight
    from sitl_harness.scenario import load_scenario

    sc = load_scenario("fig17")
    recs = flapping_flight()
    r = summarise_flight(sc, recs, {"collisions": 0}, summarise(recs) | {"outputs": {}}, tmp_path)
    assert r["failsafes"] == 21  # the review's count, not the failsafe events alone (1)
    text = format_summary(r)
    assert "failsafes: 21" in text
    assert f"route flown to x = 12 m of {max(w[0] for w in sc.route.waypoints):.0f} m" in text
    assert "flight ended: offboard held after bad navigation estimate" in text
