import pytest
import yaml

from contracts.errors import ContractError
from contracts.vehicle import DATA_DIR, G, load_vehicle


@pytest.mark.parametrize("name", ["mambo", "x500"])
def test_shipped_vehicles_load_and_hover_over_their_thrust_range(name):
    v = load_vehicle(name)
    lo, hi = v.thrust_ratio_range
    assert v.t_max(lo) > v.mass_kg * G  # can hover at the bottom of its range
    assert abs(4 * v.rotor.k_thrust * v.rotor.omega_max_rad_s**2 - v.t_nom_n) < 0.02 * v.t_nom_n


def test_mambo_constants_match_the_reference():
    v = load_vehicle("mambo")
    assert v.mass_kg == 0.063
    assert v.t_nom_n == pytest.approx(1.307, abs=0.002)
    assert v.hover_fraction() == pytest.approx(0.473, abs=0.002)


def _write(tmp_path, data):
    p = tmp_path / "v.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _mambo_dict():
    return yaml.safe_load((DATA_DIR / "mambo.yaml").read_text())


def test_unknown_key_is_one_line_naming_it(tmp_path):
    d = _mambo_dict()
    d["braking"]["decel_max"] = 3.0
    with pytest.raises(ContractError) as e:
        load_vehicle(_write(tmp_path, d))
    assert "braking.decel_max" in str(e.value) and "\n" not in str(e.value)


def test_bad_value_is_one_line_naming_it(tmp_path):
    d = _mambo_dict()
    d["braking"]["jerk_max_m_s3"] = -1
    with pytest.raises(ContractError) as e:
        load_vehicle(_write(tmp_path, d))
    assert "braking.jerk_max_m_s3" in str(e.value) and "-1" in str(e.value)


def test_mambo_cannot_fly_a_range_starting_at_half_thrust(tmp_path):
    d = _mambo_dict()
    d["thrust_ratio_range"] = [0.5, 1.0]
    with pytest.raises(ContractError, match="thrust_ratio_range"):
        load_vehicle(_write(tmp_path, d))


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ContractError, match="cannot read"):
        load_vehicle(tmp_path / "nope.yaml")
    p = tmp_path / "bad.yaml"
    p.write_text("mass_kg: [1, 2\n")
    with pytest.raises(ContractError, match="not valid YAML"):
        load_vehicle(p)


def test_fingerprint_changes_with_any_parameter(tmp_path):
    d = _mambo_dict()
    a = load_vehicle(_write(tmp_path, d)).fingerprint()
    d["r_body_m"] = 0.11
    assert load_vehicle(_write(tmp_path, d)).fingerprint() != a
