"""The event log's schema, in one place: file names, the record envelope, the state sample's fields (in
the order the daemon writes them), the events and their fields, the daemon's NAMED_VALUE_FLOATs and its
command names (DESIGN.md §5). Written by `companion.onboard.eventlog`, read by `companion.ground.review` and
`companion.ground.flightlogs.tlog`; `tests/test_logschema.py` checks it against what the daemon really writes.

A record is one JSON object per line (JSON Lines):

    {"kind": "state", "t": 12.34, "wall": 1790000000.1, "seq": 17, "boot": "3f9c0a1b2d4e", ...STATE_FIELDS}
    {"kind": "event", "t": 12.36, "wall": ..., "seq": 18, "boot": ..., "event": "violation_start", ...fields}

Pure data: no I/O, no imports of the rest of the daemon.
"""

from __future__ import annotations

from typing import NamedTuple

from .states import Subsystem

LOG_NAME = "events"  # the current file is events.jsonl; rotated to events.1.jsonl (newest) … events.<keep>.jsonl
LOG_SUFFIX = ".jsonl"
LOG_FILE = LOG_NAME + LOG_SUFFIX
REPLAY_LOG_FILE = "replay-events.jsonl"  # an event log made by replaying a raw log, as kept beside its review

# every record's envelope (a field of the same name is stored with a trailing underscore: `seq_`)
ENVELOPE = {
    "kind": "'state' | 'event'",
    "t": "daemon time [s] (runs at the vehicle's rate; lock-step: sim time; null for the log's own events)",
    "wall": "UNIX time [s] from the injected wall clock",
    "seq": "record number of this daemon run, from 0 (a gap means lost records)",
    "boot": "random id of this daemon run (one per EventLog)",
    "event": "event name (events only; see EVENTS)",
    "nonfinite": "dotted names of fields whose NaN/inf was written as null (only when there were any)",
}
RECORD_KEYS = tuple(ENVELOPE)

# state sample (kind "state", at log.state_hz ≥ 10 Hz): field → (unit, meaning), in the order written
STATE = {
    "state": ("", "supervisor state: standby | active | holding | failsafe"),
    "mode": ("", "autopilot flight mode (the adapter's name; 'other' while the link is down)"),
    "contract": ("", "contract enforced: stop (governor, shadow) | avoid (offboard)"),
    "engaged": ("bool", "the daemon is asked to act and may (CG_ENGAGE, start-up checks, not restarted in air)"),
    "x": ("m", "position north, local NED"),
    "y": ("m", "position east, local NED"),
    "z": ("m", "position down, local NED"),
    "vx": ("m/s", "velocity north"),
    "vy": ("m/s", "velocity east"),
    "vz": ("m/s", "velocity down"),
    "ground_speed": ("m/s", "horizontal speed (NaN/null while telemetry is stale)"),
    "d_od": ("m", "detection range D_od the navigation guarantees now (the evidence's, when below the claim)"),
    "d_od_stated": ("m", "the D_od the sensors' stated range gives (D_od's claim, before evidence and late detections)"),
    "e_tr": ("m", "tracking error E_tr used by the contract (measured or predicted, the larger)"),
    "e_tr_measured": ("m", "contour error measured against the commanded path"),
    "r_obst": ("m", "expected obstacle radius R_obst (CG_R_OBST)"),
    "thrust_ratio": ("1", "available thrust T_max / T_nom, estimated"),
    "v_max": ("m/s", "speed limit V_max of the chosen operating point Ω"),
    "tilt_deg": ("deg", "tilt limit of Ω"),
    "v_safe": ("m/s", "the contract's safe speed at Ω"),
    "gamma": ("m/s", "Γ = limit in force (v_cmd, else v_max) − v_safe"),
    "gamma_flown": ("m/s", "ground speed − v_safe: the contract evaluated on the flight itself"),
    "v_cmd": ("m/s", "speed limit actually commanded (null when none: shadow, not engaged)"),
    "obstacle_m": ("m", "nearest obstacle seen near the path, D_od's band 2·R_obst + E_tr + r_body about the "
                        "direction of travel (inf/null: none); the stop contract's Hold judges the narrower swept "
                        "corridor"),
    "withheld": ("count", "returns within a sensor's clutter (sensors[k].clutter_m) withheld from the obstacle logic "
                          "until the next frames confirm them, one per frame, since the daemon started"),
}
# what the link did not believe, counted since the daemon started (companion/onboard/mavlink_out.py Counters)
LINK_COUNTERS = {
    "bad_packets": ("count", "malformed packets (bad CRC, torn frames)"),
    "rejected_signature": ("count", "unsigned or wrongly signed packets, where signing is on"),
    "unknown_source": ("count", "messages from ids no configured autopilot, sensor or ground station has"),
    "refused_address": ("count", "datagrams claiming a pinned source's ids from another address"),
    "link_dropped": ("count", "datagrams dropped unread: not MAVLink, or a frame cut at the datagram's end"),
    "kernel_drops": ("count", "datagrams the kernel dropped (receive buffer full), where it says"),
}
STATE.update(LINK_COUNTERS)
STATE_FIELDS = tuple(STATE)

SUBSYSTEMS = tuple(s.value for s in Subsystem)  # violation_start.subsystem


class Event(NamedTuple):
    fields: tuple[str, ...]  # every field it may carry (beyond the envelope)
    by: str  # who writes it
    meaning: str


_NO_SPEED = ("input", "why", "resume")  # a `no safe speed` Hold's cause (companion/onboard/no_speed.py)
_MISSION_STATS = ("resent", "duplicates", "out_of_order", "malformed")
EVENTS = {
    "start": Event(("mode", "vehicle", "table", "connect", "replay_of", "contract", "controller_contract", "nav_margin",
                    "delivery", "sensor_silence", "table_serial", "table_signature"),
                   "cli run, replay",
                   "daemon run starts (connect: the live link; replay_of: the raw log replayed; sensor_silence: how "
                   "long an obstacle sensor may be silent, budgeted as dead time (periods of its own, min_s, max_s); "
                   "table_serial: the signed table's serial, None unsigned; table_signature: signed, key_id, "
                   "verified)"),
    "table_rollback": Event(("serial", "last_serial", "last_table", "state_file"), "cli run",
                            "a table older than the last accepted is flown because the config allows it "
                            "(allow_table_rollback; WEAKENED in the banner)"),
    "stop": Event(("counters",), "cli run, replay", "daemon run ends cleanly (the daemon's counters)"),
    "loop_timing": Event(("cycles", "work_ms_max", "wake_late_ms_max", "cycles_over_ms", "worst",
                          "event_log_max_fsync_ms"), "daemon",
                         "how the real-time loop kept its schedule: a cycle's wake-up lateness (the host woke it "
                         "late) and its own work (poll, step, the commit of its events), largest, cycles over "
                         "10/20/40 ms, the worst five; the event log's slowest fsync (one commit a cycle)"),
    "planning": Event(("answers", "first_s", "median_s", "max_s", "replans", "kept", "rejected"), "daemon",
                      "offboard's avoidance planning at the loop's end: answers waited for and how late they came "
                      "(request to poll, vehicle time; first_s: the first obstacle's), plans flown, failed replans "
                      "that kept the plan in force, plans the exact check rejected"),
    "log_open": Event(("pid", "torn_tail"), "eventlog", "log opened (torn_tail: the previous run's last line was cut)"),
    "log_failing": Event(("error",), "daemon", "the event log cannot write (said by STATUSTEXT and on the console)"),
    "log_writing": Event(("error",), "daemon", "the event log writes again"),
    "log_recovered": Event(("dropped_records", "write_errors", "since_wall", "error"), "eventlog",
                           "writes succeed again after a failure (records dropped meanwhile)"),
    "violation_start": Event(("subsystem", "guarantee", "assumed", "observed", "action", "sensor"), "supervisor",
                             "a subsystem broke its guarantee (subsystem ∈ SUBSYSTEMS; sensor: the obstacle sensor "
                             "silent longer than its budget, its index in `sensors`; guidance's own: a cycle that "
                             "ended in an internal error, a setpoint put away from the vehicle)"),
    "reaction_time": Event(("late_s", "t_react_s"), "supervisor",
                           "the daemon's own lateness counted as reaction time changed (a late cycle, or 10 s on "
                           "time since): Ω flies V ≤ V_safe(d_od − V·(t_react + late_s)); 0 when on time"),
    "cycle_jitter": Event(("late_s", "allowance_s"), "supervisor",
                          "a cycle later than its period by late_s, inside the jitter allowance t_react budgets "
                          "(timeouts.cycle_jitter_s): no violation; said when it is the worst of the last 10 s"),
    "dod_coverage": Event(("basis", "d_od", "reason"), "supervisor",
                          "D_od's basis changed to or from `swept`: the direction of travel outside every field of "
                          "view, D_od the distance along it seen free recently (else `field of view` or `none`: 0)"),
    "violation_end": Event(("subsystem", "guarantee", "observed"), "supervisor",
                           "that guarantee holds again (observed, of the daemon's own cycles: how many failed in a "
                           "row)"),
    "contract_in_force": Event(("contract", "reason"), "supervisor",
                               "offboard: the contract in force changed — `stop` where the avoid contract's assumptions "
                               "are not there (something wider than R_obst in view or still within reach, or a swerve "
                               "the sensors' field of view would not keep in view at this D_od), `avoid` again once "
                               "they have held for the dwell"),
    "one_frame_split": Event(("told", "counted", "nearest_m", "v_ref", "v_stop"), "supervisor, offboard",
                             "under the avoid contract, a frame told `told` obstacles apart where the frame before "
                             "told at most one: runs in neighbouring bins (as a column the range noise splits) counted "
                             "as `counted` until the next frame tells them apart too, the stop contract stopping short "
                             "of the nearest waiting run, nearest_m away (v_ref ≤ v_stop [m/s]); said once a frame"),
    "dead_end": Event(("reason", "obstacle_m"), "supervisor, offboard",
                      "no path the contract can prove: offboard under the stop contract, something in the swept "
                      "corridor within the stopping distance (obstacle_m ahead: a braking stop, then Hold; the "
                      "supervisor's), or at rest for 3 s on a stop short of what is in the way, the planner finding no "
                      "pass (obstacle_m: the room left before the body touches it; Hold, the offboard controller's)"),
    "state_change": Event(("from", "to", "reason"), "supervisor", "supervisor state changed"),
    "mode_change": Event(("from", "to", "by"), "supervisor", "autopilot mode changed (by: daemon | other)"),
    "failsafe": Event(("cause", "action", *_NO_SPEED), "supervisor", "a failsafe cause made the daemon hold (a "
                      "`no safe speed`: `input` that caused it — thrust_ratio, d_od, e_tr, late_s, policy, table, "
                      "non-finite —, `why` in words, how the flight resumes)"),
    "hold_trigger": Event(("cause", "action"), "supervisor", "a non-failsafe cause (obstacle, limit not in force) "
                          "made the daemon hold"),
    "limit_change": Event(("v_max", "reason", "overshoot_budget_m_s"), "supervisor", "a new speed limit is sent (`sent`, `cruise`: a "
                          "governor sent the autopilot's lower cruise speed instead; `mission_speed`: the mission's "
                          "own speed item's, with calibration.legs; with the approach ramp: the speed the ramp's "
                          "commands climb to changed; `overshoot_budget_m_s`: the stop contract's limit is V_max − "
                          "this, the autopilot's overshoot budget, speed_overshoot)"),
    "cruise_speed": Event(("param", "v"), "daemon", "the autopilot's cruise-speed parameter (NaN: unusable); a "
                          "governor never sends a limit above it"),
    "limit_not_applicable": Event(("mode", "v_max"), "supervisor", "the autopilot's mode ignores the speed limit"),
    "would_hold": Event(("causes", *_NO_SPEED), "supervisor", "shadow mode: the causes a governor would hold for "
                        "now (with `no safe speed`: its input, as `failsafe`)"),
    "thrust_start": Event(("thrust_ratio", "vehicle_min", "table_min", "covered", "reason"), "cycle",
                          "airborne before the hover estimate of thrust_ratio settles (once per flight; again when the "
                          "estimate goes stale in flight): the value the "
                          "contract takes until then — the vehicle's lowest (`vehicle_min`) where the table covers "
                          "it (`covered`), else no safe speed (the table's lowest is `table_min`)"),
    "command": Event(("cmd", "params", "send"), "daemon", "a COMMAND_LONG sent (cmd ∈ COMMANDS; `send` > 1: the mode "
                     "authority's re-send of the same command, every cycle until answered or shown)"),
    "command_ack": Event(("command", "result"), "daemon", "the autopilot's answer to a speed or mode command"),
    "delivery": Event(("cmd", "outcome", "sends", "waited_s", "by", "why", "next"), "authority",
                      "a mode command's delivery ended (outcome: shown | refused | not shown; `why` for the last two) "
                      "or took its fallback (outcome: fallback, `next`: the mode asked instead, `why`): re-sent "
                      "every cycle until answered or shown, `sends` times, `waited_s` since the first"),
    "link": Event(("status",), "daemon", "autopilot heartbeat: up | down"),
    "startup_check": Event(("ok", "reason"), "daemon", "verdict of the start-up checks"),
    "autopilot_restart": Event(("boot_s_before", "boot_s_now"), "daemon",
                               "the autopilot's boot clock went back: the start-up checks run again"),
    "param_set": Event(("param", "old", "new"), "daemon", "a ground station set one of our parameters"),
    "param_refused": Event(("param", "value", "source", "why"), "daemon",
                           "a parameter set refused (unknown sender, unsigned over a network link, out of range, "
                           "read-only)"),
    "source_refused": Event(("what", "system", "component", "autopilot", "address", "pinned", "count", "held"), "daemon",
                            "messages refused for who sent them (docs/link-trust.md): `unknown` ids no configured "
                            "autopilot, sensor or ground station has (once per source); `refused` a pinned source's "
                            "ids from another address — a second autopilot, a spoofed sensor — (said by STATUSTEXT "
                            "and on the console; count: refused since the last such record); `moved` a source "
                            "without a configured address follows a new one after falling silent (never while `held`: engaged "
                            "or armed); `contested` two or more addresses (`address`, the seat's holder `pinned`) "
                            "claim one source: the daemon refuses to engage until `uncontested`; `bad_signature` a "
                            "signed message that does not verify under our key (a wrong key)"),
    "implausible_input": Event(("message", "why", "count"), "daemon",
                               "a message dropped as implausible (message: its type, or time_boot_ms for the "
                               "autopilot's clock; count: of this type since the last such record)"),
    "sample_dropped": Event(("kind", "error", "count"), "daemon",
                            "a message its decoder or a sample's taker complained of: dropped and counted (logged at "
                            "the 1st, 10th, 100th and every 1000th bad packet)"),
    "loop_error": Event(("error", "consecutive", "action"), "daemon",
                        "an exception inside a cycle (logged, not fatal; action: the safe action taken)"),
    "offboard": Event(("from", "to", "reason"), "offboard", "offboard controller state changed (governor mode: the "
                      "recovery brake's)"),
    "recovery_brake": Event(("available", "proven", "reason", "limit"), "cycle",
                            "governor.recovery_brake: the brake's availability changed (its start-up checks, the "
                            "switch to offboard refused or shown late), whether its switch has been shown in time in "
                            "this flight (proven: only then is its own stop contract the limit's), and the stop "
                            "contract the limit is flown under (a refusal above the autopilot's Hold's limit is also "
                            "the autopilot's violation_start)"),
    "approach_ramp": Event(("in_force", "a0_max", "accel", "why"), "supervisor",
                           "governor.approach_ramp_m_s: the ramp's bound on the Hold-start acceleration (a0_max, "
                           "m/s²) came into force (the ramp followed 3 s, measured: accel) or went out of it (its "
                           "commands no longer reach the autopilot; `why`: the autopilot accelerated harder than it "
                           "allows, also the autopilot's violation_start)"),
    "no_avoiding_plan": Event(("notes",), "offboard", "no avoiding plan: braking"),
    "back_off": Event(("inside_m", "path_m"), "offboard",
                      "a braking stop came to rest `inside_m` inside a keep-out disc (the controller's E_tr allowance "
                      "round an obstacle): the daemon backs off `path_m` along the path it flew before Hold"),
    "calibration_hold": Event(("status", "leg", "seq", "leg_speed_m_s", "speed_m_s", "distance_m", "hold_before_m",
                               "rest_s", "at_rest", "reason"), "daemon",
                              "a calibration plan's hold leg (config calibration.legs, governor mode): commanded "
                              "(speed_m_s: ground speed, distance_m: to its waypoint), resumed (rest_s at rest; "
                              "at_rest false: not at rest in time) or abandoned (reason: the daemon's own hold or "
                              "failsafe, a mode change by someone else, a command not taken)"),
    "mission": Event(("status", "why", "reason", "waypoints", "altitude_m", "items", "notes", *_MISSION_STATS),
                     "mission", "mission download: downloading | waiting_home | ready | refused"),
}

# NAMED_VALUE_FLOATs the daemon sends (2 Hz; -1 for a non-finite value): name → (state field it equals or
# None, unit, meaning)
NVF = {
    "CG_VMAX": ("v_max", "m/s", "V_max of Ω"),
    "CG_GAMMA": (None, "m/s", "Γ of Ω (v_max − v_safe; the state's gamma uses the limit in force)"),
    "CG_DOD": ("d_od", "m", "D_od"),
    "CG_ETR": ("e_tr", "m", "E_tr used"),
}

# `command` events: cmd → the MAVLink command (COMMAND_LONG) sent
COMMANDS = {
    "hold": "MAV_CMD_DO_SET_MODE",
    "change_speed": "MAV_CMD_DO_CHANGE_SPEED",
    "offboard": "MAV_CMD_DO_SET_MODE",
    "mission": "MAV_CMD_DO_SET_MODE",  # a calibration hold leg resumes the mission
    "land": "MAV_CMD_DO_SET_MODE",  # a Hold refused or not shown: the next way to stop
    "set_message_interval": "MAV_CMD_SET_MESSAGE_INTERVAL",
}
