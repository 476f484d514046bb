"""Relative paths in a daemon config are relative to the config file's directory, not to the directory the
daemon happens to be started in (systemd starts it in /, a person in the repository or their home).
Before, `vehicle: quad.yaml` beside the config was looked up in the working directory."""

import os
import shutil
from pathlib import Path

from companion import cli
from companion.onboard.config import load_config

ROOT = Path(__file__).resolve().parents[1]


def own_vehicle_dir(tmp_path: Path) -> Path:
    """A directory as a team keeps one aircraft: vehicle file, its stop table, calibration legs, config."""
    d = tmp_path / "aircraft"
    d.mkdir()
    shutil.copy(ROOT / "examples" / "vehicles" / "quad-1600g.yaml", d / "quad.yaml")
    assert cli.main(["table", "build", "--vehicle", str(d / "quad.yaml"), "--stop-only",
                     "--out", str(d / "quad.npz")]) == 0
    assert cli.main(["calibrate", "plan", "--vehicle", "x500", "--out", str(d / "cal")]) == 0
    (d / "config.yaml").write_text(
        "vehicle: quad.yaml\ntable: quad.npz\nmode: governor\n"
        "sensors: [{h_fov_deg: 60, max_range_m: 8}]\ncontract: {e_tr_assumed_m: 0.5}\n"
        "calibration: {legs: cal/calibration-legs.json}\n"
        "link: {signing_key_file: keys/signing.key, signing_timestamp_file: /var/lib/cg/signing.ts}\n"
        "log: {dir: logs}\n")
    (d / "keys").mkdir()
    (d / "keys" / "signing.key").write_text("ab" * 32 + "\n")  # run --check reads it, as run does
    (d / "keys" / "signing.key").chmod(0o600)
    return d


def test_paths_resolve_against_the_config_files_directory(tmp_path, monkeypatch, capsys):
    d = own_vehicle_dir(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    cfg = load_config(Path("..") / "aircraft" / "config.yaml")
    assert Path(cfg.vehicle).resolve() == d / "quad.yaml" and cfg.table.resolve() == d / "quad.npz"
    assert cfg.log.dir.resolve() == d / "logs"
    assert cfg.calibration.legs.resolve() == d / "cal" / "calibration-legs.json"
    assert cfg.link.signing_key_file.resolve() == d / "keys" / "signing.key"
    assert cfg.link.signing_timestamp_file == Path("/var/lib/cg/signing.ts")  # absolute: as written
    capsys.readouterr()
    assert cli.main(["run", "--config", str(Path("..") / "aircraft" / "config.yaml"), "--check"]) == 0
    assert "vehicle quad-1600g, table ../aircraft/quad.npz" in capsys.readouterr().out


def test_a_shipped_vehicle_name_stays_a_name(tmp_path):
    (tmp_path / "c.yaml").write_text("vehicle: x500\n")
    assert load_config(tmp_path / "c.yaml").vehicle == "x500"


def test_a_command_line_log_dir_is_the_working_directorys(tmp_path, monkeypatch, capsys):
    d = own_vehicle_dir(tmp_path)
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    assert cli.main(["run", "--config", str(d / "config.yaml"), "--log-dir", "here-log", "--check"]) == 0
    out = capsys.readouterr().out
    assert "event log here-log" in out and os.fspath(d / "quad.npz") in out
