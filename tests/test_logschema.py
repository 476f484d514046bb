"""`companion.onboard.logschema` lists exactly what the daemon writes: the golden flights' logs (every kind of
event), and one live flight with the real event log and the MAVLink it sends."""

import pytest

from companion.onboard.eventlog import EventLog, read_events
from companion.onboard.logschema import COMMANDS, EVENTS, LOG_FILE, NVF, RECORD_KEYS, STATE, STATE_FIELDS, SUBSYSTEMS
from tests import golden
from tests.lockstep import Rig, mav
from tests.test_daemon_lockstep import column_scenario, fly

GOLDEN = {name: golden.load(name) for name in golden.FLIGHTS}


@pytest.mark.parametrize("name", list(golden.FLIGHTS))
def test_golden_states_have_exactly_the_schema_fields_in_order(name):
    assert all(list(s) == ["t", *STATE_FIELDS] for s in GOLDEN[name]["states"])


@pytest.mark.parametrize("name", list(golden.FLIGHTS))
def test_golden_events_are_in_the_schema_with_their_fields(name):
    for e in GOLDEN[name]["events"]:
        assert e["event"] in EVENTS, e
        assert set(e) - {"t", "event"} <= set(EVENTS[e["event"]].fields), e
        if e["event"] == "violation_start":
            assert e["subsystem"] in SUBSYSTEMS
        if e["event"] == "command":
            assert e["cmd"] in COMMANDS


def test_every_state_field_has_a_unit_and_a_meaning():
    assert len(STATE_FIELDS) == len(set(STATE_FIELDS)) and all(meaning for _, meaning in STATE.values())
    assert not set(STATE_FIELDS) & set(RECORD_KEYS)


def test_a_live_flight_writes_the_schema_and_sends_its_nvfs_and_commands(tmp_path):
    log = EventLog(tmp_path, commit="none")
    rig = Rig(column_scenario(1), "px4", log=log)
    fly(rig, 6.0)
    log.close()
    recs = list(read_events(tmp_path / LOG_FILE))
    states = [r for r in recs if r["kind"] == "state"]
    events = [r for r in recs if r["kind"] == "event"]
    assert states and {r["kind"] for r in recs} == {"state", "event"}
    for r in states:
        assert list(r)[:5] == ["kind", "t", "wall", "seq", "boot"] and set(r) <= {*RECORD_KEYS, *STATE_FIELDS}
        assert [k for k in r if k not in RECORD_KEYS] == list(STATE_FIELDS)
    for e in events:
        assert e["event"] in EVENTS and set(e) - set(RECORD_KEYS) <= set(EVENTS[e["event"]].fields), e
    assert {"log_open", "command", "link", "limit_change"} <= {e["event"] for e in events}

    sent = rig.daemon_messages()
    assert {m.name for m in sent if m.get_type() == "NAMED_VALUE_FLOAT"} == set(NVF)
    wire = [m.command for m in sent if m.get_type() == "COMMAND_LONG"]
    logged = [getattr(mav, COMMANDS[e["cmd"]]) for e in events if e["event"] == "command"]
    assert wire == logged and len(logged) > len(set(logged))
