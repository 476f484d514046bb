"""The ground-side commands (`table`, `figures`, `review`, `demo`, `campaign`, `calibrate`, `keys`): what
`contract-guard` runs away from the aircraft. Each returns the exit status; a person's error is a `ContractError`."""

from __future__ import annotations

import contextlib
import json
import math
import signal
import sys
from pathlib import Path

from companion.onboard.console import for_terminal
from contracts.errors import ContractError

from .flightlogs import READERS


def _emit(obj: dict, as_json: bool, text: str) -> None:
    """The result on stdout: JSON (its strings escaped by the encoder), or text stripped of control characters."""
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
    serial = f", serial {t.serial}" if t.serial is not None else ""
    if s["verified"]:
        return f"signed, signature verified with public key {s['key_id']}{serial}"
    if s["signed"]:
        return f"signed by key {s['key_id']}{serial}, signature not checked (no --public-key): integrity only"
    return "unsigned: integrity only"


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
    from companion.onboard.console import controller_coverage

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


def _base_checked(path, key, args) -> str:
    """The base table `path` may be signed over (`contracts.table.base_trust`): its signature verifies (with
    --base-public-key, else the signing key's own), or it is the shipped table of its vehicle; else refused
    naming what differs, unless --accept-edited-base. Returns the words that say which."""
    from contracts.table import base_trust, load_private_key

    return base_trust(path, load_private_key(key).public_key(), args.base_public_key, args.accept_edited_base)


def cmd_table_sign(args) -> int:
    from contracts.table import sign_table

    src = table_file(args.file)
    base = _base_checked(src, args.key, args)
    sig = sign_table(src, args.key, args.out, args.serial)
    _emit({"ok": True, "file": str(args.out or args.file), "base": base, **sig}, args.json,
          f"signed {args.out or args.file} with key {sig['key_id']}, serial {sig['serial']} (ed25519; check: "
          f"contract-guard table verify {args.out or args.file} --public-key PUBLIC.pem); the table signed: {base}")
    return 0


def _sign_after(path, key) -> str:
    """`--sign-key` of a command that writes a table: sign it; the text that says so ('' without a key)."""
    if key is None:
        return ""
    from contracts.table import sign_table

    sig = sign_table(path, key)
    return f"; signed with key {sig['key_id']}, serial {sig['serial']}"


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
    if args.stop_only and args.extend is not None:
        raise ContractError("table build: --extend keeps avoid cells; it does not go with --stop-only")
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
                                    partial_grid=args.partial_grid, extend=args.extend)
    for gap in summary["coverage_gaps"]:
        print(f"contract-guard: warning: the grid does not cover the vehicle: {gap}", file=sys.stderr)
    signed = _sign_after(args.out, args.sign_key)
    _emit({"ok": True, "out": str(args.out), **summary}, args.json, f"wrote {args.out}: {one_line(summary)}{signed}")
    return 0


def cmd_table_etr(args) -> int:
    """The controller contract E_tr_pred (Figure 12) from SITL flights, written into the table."""
    from contracts.runner import show_progress
    from contracts.vehicle import DATA_DIR
    from sitl_harness.etr_sweep import build_etr, build_governor_etr  # offline: flies the SITL

    table = table_file(args.table)
    if table.resolve().parent == DATA_DIR and args.out is None:
        raise ContractError(f"table etr: {args.table} is a shipped table; give --out for the result (shipped tables "
                            "are not rewritten in place)")
    # a signed result vouches for the avoid contract it keeps from its base: checked before any flight
    base = _base_checked(table, args.sign_key, args) if args.sign_key else None
    if args.brake:
        if args.resume:
            raise ContractError("table etr: --resume is for the offboard sweep, not --brake (a few minutes, "
                                "no checkpoint)")
        with _interruptible():
            s = build_governor_etr(table, args.vehicle, grid=args.grid, workers=args.workers, scheduler=args.scheduler,
                                   progress=show_progress(not args.json), out=args.out, brake=True)
        signed = _sign_after(s["path"], args.sign_key)
        _emit({"ok": True, **s}, args.json, f"wrote the recovery brake's E_tr_pred into {s['path']}: {s['cells']} "
              f"cells in {s['wall_s']} s, {s['monotone_repairs_up']} repaired upward{signed}"
              + (f"; the base table: {base}" if base else ""))
        return 0
    with _interruptible():
        s = build_etr(table, args.vehicle, grid=args.grid, workers=args.workers, scheduler=args.scheduler,
                      progress=show_progress(not args.json), out=args.out, resume=args.resume)
    resumed = f", {s['resumed_cells']} from the checkpoint" if s["resumed_cells"] else ""
    signed = _sign_after(s["path"], args.sign_key)
    _emit({"ok": True, **s}, args.json, f"wrote E_tr_pred into {s['path']}: {s['cells']} cells in {s['wall_s']} s"
          f"{resumed}, {s['monotone_repairs_up']} repaired upward, worst raw contour error "
          f"{s['raw_worst_max_m']:.3f} m (--json for the full record){signed}"
          + (f"; the base table: {base}" if base else ""))
    return 0


def cmd_figures(args) -> int:
    """Figure 12 and the demonstration flights of Figures 14-16 (PNG + CSV)."""
    need("build", "matplotlib")
    from contracts.table import shipped_table
    from sitl_harness.figures import make_figures

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


def raw_log_of(paths) -> Path | None:
    """The one raw log among `paths`, if any (it is replayed, not read)."""
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    raw = [Path(p) for p in paths if Path(p).suffix.lower() in READERS]
    if raw and len(paths) > 1:
        raise ContractError(f"{raw[0]}: a {raw[0].suffix.lower()} is replayed on its own; review it without other logs")
    return raw[0] if raw else None


def review_log(paths, out_dir=None, *, config=None, vehicle=None, table=None, gap_s: float = 1.0,
               tolerance_m_s: float | None = None, sensor=None, world: dict | None = None):
    """(report, origin) for event logs, or for one raw log replayed into an event log first (`origin`
    says what it was made from; None for an event log). `config`, `vehicle`, `table`: for the replay;
    `tolerance_m_s`: None, the review's (`review_checks.SPEED_TOLERANCE_M_S`); `world`: the true world's outline
    (`scenario_world`), drawn on the plan view."""
    import shutil
    import tempfile

    from companion.onboard.logschema import LOG_FILE, REPLAY_LOG_FILE

    from .flightlogs import check_file, guarded, replay_log
    from .review import review
    from .review_checks import SPEED_TOLERANCE_M_S

    tolerance_m_s = SPEED_TOLERANCE_M_S if tolerance_m_s is None else tolerance_m_s

    raw = raw_log_of(paths)
    if raw is None:
        if config or vehicle or table:
            raise ContractError(f"--config, --vehicle and --table apply only to a {' or '.join(READERS)} "
                                "(an event log carries its values)")
        files = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
        from companion.onboard.eventlog import file_set

        for p in files:
            for f in file_set(p) if p.is_dir() else [p]:
                check_file(f, "an event log")
        return guarded(files[0], "event log", review, paths, out_dir, gap_s=gap_s, tolerance_m_s=tolerance_m_s,
                       sensor=sensor, world=world), None
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
        rep = review(log, out_dir, gap_s=gap_s, tolerance_m_s=tolerance_m_s, origin=origin, sensor=sensor, world=world)
    return rep, origin


def scenario_world(name_or_path: str | None) -> dict | None:
    """The outline of a SITL scenario's world (`review --scenario`), or None without one."""
    if not name_or_path:
        return None
    from sitl_harness.scenario import load_scenario

    return load_scenario(name_or_path).world.outline()


def cmd_review(args) -> int:
    """Event logs are reviewed; a raw log is replayed into an event log, then reviewed (`READERS`)."""
    from companion.onboard.eventlog import file_set

    from .review import format_report
    from .reviewset import expand, review_set, summary_lines

    # many flights (several raw logs, or folders of them, and no event log among them): one table, each reviewed
    event_logs = any(file_set(p) if p.is_dir() else p.suffix.lower() not in READERS for p in map(Path, args.log))
    raw = [] if event_logs else expand(args.log, READERS)
    world = scenario_world(args.scenario)
    if len(raw) > 1 or (raw and any(Path(p).is_dir() for p in args.log)):
        result, texts = review_set(args.log, READERS, lambda path, out: review_log(
            path, out, config=args.config, vehicle=args.vehicle, table=args.table, sensor=args.assume_sensor,
            world=world),
            args.out)
        text = "\n".join(summary_lines(result) + [""] + texts
                          + [f"  wrote {k}: {v}" for k, v in result.get("outputs", {}).items()])
        _emit(result, args.json, text)
        return 0 if result["ok"] or not args.strict else 1
    rep, origin = review_log(args.log, args.out, config=args.config, vehicle=args.vehicle, table=args.table,
                             sensor=args.assume_sensor, world=world)
    _emit(rep, args.json, format_report(rep, origin))
    return 0 if rep["ok"] or not args.strict else 1


def demo(scenario: str = "fig17", out: Path = Path("demo-out"), **kw) -> dict:
    """`companion.ground.demo.run_demo` of a scenario by name or path (the harness is wired in here only)."""
    from sitl_harness.scenario import load_scenario, resolve_scenario_path

    from .demo import run_demo

    return run_demo(load_scenario(scenario), resolve_scenario_path(scenario), out, **kw)


def cmd_demo(args) -> int:
    """The SITL and the daemon on loopback UDP flying the paper's in-flight scenario (Figure 17)."""
    from .demo import format_summary

    r = demo(args.scenario, args.out, speedup=args.speedup, duration_s=args.duration, personality=args.personality)
    _emit(r, args.json, format_summary(r))
    return 0 if r["verdict"] == "SAFE" else 1


def cmd_campaign(args) -> int:
    """Monte Carlo lock-step flights over a scenario distribution, baselines and controls; the report."""
    from companion.ground import campaign as cg

    need("ground", "tqdm")
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
            events, scenario = cg.keep_flight(rig, *cg.flight_of(spec, args.fly), args.out, args.fly)
        text = (f"flight {row['index']} ({row['arm']}, {row['vehicle']}, {row['personality']}): "
                f"collided {row['collided']}, min clearance {row['min_clearance_m']}, mean speed "
                f"{row['mean_speed_m_s']:.2f} m/s, route completed {row['route_completed']}, "
                f"faults {[(f['kind'], f['subsystem'], f['latency_s']) for f in row['fault_outcomes']]}")
        if args.out is not None:
            text += f"\nits review: contract-guard review {events} --scenario {scenario}"
        _emit(cg._plain(row), args.json, text)
        return 0
    if args.out is None:
        raise ContractError("campaign: --out DIR is required (results.jsonl and the report go there)")
    from contracts.runner import show_progress

    from .campaign_report import format_summary, write_report

    if not args.report_only:
        with _interruptible():
            rows = cg.run(spec, args.out, workers=args.workers, scheduler=args.scheduler,
                          progress=show_progress(not args.no_progress and not args.json), spec_path=str(args.spec),
                          limit=args.limit)
    else:
        rows = cg.read_rows(args.out)
    summary = write_report(rows, args.out, spec_path=str(args.spec))
    _emit(summary, args.json, format_summary(summary) + f"\nreport: {args.out / 'report.html'}")
    return 0


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
    # a signed result vouches for its base too: the base must be signed (and verify) or be the shipped table
    base = _base_checked(table_file(args.table), args.sign_key, args) if args.sign_key else None
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
    if base is not None:
        s["base_table"] = base
        signed += f"; the base table: {base}"
    _emit(s, args.json, format_summary(s) + signed.replace("; s", "\n  s").replace("; the base", "\n  the base")
          + f"\nreport: {args.out.with_suffix('')}.report.html")
    return 0


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
