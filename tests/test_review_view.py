"""What the review shows: every hold (the daemon's, a calibration hold's, a shadow flight's would-be hold),
failsafe (events and the failsafe state), stand-down, link-down span and collision marked on every plot (read
back from the figures' artists), titles inside the figure, a plan view of a real lock-step flight into a column
(track, obstacle hits, keep-out disc at the closest approach, the collision where the simulator saw it), an
HTML page for one log, the firmware of a .tlog, and failsafes counted where they happened."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from companion.onboard.eventlog import EventLog
from companion.ground.review import CSV_COLUMNS, analyse, format_report, plot_title, summarise

mpl = pytest.importorskip("matplotlib")
from companion.ground import review_plots as rp  # noqa: E402

DT = 0.1
CHROMIUM = Path("/usr/bin/chromium")

# the scripted flight's marks (t in s): (kind, start, end); points: (kind, t)
SPANS = {"hold": (10.0, 13.0), "would_hold": (20.0, 22.0), "calibration_hold": (30.0, 33.0),
         "failsafe_state": (40.0, 43.0), "link_down": (40.0, 43.0)}
POINTS = {"failsafe": 50.0, "stand_down": 13.0, "collision": 55.0}


def scripted_flight(directory: Path) -> None:
    """60 s eastwards at 2 m/s with every kind of mark, through the real EventLog (as the daemon writes it)."""
    log = EventLog(directory, commit="none")
    log.event(0.0, "start", mode="governor", vehicle="x500", table="")
    log.event(0.0, "link", status="up")
    log.event(0.5, "mission", status="ready", waypoints=[[0.0, 0.0], [0.0, 120.0]], altitude_m=10.0)
    ev = {
        10.0: [("hold_trigger", dict(cause="obstacle inside the stop distance", action="hold")),
               ("state_change", {"from": "active", "to": "holding", "reason": "obstacle inside the stop distance"})],
        13.0: [("state_change", {"from": "holding", "to": "active", "reason": "position set by someone else: standing down"})],
        14.0: [],
        20.0: [("would_hold", dict(causes=["no safe speed"]))],
        22.0: [("would_hold", dict(causes=[]))],
        30.0: [("calibration_hold", dict(status="commanded", leg=0, seq=3, leg_speed_m_s=2.0))],
        33.0: [("calibration_hold", dict(status="resumed", leg=0, seq=3, leg_speed_m_s=2.0, rest_s=2.0))],
        40.0: [("link", dict(status="down")),
               ("state_change", {"from": "active", "to": "failsafe", "reason": "autopilot heartbeat lost"})],
        43.0: [("link", dict(status="up")),
               ("state_change", {"from": "failsafe", "to": "standby", "reason": "link restored"})],
        50.0: [("failsafe", dict(cause="stale telemetry", action="hold"))],
        52.0: [("violation_start", dict(subsystem="controller", guarantee="contour error", assumed=0.5, observed=0.9,
                                        action="E_tr raised"))],
        53.0: [("violation_end", dict(subsystem="controller", guarantee="contour error"))],
    }
    for i in range(600):
        t = round(i * DT, 3)
        for name, fields in ev.get(t, []):
            log.event(t, name, **fields)
        x_east = 2.0 * t
        # a column of radius 0.5 on the path at east 90 m: seen from 19.5 m, last at 0.7 m (t 44.4 s)
        ob = 89.5 - x_east if 70.0 <= x_east < 89.0 else None
        log.state(t, state="active", mode="mission", contract="stop", engaged=True, x=0.0, y=x_east, z=-10.0,
                  vx=0.0, vy=2.0, vz=0.0, ground_speed=2.0, d_od=8.0, e_tr=0.4, e_tr_measured=0.3, r_obst=0.5,
                  thrust_ratio=1.0, v_max=3.0, tilt_deg=30.0, v_safe=3.5, gamma=-0.5, gamma_flown=-1.5, v_cmd=3.0,
                  obstacle_m=ob)
    log.event(60.0, "stop")
    log.close()


@pytest.fixture(scope="module")
def scripted(tmp_path_factory):
    d = tmp_path_factory.mktemp("marks")
    scripted_flight(d / "log")
    rep, samples = analyse([d / "log" / "events.jsonl"], keep_samples=True)
    rep["marks"]["collisions"] = [{"t": POINTS["collision"], "x": 1.0, "y": 110.0, "what": "column"}]
    return d, rep, samples


def artists(ax):
    """(gid, x-extent) of every marked artist of an axes: spans' patches and lines."""
    out = []
    for a in [*ax.patches, *ax.lines]:
        gid = a.get_gid() or ""
        if gid.startswith("mark:"):
            if hasattr(a, "get_width"):  # axvspan: a Rectangle in data x
                xs = [a.get_x(), a.get_x() + a.get_width()]
            elif hasattr(a, "get_xy"):
                xs = [p[0] for p in a.get_xy()]
            else:
                xs = list(a.get_xdata())
            out.append((gid[5:], min(xs), max(xs)))
    return out


def test_the_summary_finds_every_mark_and_counts_failsafes_where_they_happened(scripted):
    _, rep, _ = scripted
    m = rep["marks"]
    assert [(s["start_t"], s["end_t"]) for s in m["holds"]] == [SPANS["hold"]]
    assert [(s["start_t"], s["end_t"]) for s in m["calibration_holds"]] == [SPANS["calibration_hold"]]
    assert [(s["start_t"], s["end_t"]) for s in m["failsafe_states"]] == [SPANS["failsafe_state"]]
    assert [(s["start_t"], s["end_t"]) for s in m["link_down"]] == [SPANS["link_down"]]
    assert [p["t"] for p in m["stand_downs"]] == [POINTS["stand_down"]]
    # one failsafe event and one link loss: two failsafes (main counted only the event)
    assert rep["failsafe_count"] == 2 and rep["failsafe_events"] == 1 and rep["failsafe_state_entries"] == 1
    assert any(f.startswith("2 failsafe(s)") and "into the failsafe state" in f for f in rep["findings"])
    assert rep["route"] == [[0.0, 0.0], [0.0, 120.0]] and rep["obstacle_data"] is True


def test_every_time_panel_carries_every_mark_where_it_happened(scripted):
    _, rep, samples = scripted
    fig = rp.time_figure(rep, samples, CSV_COLUMNS, plot_title(rep))
    panels = [ax for ax in fig.axes if ax.get_ylabel()]
    assert len(panels) == 6
    for ax in panels:
        got = artists(ax)
        kinds = {g for g, _, _ in got}
        assert set(SPANS) | set(POINTS) | {"violation"} <= kinds, (ax.get_ylabel(), kinds)
        for kind, (t0, t1) in SPANS.items():
            assert any(g == kind and lo == pytest.approx(t0) and hi == pytest.approx(t1) for g, lo, hi in got), kind
        for kind, t in POINTS.items():
            assert any(g == kind and lo == pytest.approx(t) for g, lo, _ in got), kind
    labels = {t.get_text() for leg in fig.legends for t in leg.get_texts()}
    assert {"hold (daemon)", "would hold (shadow)", "calibration hold", "link down", "failsafe", "collision",
            "stand-down (pilot took over)", "failsafe state (link lost)", "violation: controller"} <= labels


def title_inside(fig) -> bool:
    """The title and the legend of marks inside the figure, and the title above every panel."""
    renderer = fig.canvas.get_renderer()
    fig.canvas.draw()
    whole = fig.bbox
    for artist in [fig._suptitle, *fig.legends]:
        box = artist.get_window_extent(renderer)
        if not (box.x0 >= whole.x0 and box.x1 <= whole.x1 and box.y1 <= whole.y1 and box.y0 >= whole.y0):
            return False
    top = max(ax.get_tightbbox(renderer).y1 for ax in fig.axes)
    return fig._suptitle.get_window_extent(renderer).y0 >= top - 1


def test_titles_fit_inside_their_figures(scripted):
    _, rep, samples = scripted
    long = plot_title(rep, "replayed from a-very-long-flight-log-name-of-a-real-team-2026-12-02T18-00-00.tlog")
    assert len(long) > 150  # longer than one line of the figure: main clipped it at both ends
    for make in (rp.time_figure, rp.plan_figure):
        fig = make(rep, samples, CSV_COLUMNS, long)
        assert title_inside(fig), make.__name__
        assert fig._suptitle.get_text().split() == long.split()  # wrapped, nothing dropped


def test_the_plan_view_shows_track_route_obstacles_and_where_things_happened(scripted):
    _, rep, samples = scripted
    fig = rp.plan_figure(rep, samples, CSV_COLUMNS, "plan")
    ax = fig.axes[0]
    by = {}
    for a in [*ax.lines, *ax.patches, *ax.collections]:
        by.setdefault(a.get_gid(), []).append(a)
    track = by["plan:track"][0]
    assert len(track.get_segments()) == 599
    ratio = track.get_array()
    assert ratio.min() == pytest.approx(2.0 / 3.0)  # coloured by speed against the limit (2 of 3 m/s)
    (route,) = by["plan:route"]
    assert list(route.get_xdata()) == [0.0, 120.0] and list(route.get_ydata()) == [0.0, 0.0]
    hits = by["plan:hits"][0]
    # every hit placed along the direction of travel, on the column's near surface (north 0, east ≈ 89.5)
    assert hits.get_xdata() == pytest.approx([89.5] * len(hits.get_xdata())) and set(hits.get_ydata()) == {0.0}
    keep = [c for c in by["plan:keep_out"] if abs(c.center[0] - 90.0) < 0.6]
    assert keep and keep[0].radius == pytest.approx(0.5 + 0.4)
    (closest,) = by["mark:closest"]
    assert closest.get_xdata()[0] == pytest.approx(88.8)  # the last hit, 0.7 m short of the column
    for kind, t in (("hold", 10.0), ("would_hold", 20.0), ("violation", 52.0), ("stand_down", 13.0),
                    ("link_down", 40.0)):
        (line,) = by[f"mark:{kind}"]
        assert 2.0 * t in [pytest.approx(x, abs=0.25) for x in line.get_xdata()], kind
    (col,) = by["mark:collision"]
    assert (col.get_xdata()[0], col.get_ydata()[0]) == (110.0, 1.0)  # where the simulator saw it


def test_one_log_gets_an_html_page_with_both_plots(scripted, tmp_path):
    d, _, _ = scripted
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "companion.cli", "review", str(d / "log"), "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    page = out / "review.html"
    text = page.read_text()
    assert text.count("data:image/png;base64,") == 2 and "Plan view" in text and "REVIEW NEEDED" in text
    assert "wrote html: " + str(page) in r.stdout


@pytest.mark.skipif(not CHROMIUM.exists(), reason="no /usr/bin/chromium (Debian package chromium) for the HTML check")
def test_the_one_log_page_renders_in_headless_chromium(scripted, tmp_path):
    import matplotlib.image as mpimg
    import numpy as np

    d, _, _ = scripted
    out = tmp_path / "out"
    subprocess.run([sys.executable, "-m", "companion.cli", "review", str(d / "log"), "--out", str(out)],
                   capture_output=True, timeout=300, check=True)
    shot = tmp_path / "page.png"
    subprocess.run([str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                    "--disable-background-networking", "--disable-component-update", "--disable-sync",
                    f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}", "--window-size=1280,3000",
                    (out / "review.html").as_uri()], capture_output=True, timeout=120)
    assert shot.exists(), "chromium wrote no screenshot"
    img = mpimg.imread(shot)[..., :3]
    red = (img[..., 0] > 0.55) & (img[..., 1] < 0.2) & (img[..., 2] < 0.2)  # the verdict, the failsafe marks
    # the plan view's track (at 2/3 of the limit) is drawn in its colour, below the findings
    want = np.array(mpl.colormaps["RdYlGn_r"]((2.0 / 3.0) / 1.5)[:3])
    track = np.all(np.abs(img - want) < 0.06, axis=-1)
    assert red.sum() > 50 and track.sum() > 200 and np.nonzero(track)[0].min() > 150


def test_summarise_of_a_link_loss_alone_counts_it():
    """The demo's case: the state went to failsafe, no failsafe event: main said `failsafes: 0`."""
    recs = [{"kind": "event", "t": 0.0, "boot": "b", "event": "state_change", "from": "standby", "to": "failsafe",
             "reason": "no autopilot heartbeat yet"}]  # before the first heartbeat: not a failsafe
    for k in range(3):
        recs += [{"kind": "event", "t": 10.0 * k + 1, "boot": "b", "event": "state_change", "from": "active",
                  "to": "failsafe", "reason": "autopilot heartbeat lost"},
                 {"kind": "event", "t": 10.0 * k + 2, "boot": "b", "event": "state_change", "from": "failsafe",
                  "to": "standby", "reason": "link restored"}]
    rep = summarise(recs)
    assert rep["failsafe_count"] == 3 and "failsafes: 3" in format_report(rep)


def test_a_tlog_names_its_autopilot_family_in_the_index():
    from companion.ground.reviewset import row

    rep = summarise([{"kind": "state", "t": 0.0, "boot": "b", "ground_speed": 0.0}])
    rep["replay"] = {"autopilot": {"kind": "ardupilot", "system": 1, "component": 1, "from": "detected"}}
    assert row(Path("f.tlog"), rep, None)["firmware"] == "ArduPilot"


def test_the_plots_are_drawn_apart_from_the_daemon():
    code = ("import sys, companion.ground.review, companion.onboard.daemon; "
            "assert not [m for m in sys.modules if m.startswith('matplotlib')], 'matplotlib loaded'")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


@pytest.fixture(scope="module")
def governed(tmp_path_factory):
    """A real lock-step governor flight (daemon, SITL, MAVLink bytes): the link drops at 8 s for 3 s (the
    daemon holds, goes to failsafe, holds again), the ground station resumes the mission (a stand-down), and
    the daemon holds before a column at 45 m."""
    from companion.onboard.eventlog import read_events
    from tests.lockstep import Rig
    from tests.test_daemon_lockstep import column_scenario, fly

    d = tmp_path_factory.mktemp("governed")
    log = EventLog(d / "log", commit="none")
    rig = Rig(column_scenario(1, x_col=45.0, cruise=4.0, faults=[{"at_s": 8.0, "link_dropout_s": 3.0}]), "px4",
              log=log)
    fly(rig, 14.0)
    rig.command(176, 1 | 128, 4, 4)  # the ground station: PX4 AUTO.MISSION
    rig.run(25.0)
    log.close()
    records = list(read_events(d / "log" / "events.jsonl"))
    rep, samples = analyse([d / "log" / "events.jsonl"], keep_samples=True)
    return records, rep, samples


def test_a_governed_flights_holds_failsafes_and_stand_down_are_marked_where_the_daemon_logged_them(governed):
    records, rep, samples = governed
    ev = [r for r in records if r.get("kind") == "event"]
    holds = [e["t"] for e in ev if e["event"] == "command" and e.get("cmd") == "hold" and "send" not in e]
    lost = [e["t"] for e in ev if e["event"] == "state_change" and e["to"] == "failsafe"]
    down = [e["t"] for e in ev if e["event"] == "link" and e["status"] == "down"]
    others = [e["t"] for e in ev if e["event"] == "mode_change" and e["by"] == "other" and e["t"] > 12.0]
    assert holds and lost and down and others  # the flight did what the fixture says
    m = rep["marks"]
    starts = [s["start_t"] for s in m["holds"]]
    assert all(any(abs(h - s) < 0.05 for s in starts) for h in holds), (holds, starts)
    assert [s["start_t"] for s in m["failsafe_states"]] == lost and [s["start_t"] for s in m["link_down"]] == down
    assert [p["t"] for p in m["stand_downs"]] == others[:1]
    # main: `failsafes` counted only the failsafe events, not the link loss
    n_events = sum(e["event"] == "failsafe" for e in ev)
    assert rep["failsafe_count"] == n_events + len(lost)
    fig = rp.time_figure(rep, samples, CSV_COLUMNS, plot_title(rep))
    for ax in [a for a in fig.axes if a.get_ylabel()]:
        got = artists(ax)
        for kind, t in [("hold", h) for h in starts] + [("failsafe_state", lost[0]), ("link_down", down[0]),
                                                         ("stand_down", others[0]), ("failsafe", lost[0])]:
            assert any(g == kind and lo == pytest.approx(t) for g, lo, _ in got), (ax.get_ylabel(), kind, t)
    plan = rp.plan_figure(rep, samples, CSV_COLUMNS, "plan").axes[0]
    gids = {a.get_gid() for a in [*plan.lines, *plan.patches]}
    assert {"mark:hold", "mark:failsafe", "mark:link_down", "mark:stand_down", "mark:closest", "plan:keep_out"} <= gids
    # the obstacle is drawn where the column is (north 45 m, on the path), not behind the braking vehicle
    discs = [p for p in plan.patches if p.get_gid() == "plan:obstacle"]
    assert discs and all(abs(p.center[0]) < 0.5 and 44.0 < p.center[1] < 47.0 for p in discs)


# ----------------------------------------------------------------------------- the scenario's world on the plan view

WORLD = {"walls": [{"points": [[-5, 60], [5, 60]], "thickness_m": 0.4, "gaps": [{"at_m": 5, "width_m": 2}]}],
         "clusters": [{"x_m": 8, "y_m": 100, "radius_m": 4, "count": 6, "column_radius_m": [0.2, 0.4],
                       "min_gap_m": 1.0, "seed": 2}],
         "columns": [{"x_m": 0, "y_m": 90, "radius_m": 0.5}]}


def world_artists(rep, samples):
    ax = rp.plan_figure(rep, samples, CSV_COLUMNS, "plan").axes[0]
    return ([p for p in ax.patches if p.get_gid() == "plan:wall"],
            [p for p in ax.patches if p.get_gid() == "plan:column"])


def test_the_plan_view_draws_the_scenarios_walls_and_columns_where_they_are(scripted):
    from companion.ground.review import world_outline
    from sitl_harness.scenario import scenario_from_dict

    _, rep, samples = scripted
    assert world_artists(rep, samples) == ([], [])  # the review without a scenario: nothing drawn
    outline = scenario_from_dict({"world": WORLD}).world.outline()
    walls, columns = world_artists({**rep, "world": world_outline(outline)}, samples)
    assert len(walls) == 2 and len(columns) == 7  # the wall either side of its doorway; the column and the cluster
    east = sorted(p.get_xy()[:, 0].min() for p in walls)
    assert east == pytest.approx([59.8, 59.8])  # east 60 m, 0.4 m thick: drawn east right, north up
    north = sorted((p.get_xy()[:, 1].min(), p.get_xy()[:, 1].max()) for p in walls)
    assert north[0] == pytest.approx((-5.0, -1.0)) and north[1] == pytest.approx((1.0, 5.0))  # the 2 m doorway
    assert columns[0].center == (90.0, 0.0) and columns[0].radius == 0.5  # east 90, north 0
    bad = world_outline({"columns": [[1, 2, float("nan")], ["x", 1, 1]], "polygons": [[[0, 0], [1, 1]]]})
    assert bad == {"columns": [], "polygons": []}  # nothing half-drawn from bad data


def test_review_scenario_draws_its_world_and_a_bad_name_is_one_line(scripted, tmp_path):
    d, _, _ = scripted
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "companion.cli", "review", str(d / "log"), "--out", str(out),
                        "--scenario", "wall_doorway", "--json"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    import json

    world = json.loads((out / "review.json").read_text())["world"]
    assert len(world["polygons"]) == 2 and (out / "plan.png").stat().st_size > 0
    r = subprocess.run([sys.executable, "-m", "companion.cli", "review", str(d / "log"), "--scenario", "no_such"],
                       capture_output=True, text=True)
    assert r.returncode != 0 and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_a_cluttered_lockstep_flight_is_reviewed_over_its_world(tmp_path):
    """A shadow daemon beside the SITL's own mission in the corridor_turn world (a depth camera, OBSTACLE_DISTANCE,
    real MAVLink bytes), reviewed with the scenario: the plan view draws the corridor's five wall pieces beneath a
    track that runs between them round the turn."""
    from companion.ground.review import review
    from sitl_harness.scenario import load_scenario
    from tests.lockstep import Rig
    from tests.test_daemon_lockstep import fly

    sc = load_scenario("corridor_turn")
    log = EventLog(tmp_path / "log", commit="none")
    rig = Rig(sc.model_dump(), "px4", log=log, config={"mode": "shadow"})
    (cam,) = rig.cfg.sensors  # the rig's daemon takes the SITL's sensor as it is: the camera's message and bins
    assert (cam.kind, cam.h_fov_deg, cam.max_range_m) == ("obstacle_distance", 85.0, 10.0)
    fly(rig, 30.0)
    log.close()
    assert rig.truth["collisions"] == [] and rig.truth["pos"][1] > 7.0  # round the turn, touching nothing
    rep = review([tmp_path / "log"], out_dir=tmp_path / "review", world=sc.world.outline())
    assert len(rep["world"]["polygons"]) == 5 and (tmp_path / "review" / "plan.png").stat().st_size > 0
    _, samples = analyse([tmp_path / "log" / "events.jsonl"], keep_samples=True)
    walls, _ = world_artists(rep, samples)
    assert len(walls) == 5
