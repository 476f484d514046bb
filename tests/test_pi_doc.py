"""Issue 13 item 12: docs/raspberry-pi.md agrees with systemd/contract-guard.service, its drop-in and the
example config it installs — paths, user, ExecStart, the config/vehicle/table/key locations and
RestartPreventExitStatus — so the page cannot drift from the unit. (Before: the page was untested.)"""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = (ROOT / "docs" / "raspberry-pi.md").read_text()


def unit(path: Path) -> dict[str, list[str]]:
    """A systemd unit's settings (a key may repeat; an empty assignment resets it, as systemd does)."""
    out: dict[str, list[str]] = {}
    for ln in path.read_text().splitlines():
        ln = ln.strip()
        if not ln or ln.startswith(("#", ";", "[")) or "=" not in ln:
            continue
        k, v = ln.split("=", 1)
        if v == "":
            out[k] = []
        else:
            out.setdefault(k, []).append(v)
    return out


def test_the_page_matches_the_unit():
    u = unit(ROOT / "systemd" / "contract-guard.service")
    exe, *args = u["ExecStart"][0].split()
    assert exe == "/usr/bin/contract-guard" and args[:2] == ["run", "--config"]
    config = args[2]
    assert f"ln -s /opt/contract-guard/venv/bin/contract-guard {exe}" in DOC
    assert "/etc/contract-guard/config.yaml" == config and f"install -m 0640 -g contract-guard examples/raspberry-pi.yaml {config}" in DOC
    user, group = u["User"][0], u["Group"][0]
    assert f"--user-group {user}" in DOC and user == group
    for g in u["SupplementaryGroups"]:
        assert f"usermod -aG {g} {user}" in DOC
    assert u["RestartPreventExitStatus"] == ["2"] and "RestartPreventExitStatus=2" in DOC
    assert u["ProtectHome"] == ["yes"] and "outside /home" in DOC
    assert f"/var/lib/{u['StateDirectory'][0]}" in DOC and f"/var/log/{u['LogsDirectory'][0]}" in DOC
    assert "install -m 0644 systemd/contract-guard.service /etc/systemd/system/" in DOC
    assert "journalctl -u contract-guard" in DOC


def test_the_drop_in_points_at_the_pages_venv():
    d = unit(ROOT / "systemd" / "contract-guard.conf.example")
    exe, *args = d["ExecStart"][0].split()
    assert exe == "/opt/contract-guard/venv/bin/contract-guard" and f"sudo python3 -m venv {exe.rsplit('/bin/', 1)[0]}" in DOC
    assert args[2] == unit(ROOT / "systemd" / "contract-guard.service")["ExecStart"][0].split()[3]


def test_the_example_config_uses_only_paths_the_service_may_use():
    from companion.onboard.config import load_config

    u = unit(ROOT / "systemd" / "contract-guard.service")
    cfg = load_config(ROOT / "examples" / "raspberry-pi.yaml")
    conf_dir = f"/etc/{u['ConfigurationDirectory'][0]}"
    state_dir, logs_dir = f"/var/lib/{u['StateDirectory'][0]}", f"/var/log/{u['LogsDirectory'][0]}"
    for read_only in (cfg.vehicle, cfg.table, cfg.link.signing_key_file):
        assert str(read_only).startswith(conf_dir + "/") and str(read_only) in DOC, read_only
    assert str(cfg.log.dir) == logs_dir  # writable: LogsDirectory
    assert str(cfg.link.signing_timestamp_file).startswith(state_dir + "/")  # writable: StateDirectory
    assert str(cfg.link.signing_timestamp_file) in DOC
    assert cfg.link.connect in DOC and cfg.mode == "shadow"
