"""An autopilot's own flight log (PX4 ULog, ArduPilot DataFlash) turned into an event log, as
`companion/ground/flightlogs/tlog.py` does for a `.tlog`: the reader's `Feed` (companion/ground/flightlogs/loginput.py) goes, in log time, to a
shadow-mode `Daemon` stepped at its loop rate with no sleeping — the same daemon, cycle, estimators and
supervisor; only the input differs (the reader's ops become the same `Telemetry` fields and samples
MAVLink-in produces). `companion.ground.flightlogs.READERS` wires `replay_flight_log` into `review`.

The returned `FlightLog` (a `review.Origin`) is the report's `flight_log` section: the vehicle and firmware,
what the log held, lacked (each said once, with what it means for the verdict), spoiled or skipped, and the
autopilot's parameters against the vehicle file.
"""

from __future__ import annotations

import math
from pathlib import Path

from companion.onboard.autopilots import adapter_for
from companion.onboard.config import Config, load_config
from companion.onboard.eventlog import finite_copy, read_events
from companion.onboard.logschema import LOG_FILE
from contracts.errors import ContractError

from ..review import Origin, fmt_value
from .bounds import MAX_SAMPLES, gc_paused
from .flightspan import ARMED, Watch, flight_end, gaps_finding, not_forward_lines
from .loginput import Feed, LogIn
from .tlog import ASSUMED_NOTE, ASSUMED_SENSORS, in_log_time, settle, shadow_daemon, silences, stepped_silence


def tilt_params(autopilot: str) -> dict[str, float]:
    """The autopilot's tilt-limit parameters → their scale to degrees, from its adapter's start-up checks (and
    a quadplane's own VTOL name for ArduPilot's)."""
    from .dataflash import QUADPLANE_PARAMS

    checks = adapter_for(autopilot).param_checks
    tilt = {c.name: c.scale for c in checks if c.what == "tilt_max_deg"}
    return tilt | {q: tilt[c] for q, c in QUADPLANE_PARAMS.items() if c in tilt}


def replay_feed(feed: Feed, cfg: Config, table, log_dir: Path, contract: str, source: str) -> dict:
    """Feed the ops to a shadow `Daemon` in log time; its event log goes to `log_dir`."""
    now = {"t": 0.0}
    wall = lambda: feed.wall0 + now["t"]  # noqa: E731
    daemon, log = shadow_daemon(cfg, table, log_dir, contract, source, lambda: now["t"], wall)
    login = LogIn(cfg, daemon.tel, adapter_for(feed.autopilot).autopilot_id)
    ops, bad = feed.ops, [0]
    watch = Watch(cfg.timeouts.heartbeat_s)  # every op: the autopilot's logger alive (as `LogIn` takes it)

    def take(i: int, t: float) -> None:
        t_log, op, args = ops[i]
        now["t"] = t / 1e6
        watch.stream(now["t"], t_log / 1e6)
        if op == "mode":
            watch.armed(now["t"], bool(int(args[0]) & ARMED))
        try:
            for s in login.apply(now["t"], op, args):
                daemon.take(s)  # the daemon's own routing of MAVLink-in's samples
        except Exception:  # noqa: BLE001 — a sample the estimators refuse: counted, as a bad packet
            bad[0] += 1

    def step(tick: float) -> None:
        now["t"] = tick / 1e6
        daemon.step()

    run = in_log_time([o[0] for o in ops], cfg.loop_hz, take, step, stepped_silence(cfg))
    log.event(now["t"], "stop", counters=daemon.counters.__dict__)
    log.close()
    return {**run, "ops": len(ops), "refused_samples": bad[0], "flight": watch.result(now["t"])}


class FlightLog(Origin):
    """A ULog or DataFlash log replayed: the report's `flight_log` section, its findings and its text."""

    key = "flight_log"

    def findings(self) -> list[str]:
        info, out = self.info, []
        for what, means in info["lacking"].items():
            out.append(f"log lacks {what}: {means}")
        for what in info["damaged"]:
            out.append(f"log damaged: {what}")
        if info.get("dropouts"):
            out.append(f"{info['dropouts']} logging dropout(s) ({info['dropout_s']:.1f} s of data lost)")
        if info["time_jumps"]:
            out.append(f"{len(info['time_jumps'])} clock jump(s) in the log's timestamps closed up")
        if info.get("gaps_skipped"):
            out.append(silences(info))
        gaps = gaps_finding(info.get("flight"), "gaps in the autopilot's log", "nothing logged")
        if gaps:
            out.append(gaps)
        for s in info["slow_streams"]:
            out.append(f"{s['stream']} logged at {s['rate_hz']:.1f} Hz, too slow for the daemon's {s['timeout_s']} s "
                       "staleness limit: stale-data findings may be the log's, not the flight's")
        out += info.get("estimator_notes", [])
        for p in info["param_findings"]:
            out.append(p)
        veh = info["vehicle"]
        if veh.get("vtol") and veh.get("fixed_wing_cut"):
            cuts = veh["fixed_wing_cut"]
            out.append(f"a VTOL ({veh['airframe']}): {sum(c['cut_s'] for c in cuts):.0f} s of fixed-wing flight in "
                       f"{len(cuts)} phase(s) (first at t = {cuts[0]['t']:.1f} s) excluded: this multirotor contract "
                       "does not apply there; the rest of the flight is judged")
        elif veh.get("vtol") and veh.get("fixed_wing_s") is None:
            out.append(f"a VTOL ({veh['airframe']}): the log does not say when it flew as a fixed wing (no MODE "
                       "messages), where this multirotor contract does not apply: findings there are not told apart")
        elif veh.get("vtol") and veh.get("fixed_wing_s") == 0 and veh.get("fixed_wing_from"):
            out.append(f"a VTOL ({veh['airframe']}): no fixed-wing phase in its {veh['fixed_wing_from']}; all of it "
                       "is judged as a multirotor")
        elif veh.get("vtol"):
            out.append(f"a VTOL ({veh['airframe']}): {veh['fixed_wing_s']:.0f} s in fixed-wing flight, where this "
                       "multirotor contract does not apply (the log does not say when, so findings there are not "
                       "told apart)")
        return out

    def lines(self) -> list[str]:
        info, veh, fw = self.info, self.info["vehicle"], self.info["firmware"]
        out = [f"  {info['format']}: vehicle {veh['hardware'] or '?'} ({veh['airframe']}"
               + (f", SYS_AUTOSTART {veh['sys_autostart']}" if veh.get("sys_autostart") else "")
               + f"), firmware {fw['name'] or '?'} {fw['release'] or ''} {('git ' + fw['git'][:10]) if fw.get('git') else ''}".rstrip()
               + f"; samples span {fmt_value(info['span_s'], ' s')}"
               + (f" of a {fmt_value(info['log_duration_s'], ' s')} log" if info.get("log_duration_s") else "")]
        out.append(f"  replayed {info['ops']} samples through {info['table']} ({info['contract']} contract, shadow "
                   f"mode) as vehicle {info['vehicle_file']}; event log: {info['event_log'] or 'not kept'}")
        judged = ", ".join(info["judged"]) or "nothing"
        out.append(f"  judged: {judged}; not judged: {', '.join(info['not_judged']) or 'nothing'}")
        et = info["e_tr"]
        if et["measured_max_m"] is not None and info["sources"].get("target"):
            out.append(f"  E_tr against the commanded path ({info['sources'].get('target')}): max "
                       f"{et['measured_max_m']:.2f} m at t = {et['at_t']:.1f} s (contract used "
                       f"{fmt_value(et['used_at_max_m'], ' m')} there)")
        if info.get("stamped_before_start"):
            out.append(f"  {', '.join(info['stamped_before_start'])}: the logger's first sample predates the log's "
                       "start (its snapshot of the last value): taken as the value at the start")
        return out + not_forward_lines(info.get("other_sensors", []))

    def flight_end(self, daemon_end: dict | None) -> dict | None:
        return flight_end(self.info.get("flight"), daemon_end)

    def title(self) -> str:
        return f"replayed from {Path(self.info['log']).name}"


def _judged(info: dict) -> tuple[list[str], list[str]]:
    lacking = " ".join(info["lacking"])
    judged, not_judged = [], []
    for part, key in (("navigation (D_od)", "obstacle"), ("controller (E_tr)", "commanded path"),
                      ("actuators (thrust_ratio)", "thrust"), ("estimator health", "navigation health"),
                      ("modes", "modes")):
        (not_judged if key in lacking else judged).append(part)
    return judged, not_judged


def _e_tr(log_dir: Path) -> dict:
    worst = {"measured_max_m": None, "at_t": None, "used_at_max_m": None}
    for r in read_events(log_dir / LOG_FILE):
        if r.get("kind") != "state":
            continue
        m = r.get("e_tr_measured")
        if isinstance(m, (int, float)) and math.isfinite(m) and (worst["measured_max_m"] is None or m > worst["measured_max_m"]):
            worst = {"measured_max_m": float(m), "at_t": r.get("t"), "used_at_max_m": r.get("e_tr")}
    return worst


def replay_flight_log(read, path, log_dir: Path, *, config=None, vehicle=None, table=None) -> FlightLog:
    """Replay the log at `path` (read by `read(path) -> Feed`) into an event log in `log_dir`."""
    path = Path(path)
    if not path.exists():
        raise ContractError(f"no such file or directory: {path}")
    if path.is_dir():
        raise ContractError(f"{path} is a directory, not a flight log")
    with gc_paused():
        feed = read(path)
    if len(feed.ops) > MAX_SAMPLES:  # bounded: the first MAX_SAMPLES (in log time) replayed, the rest said
        feed.info["damaged"] = [*feed.info.get("damaged", []), f"more than {MAX_SAMPLES} samples: only the first "
                                f"{MAX_SAMPLES} ({feed.ops[MAX_SAMPLES][0] / 1e6:.0f} s) replayed"]
        feed.ops = feed.ops[:MAX_SAMPLES]
    cfg = load_config(config) if config is not None else Config(sensors=list(ASSUMED_SENSORS))
    if config is None:
        cfg = cfg.model_copy(update={"link": cfg.link.model_copy(update={"autopilot": feed.autopilot})})
    cfg, tab, contract = settle(cfg, config, vehicle, table)
    run = replay_feed(feed, cfg, tab, log_dir, contract, str(path))
    info = dict(feed.info)
    to = cfg.timeouts
    slow = []
    pos_src = info["sources"].get("pos")
    if pos_src and (r := info["rates_hz"].get(pos_src.split(" ")[0], 0.0)) and r < 1.25 / to.telemetry_s:
        slow.append({"stream": pos_src, "rate_hz": r, "timeout_s": to.telemetry_s})
    veh = tab.vehicle
    pf = []
    for name, scale in tilt_params(feed.autopilot).items():
        v = info["params"].get(name)
        if v is not None and v * scale > veh.tilt_max_deg + 1e-6:
            pf.append(f"the autopilot's tilt limit {name} = {v * scale:g}° is above the contract's {veh.tilt_max_deg:g}° "
                      f"(vehicle {veh.name}): the vehicle may tilt beyond what the contract assumes")
    info.update({
        "ops": run["ops"], "steps": run["steps"], "gaps_skipped": run["gaps_skipped"], "skipped_s": run["skipped_s"],
        "refused_samples": run["refused_samples"],
        "config": None if config is None else str(config), "vehicle_file": veh.name, "table": str(tab.path),
        "contract": contract, "loop_hz": cfg.loop_hz, "slow_streams": slow, "param_findings": pf,
        "event_log": None, "e_tr": _e_tr(log_dir), "flight": run["flight"],
        "notes": ["shadow replay: the controller guarantee (contour error vs E_tr_pred at the commanded limit) "
                  "is evaluated only against a commanded limit, so it is not checked here"]
        + ([ASSUMED_NOTE] if config is None else []),
    })
    info["judged"], info["not_judged"] = _judged(info)
    return FlightLog([str(path)], finite_copy(info))
