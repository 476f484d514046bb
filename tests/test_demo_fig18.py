"""`contract-guard demo --scenario fig18` end to end: SITL and daemon on loopback UDP, the ground
station lowering CG_R_OBST in flight through the SITL's routing (40–80 s of wall time)."""

import pytest

from companion.ground.commands import demo


@pytest.mark.slow
def test_demo_fig18_ground_station_lowers_r_obst_in_flight(tmp_path):
    r = demo("fig18", tmp_path)
    assert r["safe"] and r["collisions"] == 0
    assert [a["value"] for a in r["gcs_actions"]] == [1.0, 0.6]
    assert all(a["t_acked"] is not None and a["t_log"] is not None for a in r["gcs_actions"])
    fog = [s for s in r["v_max_steps"] if s["d_od"] < 4]
    clear = [s for s in r["v_max_steps"] if s["d_od"] > 6 and s["r_obst"] > 0.9]
    small = [s for s in r["v_max_steps"] if s["r_obst"] < 0.7]
    assert fog and clear and small
    assert fog[-1]["v_max"] < clear[-1]["v_max"] < small[-1]["v_max"]  # up when the fog clears, up again
