"""systemd integration: the `sd_notify` datagram protocol (readiness, watchdog, status, stopping).

The protocol is tiny (one `KEY=VALUE\\n…` datagram to the AF_UNIX socket named in `$NOTIFY_SOCKET`; a
leading `@` names an abstract socket), so it is spoken directly with no dependency. Every method is a
no-op when `$NOTIFY_SOCKET` is unset (not started by systemd, tests, `contract-guard demo`) and none
raises: a failed send is counted in `Notifier.errors` and returns False.

The daemon's duty: call `ready()` once it is running (table loaded, loop started;
the autopilot link may still be connecting), then `watchdog()` from the loop **only while the loop is
healthy** — at least every `watchdog_interval_s()` (`WatchdogFeeder` does the rate limiting) — so that
systemd restarts a daemon whose loop hangs or keeps failing (`WatchdogSec=` in the unit). `status(text)` shows a one-line state in
`systemctl status`; `stopping()` before a clean exit.
"""

from __future__ import annotations

import os
import socket

MAX_STATUS = 512  # systemd accepts more; a status line longer than this is not readable anyway


def watchdog_usec_from_env(environ=None, pid: int | None = None) -> int | None:
    """The watchdog period [µs] systemd asked for, or None (unset, not for this process, or malformed)."""
    env = os.environ if environ is None else environ
    try:
        usec = int(env.get("WATCHDOG_USEC", ""))
    except ValueError:
        return None
    wpid = env.get("WATCHDOG_PID")
    if wpid:
        try:
            if int(wpid) != (os.getpid() if pid is None else pid):
                return None
        except ValueError:
            return None
    return usec if usec > 0 else None


def _one_line(text: str) -> str:
    return " ".join(str(text).split())[:MAX_STATUS]


class Notifier:
    """Sends sd_notify messages to `$NOTIFY_SOCKET` (or `socket_path`); silent when there is none."""

    def __init__(self, socket_path: str | None = None, environ=None):
        env = os.environ if environ is None else environ
        path = socket_path if socket_path is not None else env.get("NOTIFY_SOCKET", "")
        self.address: str | bytes | None = None
        if path.startswith("@"):
            self.address = "\0" + path[1:]
        elif path.startswith("/"):
            self.address = path
        self.watchdog_usec = watchdog_usec_from_env(env)
        self.errors = 0
        self.sent = 0
        self.last_error: str | None = None
        self._sock: socket.socket | None = None

    @property
    def enabled(self) -> bool:
        return self.address is not None

    def watchdog_interval_s(self) -> float | None:
        """How often to call `watchdog()` [s]: half of `WatchdogSec=` (as sd_watchdog_enabled advises)."""
        return None if self.watchdog_usec is None else self.watchdog_usec / 2e6

    def notify(self, message: str) -> bool:
        """Send one raw message (`KEY=VALUE` lines); True when sent, False when disabled or failed."""
        if self.address is None:
            return False
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.sendto(message.encode("utf-8", "replace"), self.address)
            self.sent += 1
            return True
        except Exception as err:  # noqa: BLE001 — systemd going away must not stop the loop
            self.errors += 1
            self.last_error = f"{type(err).__name__}: {err}"
            self.close()
            return False

    def ready(self, status: str | None = None) -> bool:
        """READY=1 (Type=notify: systemd considers the start finished), with an optional status line."""
        return self.notify("READY=1" + (f"\nSTATUS={_one_line(status)}" if status else ""))

    def watchdog(self) -> bool:
        """WATCHDOG=1 — call only while the loop is healthy."""
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        """STATUS=… shown by `systemctl status` (newlines folded to spaces)."""
        return self.notify(f"STATUS={_one_line(text)}")

    def stopping(self, status: str | None = None) -> bool:
        """STOPPING=1 before a clean exit."""
        return self.notify("STOPPING=1" + (f"\nSTATUS={_one_line(status)}" if status else ""))

    def extend_timeout(self, seconds: float) -> bool:
        """EXTEND_TIMEOUT_USEC=… while a slow start-up (or stop) is still making progress."""
        return self.notify(f"EXTEND_TIMEOUT_USEC={max(int(seconds * 1e6), 0)}")

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass


class WatchdogFeeder:
    """Rate-limits `WATCHDOG=1` from a 50 Hz loop: `tick(healthy)` pings at most every `period_s` and never
    while unhealthy, so systemd's watchdog fires once the loop has been unhealthy (or hung) for `WatchdogSec`.

    "Healthy" is the daemon's call (the loop ran on time and its inputs were processed). A failing event
    log is *not* a reason to starve the watchdog: a restart would not free the disk (DESIGN.md §5).
    """

    def __init__(self, notifier: Notifier, clock, period_s: float | None = None):
        self.notifier, self.clock = notifier, clock
        self.period_s = period_s if period_s is not None else notifier.watchdog_interval_s()
        self._last: float | None = None

    def tick(self, healthy: bool) -> bool:
        """True when a ping was sent now."""
        if not healthy or self.period_s is None:
            return False
        now = self.clock()
        if self._last is not None and now - self._last < self.period_s:
            return False
        self._last = now
        return self.notifier.watchdog()
