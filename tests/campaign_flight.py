"""One recorded flight of the evidence campaign, re-flown lock-step (the regression tests of issues 16 and 19)."""

from companion.ground import campaign as cg

SPEC = "examples/campaign-evidence.yaml"


def fly_recorded(flights: dict, i: int, keep_rig: bool = False, spec_path: str = SPEC):
    """Fly flight `i` of the spec; `flights[i]` = (vehicle, personality, offset of the first column) as recorded,
    so a change of the spec fails loudly here. Returns (scenario, campaign row)."""
    spec = cg.load_spec(spec_path)
    s, arm = cg.flight_of(spec, i)
    veh, pers, off = flights[i]
    assert (arm, s["vehicle"], s["personality"], round(s["lateral_offset_m"], 3)) == ("offboard", veh, pers, off), \
        f"{spec_path} no longer samples flight {i} as recorded here"
    assert s["in_assumption"]
    return s, cg.fly(spec, i, keep_rig=keep_rig)
