"""How the beams cover the swept corridor, counted in D_od (companion/onboard/coverage.py): the geometry against
brute-force sampling, the refusal at `run --check` and at start, the banner, the estimator's D_od, and the narrow
beam's lock-step flight (the real daemon against the real SITL over real MAVLink bytes)."""

import math
import subprocess
import sys
from pathlib import Path
from unittest import mock

import numpy as np
import pytest

import companion.onboard.estimators as estimators
import companion.onboard.startup as startup
from companion.onboard.config import ContractConfig, SensorConfig, config_from_dict
from companion.onboard.coverage import Beam, Cover, banner_line, corridor_cover, covered_d_od, refusal
from companion.onboard.estimators import DodEstimator
from companion.onboard.samples import Scan
from tests.lockstep import Rig, fly_mission
from tests.test_daemon_lockstep import column_scenario

ROOT = Path(__file__).resolve().parents[1]
X500_W = 0.38 + 0.3  # the X500's r_body + the default E_tr floor


def sampled_cover(beams, w, beta=0.0, step=0.01):
    """The lowest covered interval by brute force: at each range, the corridor's bearings sampled finely."""
    top = max(b.range_m for b in beams)
    covered = []
    for r in np.arange(step, top + 1e-9, step):
        a = math.asin(min(w / r, 1.0))
        ok = True
        for off in np.linspace(-a, a, 181):
            if not any(b.range_m >= r - 1e-9 and
                       abs((beta + off - math.radians(b.orientation_deg) + math.pi) % (2 * math.pi) - math.pi)
                       <= math.radians(b.h_fov_deg) / 2 + 1e-9 for b in beams):
                ok = False
                break
        covered.append((r, ok))
    lo = next((r for r, ok in covered if ok), None)
    if lo is None:
        return None
    hi = lo
    for r, ok in covered:
        if r >= lo:
            if not ok:
                break
            hi = r
    return lo, hi


def test_a_3_degree_lidar_rated_12_m_covers_an_x500_corridor_nowhere_and_60_degrees_does():
    assert not corridor_cover([Beam(0, 3, 12)], X500_W).covered
    assert covered_d_od([Beam(0, 3, 12)], X500_W) == 0.0
    c = corridor_cover([Beam(0, 60, 12)], X500_W)
    assert c.covered and c.hi == 12 and c.lo == pytest.approx(X500_W / math.sin(math.radians(30)))


def test_a_long_narrow_beam_beside_a_short_wide_one_gives_the_wide_ones_range():
    """The narrow beam covers ±0.68 m only from 26 m on: an obstacle at the corridor's edge it sees at 30 m it
    loses again at 26 m, and the wide beam sees it next at 5 m."""
    c = corridor_cover([Beam(0, 3, 30), Beam(0, 60, 5)], X500_W)
    assert c.covered and c.hi == 5
    assert corridor_cover([Beam(0, 3, 30)], X500_W).lo == pytest.approx(X500_W / math.sin(math.radians(1.5)))


@pytest.mark.parametrize("beams, beta", [
    ([Beam(0, 60, 12)], 0.0), ([Beam(0, 60, 12)], math.radians(20)), ([Beam(0, 60, 12)], math.radians(29)),
    ([Beam(-25, 60, 12), Beam(25, 60, 10)], 0.0), ([Beam(-35, 60, 12), Beam(35, 60, 12)], 0.0),
    ([Beam(0, 86, 10), Beam(0, 3, 12)], 0.0), ([Beam(170, 60, 8), Beam(-170, 60, 9)], math.pi),
    ([Beam(0, 20, 40), Beam(0, 40, 15), Beam(0, 90, 4)], 0.1)])
def test_the_cover_matches_brute_force_sampling(beams, beta):
    c = corridor_cover(beams, X500_W, beta)
    s = sampled_cover(beams, X500_W, beta)
    if s is None:
        assert not c.covered
    else:
        assert c.covered and c.lo == pytest.approx(s[0], abs=0.011) and c.hi == pytest.approx(s[1], abs=0.011)


def test_the_refusal_names_each_sensor_its_width_and_the_corridor():
    why = refusal([SensorConfig(h_fov_deg=3, max_range_m=12)], 0.38, 0.3)
    assert "sensors[0] 3° wide, rated 12 m, covers ±0.31 m" in why and "±0.68 m" in why
    assert refusal([SensorConfig(h_fov_deg=60, max_range_m=12)], 0.38, 0.3) is None
    assert "covered at NO range" in banner_line([SensorConfig(h_fov_deg=3, max_range_m=12)], 0.38, 0.3)
    line = banner_line([SensorConfig(kind="obstacle_distance", h_fov_deg=86, max_range_m=10),
                        SensorConfig(h_fov_deg=3, max_range_m=12)], 0.38, 0.3)
    assert "out to 10 m: D_od at most 10 m (not the 12 m of the longest sensor" in line


def _config(tmp_path, fov, mode="governor"):
    cfg = tmp_path / f"cfg{fov}.yaml"
    cfg.write_text(f"vehicle: x500\nmode: {mode}\nsensors:\n  - kind: distance_sensor\n    h_fov_deg: {fov}\n"
                   f"    max_range_m: 12\nlog:\n  dir: {tmp_path / 'log'}\n")
    return cfg


def _check(cfg):
    return subprocess.run([sys.executable, "-m", "companion.cli", "run", "--config", str(cfg), "--check"],
                          capture_output=True, text=True, cwd=str(ROOT), timeout=120)


def test_run_check_refuses_the_narrow_beam_in_one_line_and_passes_the_wide_one(tmp_path):
    r = _check(_config(tmp_path, 3))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "governor mode refused" in err[0] and "3° wide" in err[0] and "±0.68 m" in err[0]
    ok = _check(_config(tmp_path, 60))
    assert ok.returncode == 0, ok.stderr
    assert "sensor coverage: the swept corridor ±0.68 m" in ok.stdout and "out to 12 m" in ok.stdout
    shadow = _check(_config(tmp_path, 3, mode="shadow"))  # shadow commands nothing: said, not refused
    assert shadow.returncode == 0 and "covered at NO range" in shadow.stdout


def _scan(t, max_m=12.0):
    return Scan(sensor=0, t=t, max_m=max_m, quality=100, hits=())


@pytest.mark.parametrize("fov, expect", [(3, 0.0), (60, 12.0)])
def test_the_estimators_d_od_is_the_cover_of_the_corridor(fov, expect):
    est = DodEstimator([SensorConfig(h_fov_deg=fov, max_range_m=12)], ContractConfig(), 0.5)
    est.add_scan(_scan(0.0))
    r_obst = est.r_obst
    d = est.estimate(0.01, 0.0, 2 * r_obst + X500_W)
    assert d.d_od == expect and d.stated_m == expect
    if expect == 0.0:
        assert "cover the swept corridor ±0.69 m nowhere" in d.reason  # 0.68 m, widened to the cycle's grid
    # the negative control: the claim alone (no corridor given) is the old D_od, the sensor's range
    assert est.estimate(0.02, 0.0).d_od == 12.0


def test_a_wider_tracking_error_lowers_the_d_od_of_a_beam_that_covers_only_far_out():
    est = DodEstimator([SensorConfig(h_fov_deg=6, max_range_m=12)], ContractConfig(), 0.5)
    est.add_scan(_scan(0.0))
    assert est.estimate(0.01, 0.0, 2 * est.r_obst + 0.5).d_od == 12.0  # 12·sin 3° = 0.63 m ≥ 0.5 m
    assert est.estimate(0.02, 0.0, 2 * est.r_obst + 0.7).d_od == 0.0


# ---------------------------------------------------------------- the lock-step flights

def narrow_scenario(fov_deg: float, edge_m: float, r_m: float = 0.5) -> dict:
    """The X500 (r_body 0.38 m) at 8 m/s cruise along y = 0 past one column of radius `r_m` whose edge is
    `edge_m` off the track; one forward sensor of `fov_deg` rated 12 m."""
    sc = column_scenario(1, x_col=40.0, cruise=8.0, vehicle="x500")
    sc["world"]["columns"][0].update(y_m=edge_m + r_m, radius_m=r_m)
    sc["sensor"].update(fov_deg=fov_deg, max_range_m=12.0)
    return sc


def _fly(sc) -> Rig:
    rig = Rig(sc, "px4")
    fly_mission(rig, 20.0)
    return rig


def test_the_narrow_beam_flight_is_refused_at_start():
    """The column's edge 0.30 m off the track: the daemon says why it refuses to engage, and its D_od is 0."""
    rig = _fly(narrow_scenario(3, 0.30))
    checks = rig.log.named("startup_check")
    assert checks and not checks[-1]["ok"] and "3° wide, rated 12 m" in checks[-1]["reason"]
    assert max(s["d_od"] for s in rig.log.states if s["t"] > 2.0) == 0.0  # in its beam or outside it (swept)


def test_engaged_anyway_the_narrow_beam_gives_no_safe_speed_and_no_collision():
    with mock.patch.object(startup, "coverage_refusal", lambda *a: None):
        rig = _fly(narrow_scenario(3, 0.30))
    assert not rig.truth["collisions"]
    assert max(s["ground_speed"] for s in rig.log.states) < 0.3
    assert all(s["d_od"] == 0.0 for s in rig.log.states if s["t"] > 2.0)


def test_the_same_flight_with_a_60_degree_sensor_holds_short_of_the_column():
    rig = _fly(narrow_scenario(60, 0.30))
    assert not rig.truth["collisions"]
    assert rig.log.named("hold_trigger")[0]["cause"] == "obstacle inside the stop distance"
    assert rig.log.named("startup_check")[-1]["ok"]


def test_negative_control_the_claim_alone_flies_into_a_column_the_beam_never_sees():
    """The old rule (D_od the sensor's claim, no refusal): the 3° beam's edge rays reach ±0.314 m at 12 m, so a
    column edge 0.34 m off the track is never seen; the vehicle's side (r_body 0.38 m) hits it at cruise."""
    full = lambda beams, w, beta, grid=False: Cover(0.0, math.inf, w)  # noqa: E731
    with mock.patch.object(startup, "coverage_refusal", lambda *a: None), \
            mock.patch.object(estimators, "corridor_cover", full):
        rig = _fly(narrow_scenario(3, 0.34))
    assert rig.truth["collisions"]
    assert not rig.log.named("hold_trigger")
    dods = sorted(s["d_od"] for s in rig.log.states if s["t"] > 2.0)
    assert dods[len(dods) // 2] > 10.0  # the claim, mostly (swept where the velocity strays out of the 3° beam)
    assert not _fly(narrow_scenario(3, 0.34)).log.named("startup_check")[-1]["ok"]


def test_the_cycles_grid_never_covers_more_than_the_exact_corridor():
    """The daemon's per-cycle cover (`grid=True`: the direction rounded, the half-width widened and rounded up)
    covers the corridor at no range where the exact one does not."""
    rng = np.random.default_rng(3)
    for _ in range(300):
        beams = [Beam(rng.uniform(-40, 40), rng.uniform(2, 120), rng.uniform(3, 30)) for _ in range(rng.integers(1, 4))]
        w, beta = rng.uniform(0.2, 1.5), rng.uniform(-0.6, 0.6)
        g, e = corridor_cover(beams, w, beta, grid=True), corridor_cover(beams, w, beta)
        assert g.half_width_m >= w
        if g.covered:
            mid = (g.lo + g.hi) / 2
            assert e.covered and all(
                any(abs((beta + off - math.radians(b.orientation_deg) + math.pi) % (2 * math.pi) - math.pi)
                    <= math.radians(b.h_fov_deg) / 2 + 1e-9 and b.range_m >= r for b in beams)
                for r in (g.lo + 1e-6, mid, g.hi) for off in np.linspace(-math.asin(min(w / r, 1)),
                                                                           math.asin(min(w / r, 1)), 41))
