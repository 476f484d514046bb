"""`contract-guard`: keeps a multirotor's obstacle avoidance within its contract (PX4, ArduPilot).

Every command that prints results has `--json` (one JSON object on stdout). Errors a person can cause
end with one line on stderr and a non-zero exit status, never a traceback. This module is the
command line only: each command runs in `companion.onboard.commands` (`run`) or
`companion.ground.commands` (the rest), loaded when that command runs, so the daemon's start loads no ground
module.
"""

from __future__ import annotations

import argparse
import math
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
    """An argparse type: `RANGE_M[,FOV_DEG]` (`companion.ground.detection_need.Sensor`), one line when wrong."""
    from .ground.detection_need import Sensor

    try:
        return Sensor.parse(text)
    except ContractError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _onboard(args) -> int:
    """The on-board command (`run`)."""
    from .onboard import commands

    return getattr(commands, args.handler)(args)


def _ground(args) -> int:
    """A ground command: its module loads only when one runs."""
    from .ground import commands

    return getattr(commands, args.handler)(args)


def _command(sub, name: str, help: str | None = None, handler: str | None = None, side=_ground,
             **kw) -> argparse.ArgumentParser:
    """A subcommand whose own `--help` page opens with what it does (its line in the command list; no
    `help`: not listed, as `calibrate-plan`, which is spelled `calibrate plan`), run by `handler` of its package
    (`side`: `_ground` or `_onboard`)."""
    kw.setdefault("description", help)
    parser = sub.add_parser(name, **({"help": help} if help else {}), **kw)
    if handler is not None:
        parser.set_defaults(func=side, handler=handler)
    return parser


def _base_options(parser: argparse.ArgumentParser, what: str) -> None:
    """The options on the table a signature will vouch for (`table sign`, `calibrate --sign-key`)."""
    parser.add_argument("--base-public-key", type=Path, help=f"{what} is signed by this key's private key (PEM; "
                        "default: the signing key's own)")
    parser.add_argument("--accept-edited-base", action="store_true", help=f"sign over {what} even where it is "
                        "unsigned and not the shipped table of its vehicle (what differs is named)")


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="contract-guard", description=__doc__.splitlines()[0],
               epilog="`contract-guard COMMAND --help` describes each command and its options.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    JSON = "print the result as one JSON object on stdout"

    d = _command(sub, "demo", help="fly the paper's in-flight scenario: SITL + daemon on loopback UDP",
                 handler="cmd_demo")
    d.add_argument("--scenario", default="fig17", help="scenario name or file (default: fig17)")
    d.add_argument("--out", type=Path, default=Path("demo-out"), help="event log, plot and summary go here")
    d.add_argument("--speedup", type=finite, default=1.0,
                   help="simulated seconds per wall-clock second (default 1: real time, the daemon's timing budget "
                        "as on an aircraft; at K the host's lateness counts K times)")
    d.add_argument("--duration", type=finite, default=85.0,
                   help="simulated seconds after the take-off (default 85: the route and its Hold)")
    d.add_argument("--personality", choices=["px4", "ardupilot"], default="px4",
                   help="which autopilot the SITL behaves like (default px4)")
    d.add_argument("--json", action="store_true", help=JSON)

    # `sitl` hands its arguments to the harness's own parser (see main)
    _command(sub, "sitl", help="the SITL vehicle alone, for any MAVLink client: [--scenario NAME|FILE] "
                   "--personality px4|ardupilot --listen udp:127.0.0.1:PORT [--speedup K] (an empty world by "
                   "default; `sitl --help` names the shipped scenarios)", add_help=False)

    r = _command(sub, "run", help="the on-board daemon (what systemd starts): connects to the autopilot, holds its "
                 "speed within the contract in shadow, governor or offboard mode, and writes the event log",
                 handler="cmd_run", side=_onboard)
    r.add_argument("--config", required=True, type=Path,
                   help="the daemon's YAML config (relative paths in it are relative to its directory)")
    r.add_argument("--connect", help="override link.connect (pymavlink URL)")
    r.add_argument("--log-dir", help="override log.dir")
    r.add_argument("--mode", choices=["shadow", "governor", "offboard"], help="override mode")
    r.add_argument("--quiet", action="store_true", help="print nothing (the event log still has everything)")
    r.add_argument("--check", action="store_true", help="validate the config, its vehicle and table, print the "
                   "start banner and exit (the link is not opened)")

    rv = _command(sub, "review", help="contract-violation report for a flight's event log, or for raw flight logs "
                        "(.tlog, PX4 .ulg, ArduPilot .bin) replayed through the contract", handler="cmd_review")
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
    rv.add_argument("--scenario", help="a SITL flight: its scenario (a shipped name or a file), whose walls, "
                    "polygons and columns the plan view draws beneath the track")
    rv.add_argument("--strict", action="store_true", help="exit 1 when the report has findings")
    rv.add_argument("--json", action="store_true", help=JSON)

    t = _command(sub, "table", help="build, inspect, query, verify and plot Γ tables (the contract of one vehicle)")
    tsub = t.add_subparsers(dest="table_command", required=True)

    s = _command(tsub, "show", help="print a table's metadata", handler="cmd_table_show")
    s.add_argument("file", type=Path, help="table file (.npz)")
    s.add_argument("--public-key", type=Path, help="the table must be signed by this key's private key (PEM)")
    s.add_argument("--json", action="store_true", help=JSON)

    v = _command(tsub, "verify",
                 help="check a table (schema, hash, monotonicity, vehicle; signature with --public-key)",
                 handler="cmd_table_verify")
    v.add_argument("file", type=Path, help="table file (.npz)")
    v.add_argument("--vehicle", help="vehicle file or shipped name the table must match")
    v.add_argument("--public-key", type=Path, help="the table must be signed by this key's private key (PEM)")
    v.add_argument("--json", action="store_true", help=JSON)

    sg = _command(tsub, "sign", help="sign a table (ed25519 over its arrays and metadata; `keys --table` makes a key)",
                  handler="cmd_table_sign")
    sg.add_argument("file", type=Path, help="table file (.npz)")
    sg.add_argument("--key", type=Path, required=True, help="ed25519 private key (PEM)")
    sg.add_argument("--out", type=Path, help="write the signed table here instead of in place")
    sg.add_argument("--serial", type=int, help="the signing's serial (default: the UTC time, YYYYMMDDHHMMSS; above "
                    "the table's own): the daemon refuses a table older than the last it accepted")
    _base_options(sg, "the table")
    sg.add_argument("--json", action="store_true", help=JSON)

    q = _command(tsub, "query", help="answer one query: Ω, V_safe, Γ and the stop-contract speed",
                 handler="cmd_table_query")
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

    b = _command(tsub, "build", help="build a Γ table for a vehicle: the stop contract (closed form, about a second) "
                 "and, unless "
                 "--stop-only, the avoid contract's sweep over ρ, tilt and thrust ratio (IPOPT via CasADi)",
                 handler="cmd_table_build")
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
    b.add_argument("--extend", type=Path, metavar="TABLE",
                   help="keep the verified avoid cells of this built table (same vehicle, tilt model, tilt and thrust "
                   "axes and solver settings) and solve only the ρ points its axis lacks; its E_tr_pred is carried "
                   "over; without --grid: its axes with the default ρ axis")
    b.add_argument("--sign-key", type=Path, help="sign the table with this ed25519 private key (PEM)")
    b.add_argument("--json", action="store_true", help=JSON)

    e = _command(tsub, "etr", help="fly the SITL and write the controller contract E_tr_pred (Figure 12) into a table",
                 handler="cmd_table_etr")
    e.add_argument("--table", type=Path, required=True, help="table with an avoid slot (updated in place unless --out)")
    e.add_argument("--vehicle", help="vehicle file or shipped name the table must match")
    e.add_argument("--out", type=Path, help="write the result here instead of in place")
    e.add_argument("--grid", type=Path, help="E_tr grid YAML: v_max, tilt_deg, thrust_ratio, rhos, seeds "
                   "(default: the vehicle's shipped grid, about 15 min on two cores)")
    e.add_argument("--resume", action="store_true",
                   help="continue an interrupted sweep from its checkpoint (DEST.partial/, kept until the table is written)")
    e.add_argument("--brake", action="store_true",
                   help="instead: the governor's E_tr_pred with its recovery brake (what the autopilot flies and the "
                        "brake's own stop), written as the table's e_tr_pred_brake slot")
    e.add_argument("--workers", type=int, default=2, help="local process pool size")
    e.add_argument("--sign-key", type=Path, help="sign the result with this ed25519 private key (PEM)")
    _base_options(e, "--table, with --sign-key,")
    e.add_argument("--scheduler", help="Dask distributed scheduler address, e.g. tcp://host:8786")
    e.add_argument("--json", action="store_true", help=JSON)

    fg = _command(sub, "figures", help="Figure 12 and the demonstration flights of Figures 14-16, PNG + CSV",
                  handler="cmd_figures")
    fg.add_argument("--out", type=Path, required=True, help="directory for the PNG and CSV files")
    fg.add_argument("--table", type=Path, help="table file (default: the shipped Mambo table)")
    fg.add_argument("--seeds", type=int, default=3, help="wind seeds per flight")
    fg.add_argument("--json", action="store_true", help=JSON)

    cp = _command(tsub, "compare", help="analytical vs numerical contract (Figures 4, 6, 7), PNG + CSV",
                  handler="cmd_table_compare")
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

    cg = _command(sub, "campaign", help="Monte Carlo lock-step flights over a scenario distribution, with the "
                        "PX4/ArduPilot laws as baselines and negative controls, on a pool or a Dask cluster; report",
                  handler="cmd_campaign")
    cg.add_argument("spec", type=Path, help="campaign spec (YAML)")
    cg.add_argument("--out", type=Path, help="results.jsonl and the report (an interrupted campaign resumes here)")
    cg.add_argument("--workers", type=int, default=1, help="local process pool size (default 1: in-process)")
    cg.add_argument("--scheduler", help="Dask distributed scheduler address, e.g. tcp://host:8786")
    cg.add_argument("--fly", type=int, metavar="INDEX", help="re-fly one flight (with --out: its event log too)")
    cg.add_argument("--limit", type=int, help="fly at most this many more flights, then report")
    cg.add_argument("--report-only", action="store_true", help="report the results already in --out")
    cg.add_argument("--no-progress", action="store_true",
                    help="no progress bar on stderr (there is none unless stderr is a terminal)")
    cg.add_argument("--json", action="store_true", help=JSON)

    ca = _command(sub, "calibrate", help="calibrate the controller contract and braking from flight logs "
                        "(`calibrate plan` writes the calibration flight plan)", handler="cmd_calibrate")
    ca.add_argument("log", nargs="+", type=Path, help="flight logs (.tlog, .ulg, .bin) or folders of them")
    ca.add_argument("--vehicle", required=True, help="vehicle file or shipped name")
    ca.add_argument("--table", type=Path, required=True, help="the table to calibrate (its avoid slot is kept)")
    ca.add_argument("--out", type=Path, required=True, help="the calibrated table (NEW.npz; NEW.yaml and the report beside)")
    ca.add_argument("--quantile", type=finite, default=0.9, help="quantile the per-cell bound covers (default 0.9)")
    ca.add_argument("--confidence", type=finite, default=0.9, help="its confidence (default 0.9)")
    ca.add_argument("--sign-key", type=Path, help="sign the calibrated table with this ed25519 private key (PEM)")
    _base_options(ca, "--table, with --sign-key,")
    ca.add_argument("--accept-faster", action="store_true", help="accept cells that became faster than the stock "
                    "table (E_tr_pred below the SITL's): without it calibrate refuses them (see the report's evidence)")
    ca.add_argument("--json", action="store_true", help=JSON)

    cpl = _command(sub, "calibrate-plan", handler="cmd_calibrate_plan",
                   description="write the calibration flight plan: calibration.plan (QGroundControl), "
                   "calibration.waypoints (Mission Planner) and calibration-legs.json (the daemon's hold legs)")
    cpl.prog = "contract-guard calibrate plan"
    cpl.add_argument("--vehicle", required=True, help="vehicle file or shipped name")
    cpl.add_argument("--out", type=Path, required=True, help="directory for calibration.plan / .waypoints / -legs.json")
    cpl.add_argument("--table", type=Path, help="table whose E_tr_pred speed grid sets the ladder (default: shipped)")
    cpl.add_argument("--v-top", type=finite, help="top speed of the ladder [m/s] (default: the grid's top)")
    cpl.add_argument("--altitude", type=finite, default=5.0, help="altitude above home [m]")
    cpl.add_argument("--json", action="store_true", help=JSON)

    ky = _command(sub, "keys", help="create or show the MAVLink signing key in the forms MAVProxy, QGroundControl, "
                  "PX4 and ArduPilot take (--table: the key pair that signs tables)", handler="cmd_keys")
    ky.add_argument("dir", type=Path, help="directory for the key files (created, mode 700)")
    ky.add_argument("--passphrase", help="derive the key from this MAVProxy passphrase (default: a new random one)")
    ky.add_argument("--table", action="store_true", help="an ed25519 key pair for `table sign` / --sign-key instead")
    ky.add_argument("--json", action="store_true", help=JSON)

    pl = _command(tsub, "plot", help="V_max vs D_od (Figures 6-7) and the surfaces of Figures 9-10, PNG + CSV",
                  handler="cmd_table_plot")
    pl.add_argument("file", type=Path, help="table file (.npz)")
    pl.add_argument("--out", type=Path, required=True, help="directory for the PNG and CSV files")
    pl.add_argument("--json", action="store_true", help=JSON)
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
        from .onboard.console import for_terminal

        print(f"contract-guard: error: {for_terminal(str(err))}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
