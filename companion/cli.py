"""`contract-guard`: keeps a multirotor's obstacle avoidance within its contract (PX4, ArduPilot).

Every command that prints results has `--json` (one JSON object on stdout). Errors a person can cause
end with one line on stderr and a non-zero exit status, never a traceback. This module wires the
subcommands; the work lives in `contracts/`, `companion/` and `sitl_harness/`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import signal
import sys
from pathlib import Path

from contracts.errors import ContractError
from contracts.runner import BuildInterrupted

EXIT_USER_ERROR = 2



class Parser(argparse.ArgumentParser):
    """A usage error is one line on stderr and exit status 2 (`--help` shows the usage)."""

    def error(self, message: str):
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message} (see --help)\n")


def finite(text: str) -> float:
    """An argparse type: a finite number (NaN and inf are refused with one line)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"not a finite number: {text!r}")
    return v


def _sensor(text: str):
    """An argparse type: `RANGE_M[,FOV_DEG]` (`companion.detection_need.Sensor`), one line when wrong."""
    from .detection_need import Sensor

    try:
        return Sensor.parse(text)
    except ContractError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _emit(obj: dict, as_json: bool, text: str) -> None:
    """The result on stdout: JSON (its strings escaped by the encoder), or text stripped of control characters."""
    from .flightlogs import for_terminal

    print(json.dumps(obj, sort_keys=True) if as_json else for_terminal(text))


def one_line(record: dict) -> str:
    """A build's record for a person: its scalar figures in one line (the lists and per-solve times are in
    `--json`)."""
    parts = []
    for k, v in record.items():
        if isinstance(v, bool) or not isinstance(v, (int, float, str)) or (isinstance(v, str) and len(v) > 40):
            continue
        parts.append(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}")
    return ", ".join(parts) + " (--json for the full record)"


def need(extra: str, *modules: str) -> None:
    """Before any work starts: the optional packages a command needs, else one line naming the extra."""
    import importlib.util

    missing = [m for m in modules if importlib.util.find_spec(m) is None]
    if missing:
        raise ContractError(f"this needs {', '.join(missing)}: pip install 'contract-guard[{extra}]'")


def table_file(path) -> Path:
    """A table by file or by shipped name: `x500`, `x500.npz` or the documented `contracts/data/x500.npz` from
    any directory (an installed package keeps its tables inside it)."""
    from contracts.table import shipped_table, shipped_vehicles

    p = Path(path)
    if p.exists():
        return p
    name = p.name[:-4] if p.name.endswith(".npz") else p.name
    if name in shipped_vehicles() and (p.parent == Path(".") or p.parent.as_posix().endswith("contracts/data")):
        return shipped_table(name)
    return p


def _load_table(path, vehicle=None, public_key=None):
    """The table at `path` (or a shipped one by name), verified (against `vehicle`, a shipped name or file,
    when given; signed by the private key of `public_key`, a PEM file, when given)."""
    from contracts.table import load_for_vehicle

    return load_for_vehicle(vehicle or None, table_file(path), public_key)


def signature_line(t) -> str:
    """How far a verified table is trusted: its signature's status (`table verify`, `table show`)."""
    s = t.signature
    if s["verified"]:
        return f"signed, signature verified with public key {s['key_id']}"
    if s["signed"]:
        return f"signed by key {s['key_id']}, signature not checked (no --public-key): integrity only"
    return "unsigned: integrity only"


# ----------------------------------------------------------------------------- table


def cmd_table_show(args) -> int:
    t = _load_table(args.file, public_key=args.public_key)
    m = t.meta
    lines = [
        f"table {args.file}: vehicle {m['vehicle']['name']}, tilt model {m['tilt_model']}, "
        f"contracts {', '.join(t.available)}",
        f"  schema {m['schema']} v{m['schema_version']}, package {m['package_version']}, created {m['created_utc']}",
    ]
    if m.get("note"):
        lines.append(f"  note: {m['note']}")
    lines.append(f"  signature: {signature_line(t)}")
    m = {**m, "signature": t.signature}
    lines.append("  controller contract (E_tr_pred): " + ("yes" if t.e_pred is not None else
                 "NONE — E_tr is the measured value only; the daemon refuses to engage with this table unless "
                 "the config states contract.e_tr_assumed_m (build it: contract-guard table etr)"))
    from .console import controller_coverage

    lines.append(f"  controller contract coverage: {controller_coverage(t)}")
    from contracts.calibrate import table_evidence

    lines += table_evidence(t)
    m = {**m, "controller_contract": t.e_pred is not None, "controller_coverage": controller_coverage(t)}
    for slot_name, slot in (("avoid", t.avoid), ("e_tr_pred", t.e_pred)):
        if slot is not None:
            for info, ax in zip(m["axes"][slot_name], slot.axes):
                lines.append(f"  {slot_name}.{info['name']}: {len(ax)} points {ax[0]:.4g} … {ax[-1]:.4g} {info['unit']}")
    _emit(m, args.json, "\n".join(lines))
    return 0


def cmd_table_verify(args) -> int:
    t = _load_table(args.file, args.vehicle, args.public_key)
    _emit(
        {"ok": True, "file": str(args.file), "available": t.available, "vehicle": t.vehicle.name,
         "signature": t.signature},
        args.json,
        f"ok: {args.file} verifies (vehicle {t.vehicle.name}; contracts {', '.join(t.available)}); {signature_line(t)}",
    )
    return 0


def cmd_table_sign(args) -> int:
    from contracts.table import sign_table

    sig = sign_table(table_file(args.file), args.key, args.out)
    _emit({"ok": True, "file": str(args.out or args.file), **sig}, args.json,
          f"signed {args.out or args.file} with key {sig['key_id']} (ed25519; check: contract-guard table verify "
          f"{args.out or args.file} --public-key PUBLIC.pem)")
    return 0


def _sign_after(path, key) -> str:
    """`--sign-key` of a command that writes a table: sign it; the text that says so ('' without a key)."""
    if key is None:
        return ""
    from contracts.table import sign_table

    return f"; signed with key {sign_table(path, key)['key_id']}"


def query_table(t, d_od, r_obst, e_tr, thrust_ratio, tilt_deg=None, v_max=None, contract=None) -> dict:
    """The answer of `table query` as a dict (SI units; degrees where the name says so)."""
    contract = contract or ("avoid" if t.avoid is not None else "stop")
    tilt = None if tilt_deg is None else math.radians(tilt_deg)
    om = t.omega(d_od, r_obst, e_tr, thrust_ratio, contract=contract, tilt=tilt)
    out = {
        "contract": contract,
        "available": t.available,
        "d_od": d_od,
        "r_obst": r_obst,
        "e_tr_measured": e_tr,
        "thrust_ratio": thrust_ratio,
        "v_max": om.v_max,
        "tilt_deg": math.degrees(om.tilt),
        "e_tr": om.e_tr,
        "v_safe": om.v_safe,
        "gamma": om.gamma,
        "v_stop": t.v_stop(d_od, r_obst, om.e_tr if math.isfinite(om.e_tr) else e_tr, thrust_ratio, tilt),
        "reason": om.reason,
    }
    if v_max is not None:  # Γ at a proposed speed instead of the chosen one
        out["v_max"] = v_max
        out["gamma"] = t.gamma(v_max, d_od, r_obst, e_tr, thrust_ratio, om.tilt, contract)
        out["v_safe"] = v_max - out["gamma"]
    return out


def cmd_table_query(args) -> int:
    t = _load_table(args.file, args.vehicle)
    if args.contract == "avoid" and t.avoid is None:
        raise ContractError(f"table {args.file} carries no avoid contract (stop contract only)")
    q = query_table(t, args.d_od, args.r_obst, args.e_tr, args.thrust_ratio, args.tilt_deg, args.v_max, args.contract)
    text = (
        f"{q['contract']} contract: V_max {q['v_max']:.3f} m/s at tilt {q['tilt_deg']:.2f}°, "
        f"E_tr {q['e_tr']:.3f} m, V_safe {q['v_safe']:.3f} m/s, Γ {q['gamma']:+.3f}; "
        f"stop-contract speed {q['v_stop']:.3f} m/s ({q['reason']})"
    )
    q["controller_contract"] = t.e_pred is not None
    if t.e_pred is None:
        text += ("\n  no controller contract (E_tr_pred) in this table: E_tr is the --e-tr given, never the "
                 "prediction at V_max (the daemon refuses to engage unless contract.e_tr_assumed_m is stated)")
    _emit(q, args.json, text)
    return 0


@contextlib.contextmanager
def _interruptible():
    """SIGTERM (systemd, `kill`, a CI timeout) stops a long build as Ctrl-C does: the workers are stopped
    and the checkpoint is kept (`contracts.runner.run_tasks`)."""
    def _term(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, _term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def cmd_table_build(args) -> int:
    if not getattr(args, "stop_only", False):
        need("build", "casadi")
    from contracts.table import write_table
    from contracts.vehicle import load_vehicle

    vehicle = load_vehicle(args.vehicle)
    if args.stop_only:
        meta = write_table(args.out, vehicle, tilt_model=args.tilt_model)
        signed = _sign_after(args.out, args.sign_key)
        _emit({"ok": True, "out": str(args.out), "available": meta["available"]}, args.json,
              f"wrote {args.out} ({meta['note']}){signed}")
        return 0
    from contracts.runner import show_progress
    from contracts.sweep import build_avoid_table  # offline only: imports CasADi

    with _interruptible():
        summary = build_avoid_table(vehicle, args.out, grid=args.grid, workers=args.workers, scheduler=args.scheduler,
                                    tilt_model=args.tilt_model or vehicle.tilt_model,
                                    progress=show_progress(not args.json), resume=args.resume,
                                    partial_grid=args.partial_grid)
    for gap in summary["coverage_gaps"]:
        print(f"contract-guard: warning: the grid does not cover the vehicle: {gap}", file=sys.stderr)
    signed = _sign_after(args.out, args.sign_key)
    _emit({"ok": True, "out": str(args.out), **summary}, args.json, f"wrote {args.out}: {one_line(summary)}{signed}")
    return 0


def cmd_table_etr(args) -> int:
    """The controller contract E_tr_pred (Figure 12) from SITL flights, written into the table."""
    from contracts.runner import show_progress
    from sitl_harness.etr_sweep import build_etr  # offline: flies the SITL

    from contracts.vehicle import DATA_DIR

    table = table_file(args.table)
    if table.resolve().parent == DATA_DIR and args.out is None:
        raise ContractError(f"table etr: {args.table} is a shipped table; give --out for the result (shipped tables "
                            "are not rewritten in place)")
    with _interruptible():
        s = build_etr(table, args.vehicle, grid=args.grid, workers=args.workers, scheduler=args.scheduler,
                      progress=show_progress(not args.json), out=args.out, resume=args.resume)
    resumed = f", {s['resumed_cells']} from the checkpoint" if s["resumed_cells"] else ""
    signed = _sign_after(s["path"], args.sign_key)
    _emit({"ok": True, **s}, args.json, f"wrote E_tr_pred into {s['path']}: {s['cells']} cells in {s['wall_s']} s"
          f"{resumed}, {s['monotone_repairs_up']} repaired upward, worst raw contour error "
          f"{s['raw_worst_max_m']:.3f} m (--json for the full record){signed}")
    return 0


def cmd_figures(args) -> int:
    """Figure 12 and the demonstration flights of Figures 14-16 (PNG + CSV)."""
    need("build", "matplotlib")
    from sitl_harness.figures import make_figures

    from contracts.table import shipped_table

    t = _load_table(args.table or shipped_table("mambo"))
    r = make_figures(t, args.out, seeds=tuple(range(args.seeds)))
    rows = [f for f in r["flights"] if f["seed"] == 0]
    text = "\n".join([f"wrote {len(r['files'])} files to {args.out}"] + [
        f"{f['name']:16} {f['variant']:12} tilt {f['tilt_deg']:5.2f}° V_max {f['v_max']:.2f} m/s (flown "
        f"{f['v_flown']:.2f}) E_tr {f['e_tr']:.2f} m clearance {f['min_clearance']:+.3f} m "
        f"contour {f['contour_max']:.3f} m{' TOUCHED' if f['touched'] else ''}" for f in rows])
    _emit(r, args.json, text)
    return 0


def cmd_table_compare(args) -> int:
    """Analytical (collision sets, eq. 20-28) vs numerical contract: Figures 4, 6, 7 and the CSV."""
    need("build", "matplotlib")
    from contracts.collision_compare import compare  # offline only: the numerical curve imports CasADi

    s = compare(args.vehicle, args.tilt_deg, args.out, args.tilt_model, ts=args.ts, placement=args.placement,
                d_od_step=args.d_od_step)
    s.pop("rows", None)
    _emit(s, args.json, "\n".join(f"wrote {f}" for f in s.get("files", [])))
    return 0


def cmd_table_plot(args) -> int:
    need("plot", "matplotlib")
    from contracts.avoid_plot import plot_table

    files = plot_table(args.file, args.out)
    _emit({"ok": True, "files": [str(f) for f in files]}, args.json, "\n".join(f"wrote {f}" for f in files))
    return 0


# ----------------------------------------------------------------------------- run


def run_config(args):
    """`run`'s config: the file, with the command line's overrides applied to what the file states (only
    the keys it sets, so a default never counts as stated: `route.altitude_m` with `source: mission`)."""
    from .config import config_from_dict, load_config

    cfg = load_config(args.config)
    if not (args.mode or args.connect or args.log_dir):
        return cfg
    data = cfg.model_dump(mode="json", exclude_unset=True)
    if args.mode:
        data["mode"] = args.mode
    if args.connect:
        data.setdefault("link", {})["connect"] = args.connect
    if args.log_dir:
        data.setdefault("log", {})["dir"] = args.log_dir
    return config_from_dict(data, f"config {args.config} with the command line's overrides")


def cmd_run(args) -> int:
    """The daemon (what systemd starts)."""
    import signal

    from contracts.table import load_for_vehicle

    from .config import weakened
    from .console import ConsoleLog, banner
    from .cycle import controller_contract
    from .daemon import Daemon
    from .eventlog import EventLog
    from .link import SigningClock, load_signing_key, open_connection, setup_signing
    from .service import Notifier

    import faulthandler

    cfg = run_config(args)
    table = load_for_vehicle(cfg.vehicle, cfg.table, cfg.table_public_key)
    if cfg.daemon_mode.contract == "avoid" and table.avoid is None:
        raise ContractError(f"mode {cfg.mode} needs an avoid contract; table {table.path} carries the stop "
                            "contract only")
    if args.check:
        for line in banner(cfg, table, controller_contract(cfg, table)):
            if not line.startswith("waiting for the autopilot"):  # it is not waited for
                print(line)
        for line in weakened(cfg):
            print(line)
        print(f"config {args.config}: valid; its table fits (--check: the link is not opened)")
        return 0
    faulthandler.enable()  # a watchdog abort prints the stack to the journal
    signing_clock = None
    key = load_signing_key(cfg.link.signing_key_file) if cfg.link.signing_key_file else None
    conn = open_connection(cfg.link.connect, cfg.link.baud, cfg.link.target_system, cfg.link.component_id,
                           (cfg.link.target_system, cfg.link.target_component), cfg.link.pins(cfg.sensors))
    if key is not None:
        signing_clock = SigningClock(cfg.link.signing_timestamp_file)
        setup_signing(conn, key, signing_clock)
    log = ConsoleLog(EventLog(cfg.log.dir, max_bytes=cfg.log.max_bytes, keep=cfg.log.keep, tlog=cfg.log.tlog,
                              commit="cycle"),
                     quiet=args.quiet)
    for line in banner(cfg, table, controller_contract(cfg, table)):
        log.say(line)
    for line in weakened(cfg):  # inside its safe range but weaker than the default; unsigned on a network
        log.say(line, 4)
    stop = {"now": False}

    def _stop(signum, frame):
        stop["now"] = True
        stop["signal"] = signal.Signals(signum).name

    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):  # every polite signal takes the shutdown path
        signal.signal(sig, _stop)
    daemon = Daemon(cfg, table, conn, log, signing_clock=signing_clock)
    notifier = Notifier()
    log.event(None, "start", mode=cfg.mode, vehicle=table.vehicle.name, table=str(table.path), connect=cfg.link.connect,
              controller_contract=controller_contract(cfg, table), nav_margin=cfg.contract.nav_margin,
              delivery=cfg.delivery.model_dump())
    notifier.ready(f"{cfg.mode} mode on {cfg.link.connect}")

    def should_stop() -> bool:  # said once, before the shutdown's own Hold (stop means stop: daemon.py)
        if stop["now"] and "said" not in stop:
            stop["said"] = True
            log.say(f"stopping ({stop['signal']})", 5)
            notifier.stopping()
        return stop["now"]

    try:
        daemon.run(should_stop, notifier)
    finally:
        if "said" not in stop:
            log.say("stopping (loop ended)", 5)
            notifier.stopping()
        daemon.finish()
        log.event(None, "stop", counters=daemon.counters.__dict__)
        log.close()
        log.say(log.summary(daemon.counters))
    return 0


# ----------------------------------------------------------------------------- review


# raw-log suffix → its reader (a MAVLink .tlog, a PX4 ULog, an ArduPilot DataFlash log): the one registry of them
from .flightlogs import READERS  # noqa: E402


def raw_log_of(paths) -> Path | None:
    """The one raw log among `paths`, if any (it is replayed, not read)."""
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    raw = [Path(p) for p in paths if Path(p).suffix.lower() in READERS]
    if raw and len(paths) > 1:
        raise ContractError(f"{raw[0]}: a {raw[0].suffix.lower()} is replayed on its own; review it without other logs")
    return raw[0] if raw else None


def review_log(paths, out_dir=None, *, config=None, vehicle=None, table=None, gap_s: float = 1.0,
               tolerance_m_s: float = 0.2, sensor=None):
    """(report, origin) for event logs, or for one raw log replayed into an event log first (`origin`
    says what it was made from; None for an event log). `config`, `vehicle`, `table`: for the replay."""
    import shutil
    import tempfile

    from .flightlogs import check_file, guarded, replay_log
    from .logschema import LOG_FILE, REPLAY_LOG_FILE
    from .review import review

    raw = raw_log_of(paths)
    if raw is None:
        if config or vehicle or table:
            raise ContractError(f"--config, --vehicle and --table apply only to a {' or '.join(READERS)} "
                                "(an event log carries its values)")
        files = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
        from .eventlog import file_set

        for p in files:
            for f in file_set(p) if p.is_dir() else [p]:
                check_file(f, "an event log")
        return guarded(files[0], "event log", review, paths, out_dir, gap_s=gap_s, tolerance_m_s=tolerance_m_s,
                       sensor=sensor), None
    with tempfile.TemporaryDirectory(prefix="contract-guard-replay-", ignore_cleanup_errors=True) as work:
        log = Path(work) / LOG_FILE
        origin = replay_log(raw, Path(work), config=config, vehicle=vehicle, table=table)
        if out_dir is not None:
            kept = Path(out_dir) / REPLAY_LOG_FILE
            try:
                kept.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(log, kept)
            except OSError as err:
                raise ContractError(f"cannot write the review to {out_dir}: {err.strerror or err}") from err
            origin.info["event_log"] = str(kept)
        rep = review(log, out_dir, gap_s=gap_s, tolerance_m_s=tolerance_m_s, origin=origin, sensor=sensor)
    return rep, origin


def cmd_review(args) -> int:
    """Event logs are reviewed; a raw log is replayed into an event log, then reviewed (`READERS`)."""
    from .review import format_report
    from .reviewset import expand, review_set, summary_lines

    from .eventlog import file_set

    # many flights (several raw logs, or folders of them, and no event log among them): one table, each reviewed
    event_logs = any(file_set(p) if p.is_dir() else p.suffix.lower() not in READERS for p in map(Path, args.log))
    raw = [] if event_logs else expand(args.log, READERS)
    if len(raw) > 1 or (raw and any(Path(p).is_dir() for p in args.log)):
        result, texts = review_set(args.log, READERS, lambda path, out: review_log(
            path, out, config=args.config, vehicle=args.vehicle, table=args.table, sensor=args.assume_sensor),
            args.out)
        text = "\n".join(summary_lines(result) + [""] + texts
                          + [f"  wrote {k}: {v}" for k, v in result.get("outputs", {}).items()])
        _emit(result, args.json, text)
        return 0 if result["ok"] or not args.strict else 1
    rep, origin = review_log(args.log, args.out, config=args.config, vehicle=args.vehicle, table=args.table,
                             sensor=args.assume_sensor)
    _emit(rep, args.json, format_report(rep, origin))
    return 0 if rep["ok"] or not args.strict else 1


# ----------------------------------------------------------------------------- demo


def demo(scenario: str = "fig17", out: Path = Path("demo-out"), **kw) -> dict:
    """`companion.demo.run_demo` of a scenario by name or path (the harness is wired in here only)."""
    from sitl_harness.scenario import load_scenario, resolve_scenario_path

    from .demo import run_demo

    return run_demo(load_scenario(scenario), resolve_scenario_path(scenario), out, **kw)


def cmd_demo(args) -> int:
    """The SITL and the daemon on loopback UDP flying the paper's in-flight scenario (Figure 17)."""
    from .demo import format_summary

    r = demo(args.scenario, args.out, speedup=args.speedup, duration_s=args.duration, personality=args.personality)
    _emit(r, args.json, format_summary(r))
    return 0 if r["verdict"] == "SAFE" else 1


# ----------------------------------------------------------------------------- campaign


def cmd_campaign(args) -> int:
    """Monte Carlo lock-step flights over a scenario distribution, baselines and controls; the report."""
    from . import campaign as cg

    spec = cg.load_spec(args.spec)
    if args.fly is not None:  # re-fly one flight, deterministic from (seed, index)
        row, rig = cg.fly(spec, args.fly, keep_rig=True)
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            log = args.out / f"flight-{args.fly}.jsonl"
            with open(log, "w") as f:
                for rec in sorted(rig.log.states + rig.log.events, key=lambda r: r["t"]):
                    f.write(json.dumps(cg._plain(rec), sort_keys=True) + "\n")
            row["log"] = str(log)
        text = (f"flight {row['index']} ({row['arm']}, {row['vehicle']}, {row['personality']}): "
                f"collided {row['collided']}, min clearance {row['min_clearance_m']}, mean speed "
                f"{row['mean_speed_m_s']:.2f} m/s, route completed {row['route_completed']}, "
                f"faults {[(f['kind'], f['subsystem'], f['latency_s']) for f in row['fault_outcomes']]}")
        _emit(cg._plain(row), args.json, text)
        return 0
    if args.out is None:
        raise ContractError("campaign: --out DIR is required (results.jsonl and the report go there)")
    from .campaign_report import format_summary, write_report

    if not args.report_only:
        with _interruptible():
            rows = cg.run(spec, args.out, workers=args.workers, scheduler=args.scheduler,
                          progress=not args.no_progress and not args.json, spec_path=str(args.spec), limit=args.limit)
    else:
        rows = cg.read_rows(args.out)
    summary = write_report(rows, args.out, spec_path=str(args.spec))
    _emit(summary, args.json, format_summary(summary) + f"\nreport: {args.out / 'report.html'}")
    return 0


# ----------------------------------------------------------------------------- calibrate


def cmd_calibrate_plan(args) -> int:
    from contracts.table import load_for_vehicle
    from contracts.vehicle import load_vehicle

    from .calibrate_plan import speed_ladder, write_plan_files

    veh = load_vehicle(args.vehicle)
    try:
        grid = load_for_vehicle(veh, table_file(args.table) if args.table else None).e_pred
    except ContractError:
        grid = None
    v_top = args.v_top or (float(grid.axes[0][-1]) if grid is not None else 8.0)
    speeds = speed_ladder(v_top, grid.axes[0] if grid is not None else None)
    info = write_plan_files(veh, args.out, speeds, args.altitude)
    _emit(info, args.json, f"calibration plan for {veh.name}: {info['legs']} legs ({info['hold_legs']} hold legs the "
          f"daemon or the operator commands), speeds {', '.join(f'{v:g}' for v in speeds)} m/s at {args.altitude:g} m\n"
          f"  {info['plan']}\n  {info['waypoints']}\n  {info['legs_file']}")
    return 0


def cmd_calibrate(args) -> int:
    from contracts.vehicle import load_vehicle

    from .calibrate import calibrate, format_summary

    veh = load_vehicle(args.vehicle)
    table = _load_table(args.table, args.vehicle)
    logs = [p for x in args.log for p in (sorted(q for q in x.rglob("*") if q.suffix.lower() in (".tlog", ".ulg", ".bin"))
                                           if x.is_dir() else [x])]
    if not logs:
        raise ContractError("no flight logs (.tlog, .ulg, .bin) given")
    try:
        s = calibrate(logs, veh, table, args.out, quantile=args.quantile, confidence=args.confidence,
                      accept_faster=args.accept_faster)
        signed = _sign_after(args.out, args.sign_key)
    except OSError as err:  # a full disk, a read-only folder: one line, not a traceback
        raise ContractError(f"cannot write the calibration to {args.out}: {err.strerror or err}") from None
    _emit(s, args.json, format_summary(s) + signed.replace("; s", "\n  s") + f"\nreport: {args.out.with_suffix('')}.report.html")
    return 0


# ----------------------------------------------------------------------------- keys


def cmd_keys(args) -> int:
    from .keys import describe, mavlink_key, table_key_pair

    if args.table:
        k = table_key_pair(args.dir)
        _emit(k, args.json, f"{'created' if k['created'] else 'found'} table signing key {k['key_id']}: sign with "
              f"--sign-key {k['private_key']} (keep it off the aircraft); the daemon's config: table_public_key: "
              f"{k['public_key']}")
        return 0
    k = mavlink_key(args.dir, args.passphrase)
    _emit(k, args.json, describe(k))
    return 0


# ----------------------------------------------------------------------------- parser


def _command(sub, name: str, help: str | None = None, **kw) -> argparse.ArgumentParser:
    """A subcommand whose own `--help` page opens with what it does (its line in the command list; no
    `help`: not listed, as `calibrate-plan`, which is spelled `calibrate plan`)."""
    kw.setdefault("description", help)
    return sub.add_parser(name, **({"help": help} if help else {}), **kw)


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="contract-guard", description=__doc__.splitlines()[0],
               epilog="`contract-guard COMMAND --help` describes each command and its options.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    JSON = "print the result as one JSON object on stdout"

    d = _command(sub, "demo", help="fly the paper's in-flight scenario: SITL + daemon on loopback UDP")
    d.add_argument("--scenario", default="fig17", help="scenario name or file (default: fig17)")
    d.add_argument("--out", type=Path, default=Path("demo-out"), help="event log, plot and summary go here")
    d.add_argument("--speedup", type=finite, default=1.0,
                   help="simulated seconds per wall-clock second (default 1: real time, the daemon's timing budget "
                        "as on an aircraft; at K the host's lateness counts K times)")
    d.add_argument("--duration", type=finite, default=75.0, help="simulated seconds")
    d.add_argument("--personality", choices=["px4", "ardupilot"], default="px4",
                   help="which autopilot the SITL behaves like (default px4)")
    d.add_argument("--json", action="store_true", help=JSON)
    d.set_defaults(func=cmd_demo)

    # `sitl` hands its arguments to the harness's own parser (see main)
    _command(sub, "sitl", help="the SITL vehicle alone, for any MAVLink client: [--scenario NAME|FILE] "
                   "--personality px4|ardupilot --listen udp:127.0.0.1:PORT [--speedup K] (an empty world by "
                   "default; `sitl --help` names the shipped scenarios)", add_help=False)

    r = _command(sub, "run", help="the on-board daemon (what systemd starts): connects to the autopilot, holds its "
                 "speed within the contract in shadow, governor or offboard mode, and writes the event log")
    r.add_argument("--config", required=True, type=Path,
                   help="the daemon's YAML config (relative paths in it are relative to its directory)")
    r.add_argument("--connect", help="override link.connect (pymavlink URL)")
    r.add_argument("--log-dir", help="override log.dir")
    r.add_argument("--mode", choices=["shadow", "governor", "offboard"], help="override mode")
    r.add_argument("--quiet", action="store_true", help="print nothing (the event log still has everything)")
    r.add_argument("--check", action="store_true", help="validate the config, its vehicle and table, print the "
                   "start banner and exit (the link is not opened)")
    r.set_defaults(func=cmd_run)

    rv = _command(sub, "review", help="contract-violation report for a flight's event log, or for raw flight logs "
                        "(.tlog, PX4 .ulg, ArduPilot .bin) replayed through the contract")
    rv.add_argument("log", nargs="+", type=Path,
                    help="log directory (its rotated set), events*.jsonl files, or raw flight logs to replay "
                    "(.tlog, .ulg, .bin; several files or folders: a summary table and one report each)")
    rv.add_argument("--config", type=Path, help="raw log: the daemon config the flight used (sensors, r_obst, vehicle, "
                    "autopilot ids; replayed in shadow mode). Default: built-in defaults, autopilot from the tlog")
    rv.add_argument("--vehicle", help="raw log: vehicle file or shipped name (overrides the config's)")
    rv.add_argument("--table", type=Path,
                    help="raw log: Γ table (default: the config's, else the vehicle's shipped one)")
    rv.add_argument("--out", type=Path, help="write review.html, plan.png, review.png, samples.csv and review.json here "
                    "(and, for a raw log, the replayed event log replay-events.jsonl; for several, index.html and a page each)")
    rv.add_argument("--assume-sensor", metavar="RANGE_M[,FOV_DEG]", type=_sensor,
                    help="a log without obstacle data: the speed limits a forward sensor of this range (and field "
                    "of view) would have set, and the time they would have cost (e.g. 10,60)")
    rv.add_argument("--strict", action="store_true", help="exit 1 when the report has findings")
    rv.add_argument("--json", action="store_true", help=JSON)
    rv.set_defaults(func=cmd_review)

    t = _command(sub, "table", help="build, inspect, query, verify and plot Γ tables (the contract of one vehicle)")
    tsub = t.add_subparsers(dest="table_command", required=True)

    s = _command(tsub, "show", help="print a table's metadata")
    s.add_argument("file", type=Path, help="table file (.npz)")
    s.add_argument("--public-key", type=Path, help="the table must be signed by this key's private key (PEM)")
    s.add_argument("--json", action="store_true", help=JSON)
    s.set_defaults(func=cmd_table_show)

    v = _command(tsub, "verify", help="check a table (schema, hash, monotonicity, vehicle; signature with --public-key)")
    v.add_argument("file", type=Path, help="table file (.npz)")
    v.add_argument("--vehicle", help="vehicle file or shipped name the table must match")
    v.add_argument("--public-key", type=Path, help="the table must be signed by this key's private key (PEM)")
    v.add_argument("--json", action="store_true", help=JSON)
    v.set_defaults(func=cmd_table_verify)

    sg = _command(tsub, "sign", help="sign a table (ed25519 over its arrays and metadata; `keys --table` makes a key)")
    sg.add_argument("file", type=Path, help="table file (.npz)")
    sg.add_argument("--key", type=Path, required=True, help="ed25519 private key (PEM)")
    sg.add_argument("--out", type=Path, help="write the signed table here instead of in place")
    sg.add_argument("--json", action="store_true", help=JSON)
    sg.set_defaults(func=cmd_table_sign)

    q = _command(tsub, "query", help="answer one query: Ω, V_safe, Γ and the stop-contract speed")
    q.add_argument("file", type=Path, help="table file (.npz)")
    q.add_argument("--d-od", type=finite, required=True, help="obstacle detection range [m]")
    q.add_argument("--r-obst", type=finite, required=True, help="expected obstacle radius [m]")
    q.add_argument("--e-tr", type=finite, required=True, help="measured tracking (contour) error [m]")
    q.add_argument("--thrust-ratio", type=finite, required=True, help="T_max / T_nom")
    q.add_argument("--tilt-deg", type=finite, help="fix the tilt limit [deg] (default: the contract chooses)")
    q.add_argument("--v-max", type=finite, help="evaluate Γ at this speed [m/s] instead of the chosen one")
    q.add_argument("--contract", choices=["avoid", "stop"], help="default: avoid if the table has it")
    q.add_argument("--vehicle", help="vehicle file or shipped name the table must match")
    q.add_argument("--json", action="store_true", help=JSON)
    q.set_defaults(func=cmd_table_query)

    b = _command(tsub, "build", help="build a Γ table for a vehicle: the stop contract (closed form, about a second) "
                 "and, unless "
                 "--stop-only, the avoid contract's sweep over ρ, tilt and thrust ratio (IPOPT via CasADi)")
    b.add_argument("--vehicle", required=True, help="vehicle file or shipped name")
    b.add_argument("--out", type=Path, required=True, help="the table file to write (.npz)")
    b.add_argument("--stop-only", action="store_true", help="carry the stop contract only (no sweep)")
    b.add_argument("--grid", type=Path, help="grid YAML (default: the vehicle's shipped grid)")
    b.add_argument("--workers", type=int, default=2, help="local process pool size")
    b.add_argument("--scheduler", help="Dask distributed scheduler address, e.g. tcp://host:8786")
    b.add_argument("--tilt-model", choices=["cone", "box"], default=None,
                   help="how the autopilot limits tilt: total tilt (cone) or roll and pitch apart (box); "
                   "default: the vehicle file's tilt_model")
    b.add_argument("--partial-grid", action="store_true",
                   help="build even when the grid does not cover the vehicle's thrust_ratio_range and tilt limit "
                   "(warns; below the grid's lowest thrust ratio the daemon finds no safe speed)")
    b.add_argument("--resume", action="store_true",
                   help="continue an interrupted build from its checkpoint (OUT.partial/, kept until the table is written)")
    b.add_argument("--sign-key", type=Path, help="sign the table with this ed25519 private key (PEM)")
    b.add_argument("--json", action="store_true", help=JSON)
    b.set_defaults(func=cmd_table_build)

    e = _command(tsub, "etr", help="fly the SITL and write the controller contract E_tr_pred (Figure 12) into a table")
    e.add_argument("--table", type=Path, required=True, help="table with an avoid slot (updated in place unless --out)")
    e.add_argument("--vehicle", help="vehicle file or shipped name the table must match")
    e.add_argument("--out", type=Path, help="write the result here instead of in place")
    e.add_argument("--grid", type=Path, help="E_tr grid YAML: v_max, tilt_deg, thrust_ratio, rhos, seeds "
                   "(default: the vehicle's shipped grid, about 15 min on two cores)")
    e.add_argument("--resume", action="store_true",
                   help="continue an interrupted sweep from its checkpoint (DEST.partial/, kept until the table is written)")
    e.add_argument("--workers", type=int, default=2, help="local process pool size")
    e.add_argument("--sign-key", type=Path, help="sign the result with this ed25519 private key (PEM)")
    e.add_argument("--scheduler", help="Dask distributed scheduler address, e.g. tcp://host:8786")
    e.add_argument("--json", action="store_true", help=JSON)
    e.set_defaults(func=cmd_table_etr)

    fg = _command(sub, "figures", help="Figure 12 and the demonstration flights of Figures 14-16, PNG + CSV")
    fg.add_argument("--out", type=Path, required=True, help="directory for the PNG and CSV files")
    fg.add_argument("--table", type=Path, help="table file (default: the shipped Mambo table)")
    fg.add_argument("--seeds", type=int, default=3, help="wind seeds per flight")
    fg.add_argument("--json", action="store_true", help=JSON)
    fg.set_defaults(func=cmd_figures)

    cp = _command(tsub, "compare", help="analytical vs numerical contract (Figures 4, 6, 7), PNG + CSV")
    cp.add_argument("--vehicle", default="mambo", help="vehicle file or shipped name (default mambo)")
    cp.add_argument("--tilt-deg", type=finite, default=5.0, help="tilt limit of the comparison [deg] (default 5)")
    cp.add_argument("--out", type=Path, required=True, help="directory for the PNG and CSV files")
    cp.add_argument("--tilt-model", choices=["box", "cone"], default="box",
                    help="tilt limit as roll and pitch apart (box, the paper's) or total tilt (cone)")
    cp.add_argument("--placement", choices=["face", "concentric"], default="face",
                    help="squares' near faces at D_od (face) or centred on the circle (concentric, Figure 5)")
    cp.add_argument("--ts", type=finite, default=0.02, help="sample time of the collision sets [s]")
    cp.add_argument("--d-od-step", type=finite, default=0.5, help="step of the detection-range axis [m] (default 0.5)")
    cp.add_argument("--json", action="store_true", help=JSON)
    cp.set_defaults(func=cmd_table_compare)

    cg = _command(sub, "campaign", help="Monte Carlo lock-step flights over a scenario distribution, with the "
                        "PX4/ArduPilot laws as baselines and negative controls, on a pool or a Dask cluster; report")
    cg.add_argument("spec", type=Path, help="campaign spec (YAML)")
    cg.add_argument("--out", type=Path, help="results.jsonl and the report (an interrupted campaign resumes here)")
    cg.add_argument("--workers", type=int, default=1, help="local process pool size (default 1: in-process)")
    cg.add_argument("--scheduler", help="Dask distributed scheduler address, e.g. tcp://host:8786")
    cg.add_argument("--fly", type=int, metavar="INDEX", help="re-fly one flight (with --out: its event log too)")
    cg.add_argument("--limit", type=int, help="fly at most this many more flights, then report")
    cg.add_argument("--report-only", action="store_true", help="report the results already in --out")
    cg.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    cg.add_argument("--json", action="store_true", help=JSON)
    cg.set_defaults(func=cmd_campaign)

    ca = _command(sub, "calibrate", help="calibrate the controller contract and braking from flight logs "
                        "(`calibrate plan` writes the calibration flight plan)")
    ca.add_argument("log", nargs="+", type=Path, help="flight logs (.tlog, .ulg, .bin) or folders of them")
    ca.add_argument("--vehicle", required=True, help="vehicle file or shipped name")
    ca.add_argument("--table", type=Path, required=True, help="the table to calibrate (its avoid slot is kept)")
    ca.add_argument("--out", type=Path, required=True, help="the calibrated table (NEW.npz; NEW.yaml and the report beside)")
    ca.add_argument("--quantile", type=finite, default=0.9, help="quantile the per-cell bound covers (default 0.9)")
    ca.add_argument("--confidence", type=finite, default=0.9, help="its confidence (default 0.9)")
    ca.add_argument("--sign-key", type=Path, help="sign the calibrated table with this ed25519 private key (PEM)")
    ca.add_argument("--accept-faster", action="store_true", help="accept cells that became faster than the stock "
                    "table (E_tr_pred below the SITL's): without it calibrate refuses them (see the report's evidence)")
    ca.add_argument("--json", action="store_true", help=JSON)
    ca.set_defaults(func=cmd_calibrate)

    cpl = _command(sub, "calibrate-plan",
                   description="write the calibration flight plan: calibration.plan (QGroundControl), "
                   "calibration.waypoints (Mission Planner) and calibration-legs.json (the daemon's hold legs)")
    cpl.prog = "contract-guard calibrate plan"
    cpl.add_argument("--vehicle", required=True, help="vehicle file or shipped name")
    cpl.add_argument("--out", type=Path, required=True, help="directory for calibration.plan / .waypoints / -legs.json")
    cpl.add_argument("--table", type=Path, help="table whose E_tr_pred speed grid sets the ladder (default: shipped)")
    cpl.add_argument("--v-top", type=finite, help="top speed of the ladder [m/s] (default: the grid's top)")
    cpl.add_argument("--altitude", type=finite, default=5.0, help="altitude above home [m]")
    cpl.add_argument("--json", action="store_true", help=JSON)
    cpl.set_defaults(func=cmd_calibrate_plan)

    ky = _command(sub, "keys", help="create or show the MAVLink signing key in the forms MAVProxy, QGroundControl, "
                  "PX4 and ArduPilot take (--table: the key pair that signs tables)")
    ky.add_argument("dir", type=Path, help="directory for the key files (created, mode 700)")
    ky.add_argument("--passphrase", help="derive the key from this MAVProxy passphrase (default: a new random one)")
    ky.add_argument("--table", action="store_true", help="an ed25519 key pair for `table sign` / --sign-key instead")
    ky.add_argument("--json", action="store_true", help=JSON)
    ky.set_defaults(func=cmd_keys)

    pl = _command(tsub, "plot", help="V_max vs D_od (Figures 6-7) and the surfaces of Figures 9-10, PNG + CSV")
    pl.add_argument("file", type=Path, help="table file (.npz)")
    pl.add_argument("--out", type=Path, required=True, help="directory for the PNG and CSV files")
    pl.add_argument("--json", action="store_true", help=JSON)
    pl.set_defaults(func=cmd_table_plot)
    return p


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["sitl"]:
        from sitl_harness.__main__ import main as sitl_main

        return sitl_main(argv[1:], prog="contract-guard sitl")
    if argv[:2] == ["calibrate", "plan"]:
        argv = ["calibrate-plan", *argv[2:]]
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except BuildInterrupted as err:
        print(f"contract-guard: {err}", file=sys.stderr)
        return 130
    except ContractError as err:
        from .flightlogs import for_terminal

        print(f"contract-guard: error: {for_terminal(str(err))}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
