"""sd_notify against a real AF_UNIX datagram socket; the systemd unit against `systemd-analyze verify`."""

import os
import re
import shutil
import socket
import subprocess
from pathlib import Path

import pytest

from companion.onboard.service import Notifier, watchdog_usec_from_env

ROOT = Path(__file__).resolve().parents[1]
UNIT = ROOT / "systemd" / "contract-guard.service"
DROPIN = ROOT / "systemd" / "contract-guard.conf.example"


@pytest.fixture
def notify_socket(tmp_path):
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = tmp_path / "notify.sock"
    sock.bind(str(path))
    sock.settimeout(2.0)
    yield str(path), sock
    sock.close()


def recv(sock):
    return sock.recv(4096).decode()


def test_messages_reach_the_socket(notify_socket):
    path, sock = notify_socket
    n = Notifier(environ={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "5000000"})
    assert n.enabled and n.watchdog_interval_s() == 2.5
    assert n.ready("loop running, link connecting")
    assert recv(sock) == "READY=1\nSTATUS=loop running, link connecting"
    assert n.watchdog() and recv(sock) == "WATCHDOG=1"
    assert n.status("governor: V_max 3.20 m/s\nΓ -0.1") and recv(sock) == "STATUS=governor: V_max 3.20 m/s Γ -0.1"
    assert n.extend_timeout(20) and recv(sock) == "EXTEND_TIMEOUT_USEC=20000000"
    assert n.stopping() and recv(sock) == "STOPPING=1"
    assert n.sent == 5 and n.errors == 0
    n.close()


def test_abstract_socket_address():
    name = f"cg-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2.0)
    try:
        n = Notifier(environ={"NOTIFY_SOCKET": "@" + name})
        assert n.ready() and recv(sock) == "READY=1"
    finally:
        sock.close()


def test_no_socket_means_no_ops():
    n = Notifier(environ={})
    assert not n.enabled and n.watchdog_interval_s() is None
    assert (n.ready(), n.watchdog(), n.status("x"), n.stopping()) == (False,) * 4
    assert n.errors == 0 and n.sent == 0
    assert not Notifier(environ={"NOTIFY_SOCKET": "relative/path"}).enabled


def test_a_vanished_socket_is_counted_not_raised(notify_socket, tmp_path):
    path, sock = notify_socket
    n = Notifier(environ={"NOTIFY_SOCKET": path})
    assert n.watchdog() and recv(sock) == "WATCHDOG=1"
    sock.close()
    os.unlink(path)
    assert n.watchdog() is False and n.errors == 1 and "FileNotFoundError" in n.last_error
    assert Notifier(environ={"NOTIFY_SOCKET": str(tmp_path / "never")}).ready() is False


@pytest.mark.parametrize(
    "env, expected",
    [
        ({"WATCHDOG_USEC": "4000000"}, 4_000_000),
        ({"WATCHDOG_USEC": "4000000", "WATCHDOG_PID": "123"}, 4_000_000),
        ({"WATCHDOG_USEC": "4000000", "WATCHDOG_PID": "124"}, None),  # meant for another process
        ({"WATCHDOG_USEC": "zero"}, None),
        ({"WATCHDOG_USEC": "0"}, None),
        ({}, None),
    ],
)
def test_watchdog_period_from_environment(env, expected):
    assert watchdog_usec_from_env(env, pid=123) == expected


# ============================================================================ the unit file


def test_unit_has_the_required_settings():
    text = UNIT.read_text()
    svc = {}
    for line in text.splitlines():
        if "=" in line and not line.lstrip().startswith(("#", ";", "[")):
            k, v = line.split("=", 1)
            svc.setdefault(k.strip(), []).append(v.strip())
    required = {
        "Type": "notify", "Restart": "on-failure", "User": "contract-guard", "SupplementaryGroups": "dialout",
        "StateDirectory": "contract-guard", "LogsDirectory": "contract-guard",
        "ConfigurationDirectory": "contract-guard", "ProtectSystem": "strict", "ProtectHome": "yes",
        "PrivateTmp": "yes", "NoNewPrivileges": "yes", "DevicePolicy": "closed", "NotifyAccess": "main",
        "Nice": "-10", "CPUWeight": "1000",  # its share of a contended CPU, within and across cgroups
        "CPUSchedulingPolicy": "fifo", "CPUSchedulingResetOnFork": "yes",  # its cycles on time, its planner not
    }
    for k, v in required.items():
        assert svc.get(k) == [v], k
    assert svc["ExecStart"] == ["/usr/bin/contract-guard run --config /etc/contract-guard/config.yaml"]
    assert re.fullmatch(r"\d+s?", svc["WatchdogSec"][0])
    assert set(svc["RestrictAddressFamilies"][0].split()) == {"AF_UNIX", "AF_INET", "AF_INET6"}
    assert any(v.startswith("char-ttyUSB") for v in svc["DeviceAllow"])


def verify(unit_dir: Path, unit_name: str):
    return subprocess.run(["systemd-analyze", "verify", "--man=no", str(unit_dir / unit_name)],
                          capture_output=True, text=True, timeout=60)


def relocated(src: Path, dst: Path, exe: Path):
    """A copy whose ExecStart points at `exe` (systemd-analyze verify checks that the binary exists)."""
    dst.write_text(src.read_text().replace("/usr/bin/contract-guard", str(exe)).replace(
        "/opt/contract-guard/venv/bin/contract-guard", str(exe)))


@pytest.fixture
def fake_exe(tmp_path):
    exe = tmp_path / "contract-guard"
    exe.write_text("#!/bin/sh\nexit 0\n")
    exe.chmod(0o755)
    return exe


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed here")
def test_unit_passes_systemd_analyze_verify(tmp_path, fake_exe):
    """Verifies a copy whose ExecStart points at a stand-in executable (the real one is not installed)."""
    d = tmp_path / "units"
    d.mkdir()
    relocated(UNIT, d / "contract-guard.service", fake_exe)
    r = verify(d, "contract-guard.service")
    problems = [ln for ln in (r.stdout + r.stderr).splitlines() if ln.strip()]
    assert r.returncode == 0 and problems == [], "\n".join(problems)


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed here")
def test_unit_with_the_dropin_example_passes_verify(tmp_path, fake_exe):
    d = tmp_path / "units"
    (d / "contract-guard.service.d").mkdir(parents=True)
    relocated(UNIT, d / "contract-guard.service", fake_exe)
    relocated(DROPIN, d / "contract-guard.service.d" / "override.conf", fake_exe)
    env = dict(os.environ, SYSTEMD_UNIT_PATH=f"{d}:")
    r = subprocess.run(["systemd-analyze", "verify", "--man=no", "contract-guard.service"], capture_output=True,
                       text=True, timeout=60, env=env)
    problems = [ln for ln in (r.stdout + r.stderr).splitlines() if ln.strip()]
    assert r.returncode == 0 and problems == [], "\n".join(problems)
    # the drop-in really was read: a typo in it must fail the same check
    (d / "contract-guard.service.d" / "override.conf").write_text("[Service]\nWatchdogSecc=3\n")
    r = subprocess.run(["systemd-analyze", "verify", "--man=no", "contract-guard.service"], capture_output=True,
                       text=True, timeout=60, env=env)
    assert "WatchdogSecc" in r.stdout + r.stderr


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed here")
def test_verify_catches_a_broken_unit(tmp_path, fake_exe):
    """Negative control: the check above can fail."""
    d = tmp_path / "units"
    d.mkdir()
    relocated(UNIT, d / "contract-guard.service", fake_exe)
    p = d / "contract-guard.service"
    p.write_text(p.read_text().replace("Type=notify", "Type=notifyy"))
    r = verify(d, "contract-guard.service")
    assert "notifyy" in r.stdout + r.stderr


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed here")
def test_sandboxing_exposure_stays_low(tmp_path, fake_exe):
    """`systemd-analyze security --offline` scores exposure 0 (locked down) … 10; this unit scores 1.6 (systemd 252)."""
    d = tmp_path / "units"
    d.mkdir()
    relocated(UNIT, d / "contract-guard.service", fake_exe)
    r = subprocess.run(["systemd-analyze", "security", "--offline=yes", "--threshold=25", "--no-pager",
                        str(d / "contract-guard.service")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr
    m = re.search(r"Overall exposure level for contract-guard.service: (\d+\.\d+)", r.stdout + r.stderr)
    assert m and float(m.group(1)) <= 2.5, (r.stdout + r.stderr)[-500:]


def test_watchdog_feeder_pings_at_half_the_period_and_only_while_healthy(notify_socket):
    from companion.onboard.service import WatchdogFeeder

    path, sock = notify_socket
    clock = {"t": 0.0}
    feeder = WatchdogFeeder(Notifier(environ={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000"}), lambda: clock["t"])
    sent = []
    for i in range(250):  # 5 s of a 50 Hz loop; unhealthy from 2.0 s to 4.0 s
        clock["t"] = i * 0.02
        if feeder.tick(healthy=not (2.0 <= clock["t"] < 4.0)):
            sent.append(round(clock["t"], 2))
    assert sent == [0.0, 1.0, 4.0]
    assert [recv(sock) for _ in sent] == ["WATCHDOG=1"] * 3
    assert WatchdogFeeder(Notifier(environ={}), lambda: 0.0).tick(True) is False  # no watchdog configured
