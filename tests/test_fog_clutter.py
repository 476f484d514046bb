"""A sensor told its clutter in hidden fog (examples/campaign-hidden-fog.yaml, `scenario.sensor_clutter_m`): the fog's
own returns, within 1.5 m of the SITL's sensor, wait for the frames that confirm them where the sensor had looked
past their place, so the governor flies on at the detection range the evidence gives instead of holding at the
first of them; the column on the route is still held for."""

from pathlib import Path

import pytest

from companion.ground import campaign as cg

SPEC = Path(__file__).resolve().parent.parent / "examples" / "campaign-hidden-fog.yaml"
SCENARIO = 3  # a Mambo on ArduPilot, the column 30 m on, the sensor stating 7.8 m


def _row(clutter: float | None) -> dict:
    d = cg.load_spec(SPEC).model_dump(mode="json")
    d.update(scenarios=SCENARIO + 1, arms=["governor_sector"])
    d["faults"][0].update(visibility_frac=0.8, p=1.0)
    d["scenario"]["sensor_clutter_m"] = clutter
    return cg.fly(cg.spec_from_dict(d), SCENARIO)


@pytest.fixture(scope="module")
def told():
    return _row(1.5)


def test_in_fog_at_0_8_of_the_stated_range_the_governor_flies_to_the_column_and_holds_there(told):
    assert not told["collided"] and told["holds"] == 1 and told["min_clearance_m"] < 3.0
    assert told["mean_speed_m_s"] > 1.4


def test_negative_control_without_the_clutter_the_fogs_first_return_is_a_hold_far_from_the_column(told):
    untold = _row(None)
    assert not untold["collided"] and untold["min_clearance_m"] > 10.0
    assert untold["mean_speed_m_s"] < 0.5 * told["mean_speed_m_s"]
