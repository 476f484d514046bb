"""Every daemon config shipped in examples/ starts: `contract-guard run --config FILE` gets through its
config, vehicle and table to the point where it would open the link to the autopilot.

`run --check` stops there and says so; a second test runs `run` itself (no `--check`) with the link's
opening replaced by an exception, so the path the daemon takes is the one checked. Before, the
offboard-mission config stopped at "waypoints and altitude_m come from the mission with source: mission":
`run` re-validated the loaded config with every default filled in, as if the file had stated them."""

import shutil
from pathlib import Path

import pytest
import yaml

from companion import cli
from companion.onboard import link

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN_KEYS = {"arms", "scenarios"}  # campaign specs live in examples/ too; they are not daemon configs
CONFIGS = sorted(p for p in (ROOT / "examples").glob("*.yaml")
                 if not CAMPAIGN_KEYS & set(yaml.safe_load(p.read_text()) or {}))


def test_the_examples_hold_the_daemon_configs_the_docs_name():
    names = {p.name for p in CONFIGS}
    assert {"offboard-mission.yaml", "px4-udp.yaml", "ardupilot-serial.yaml", "raspberry-pi.yaml",
            "sitl-px4.yaml"} <= names


def on_this_machine(config: Path, tmp_path: Path) -> Path:
    """The config as it runs here: the Pi's /etc and /var paths moved into `tmp_path`, where its vehicle
    file (the shipped 1.6 kg quad) and a stop-contract table built for it are put."""
    text = config.read_text()
    if "/etc/contract-guard/" not in text:
        return config
    etc = tmp_path / "etc"
    etc.mkdir()
    key = etc / "signing.key"  # its signing key, as `contract-guard keys` leaves one (run --check reads it)
    key.write_text("ab" * 32 + "\n")
    key.chmod(0o600)
    shutil.copy(ROOT / "examples" / "vehicles" / "quad-1600g.yaml", etc / "vehicle.yaml")
    assert cli.main(["table", "build", "--vehicle", str(etc / "vehicle.yaml"), "--stop-only",
                     "--out", str(etc / "table.npz")]) == 0
    out = tmp_path / config.name
    out.write_text(text.replace("/etc/contract-guard/", f"{etc}/").replace("/var/", f"{tmp_path}/var/"))
    return out


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.name)
def test_run_check_starts_every_shipped_config(config, tmp_path, capsys):
    rc = cli.main(["run", "--config", str(on_this_machine(config, tmp_path)), "--check"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert "valid; its table fits" in out and "contract-guard: error" not in err


class LinkReached(Exception):
    pass


def refuse_link(*args, **kwargs):
    raise LinkReached(args[0])


@pytest.mark.parametrize("overrides", [[], ["--connect", "udpin:127.0.0.1:14999"], ["--mode", "offboard"],
                                       ["--log-dir", "cg-log"]], ids=["plain", "connect", "mode", "log-dir"])
def test_run_reaches_the_link_with_the_offboard_mission_config(overrides, monkeypatch):
    monkeypatch.setattr(link, "open_connection", refuse_link)
    with pytest.raises(LinkReached) as reached:
        cli.main(["run", "--config", str(ROOT / "examples" / "offboard-mission.yaml"), *overrides])
    assert reached.value.args[0] == (overrides[1] if overrides[:1] == ["--connect"] else "udpin:127.0.0.1:14540")


def test_an_override_is_validated_with_the_file(tmp_path, capsys):
    """`--mode governor` on a shadow config whose sensor states no rated range: one line naming the key."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text("vehicle: x500\nsensors: [{h_fov_deg: 30}]\n")
    assert cli.main(["run", "--config", str(cfg), "--check"]) == 0
    capsys.readouterr()
    assert cli.main(["run", "--config", str(cfg), "--mode", "governor", "--check"]) == cli.EXIT_USER_ERROR
    err = capsys.readouterr().err
    assert "with the command line's overrides" in err and "sensors[0].max_range_m" in err and len(err.splitlines()) == 1


def test_run_check_starts_the_own_vehicle_config_beside_its_table(tmp_path, capsys):
    """examples/vehicles/quad-1600g-sitl.yaml names its vehicle file and table relative to itself; with the
    table the guide builds (a stop-contract one here, built in seconds) it starts from any directory."""
    vehicles = tmp_path / "vehicles"
    shutil.copytree(ROOT / "examples" / "vehicles", vehicles)
    assert cli.main(["table", "build", "--vehicle", str(vehicles / "quad-1600g.yaml"), "--stop-only",
                     "--out", str(vehicles / "quad-1600g.npz")]) == 0
    capsys.readouterr()
    assert cli.main(["run", "--config", str(vehicles / "quad-1600g-sitl.yaml"), "--check"]) == 0
    out = capsys.readouterr().out
    assert f"vehicle quad-1600g, table {vehicles / 'quad-1600g.npz'}" in out
    assert f"event log {vehicles / 'quad-1600g-log'}" in out


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.name)
def test_every_shipped_config_says_how_its_link_takes_the_autopilot(config, tmp_path, capsys):
    """Each shipped daemon config is pinned, loopback only or a peer link (serial, udpout): none listens on the
    network for whoever speaks first, and the banner says which it is."""
    assert cli.main(["run", "--config", str(on_this_machine(config, tmp_path)), "--check"]) == 0
    out = capsys.readouterr().out
    [line] = [ln for ln in out.splitlines() if ln.startswith("link: ")]
    assert "OPEN" not in line and "REFUSING TO ENGAGE: unsigned" not in out, out
    assert line.startswith(("link: pinned to ", "link: loopback only", "link: /dev/", "link: udpout:127.0.0.1")), line
