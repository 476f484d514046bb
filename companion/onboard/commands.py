"""The on-board command, `contract-guard run`: the daemon as systemd starts it (config, table, link, event
log, the polite signals)."""

from __future__ import annotations

from contracts.errors import ContractError


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
    import faulthandler
    import signal
    from dataclasses import asdict

    from contracts.table import load_for_vehicle

    from .assumptions import controller_contract
    from .autopilots import adapter_for
    from .config import weakened
    from .console import ConsoleLog, banner
    from .daemon import Daemon
    from .eventlog import EventLog
    from .inputs import check_inputs
    from .link import SigningClock, open_connection, setup_signing
    from .sensing import silence_budget
    from .service import Notifier
    from .startup import StartupChecks, looks_forward

    cfg = run_config(args)
    table = load_for_vehicle(cfg.vehicle, cfg.table, cfg.table_public_key)
    if cfg.daemon_mode.contract == "avoid" and table.avoid is None:
        raise ContractError(f"mode {cfg.mode} needs an avoid contract; table {table.path} carries the stop "
                            "contract only")
    # a set-up whose forward beams cover the swept corridor nowhere is refused before the link (one with no forward
    # sensor at all starts and refuses to engage, saying so to the ground station: the start-up checks)
    if cfg.daemon_mode.commands and looks_forward(cfg.sensors):
        from .assumptions import e_tr_floor
        from .coverage import refusal

        if (why := refusal(cfg.sensors, table.vehicle.r_body_m, e_tr_floor(cfg, table))) is not None:
            raise ContractError(f"config {args.config}: {cfg.mode} mode refused: {why}")
    inputs = check_inputs(cfg, table)  # the same refusals for --check as for the run (nothing recorded yet)
    if args.check:
        for line in banner(cfg, table, controller_contract(cfg, table)):
            if not line.startswith("waiting for the autopilot"):  # it is not waited for
                print(line)
        for line in inputs.lines + weakened(cfg):
            print(line)
        checks = StartupChecks(adapter_for(cfg.link.autopilot), table.vehicle, cfg, table.e_pred is not None)
        if checks.ok is False:  # refused whatever the autopilot answers
            print(f"REFUSING TO ENGAGE: {checks.reason}")
        print(f"config {args.config}: valid; its table fits (--check: the link is not opened)")
        return 0
    faulthandler.enable()  # a watchdog abort prints the stack to the journal
    signing_clock = None
    key = inputs.signing_key
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
    for line in inputs.lines:  # the table's serial (WEAKENED: a rollback allowed)
        log.say(line, 4 if line.startswith("WEAKENED") else 6)
    for line in weakened(cfg):  # inside its safe range but weaker than the default; unsigned on a network
        log.say(line, 4)
    inputs.serial.accept()
    if inputs.serial.rollback is not None:
        log.event(None, "table_rollback", **inputs.serial.rollback)
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
              delivery=cfg.delivery.model_dump(), sensor_silence=asdict(silence_budget(cfg)), table_serial=table.serial,
              table_signature=table.signature)
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
