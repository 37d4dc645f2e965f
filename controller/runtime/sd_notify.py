"""systemd readiness/watchdog notification (the ``sd_notify`` protocol, no libsystemd).

systemd passes ``NOTIFY_SOCKET`` (a filesystem path, or ``@name`` for the Linux
abstract namespace) and, with ``WatchdogSec=``, ``WATCHDOG_USEC`` (and
``WATCHDOG_PID``). Messages are newline-separated ``KEY=VALUE`` datagrams on an
AF_UNIX SOCK_DGRAM socket: ``READY=1``, ``WATCHDOG=1``, ``STATUS=...``, ``STOPPING=1``.

Sending never blocks (``MSG_DONTWAIT``) and never raises: without a notify socket
(run by hand) every call is a no-op; a send error is counted and logged once.
"""

from __future__ import annotations

import logging
import os
import socket
from typing import Mapping

log = logging.getLogger(__name__)


def _address(raw: str) -> str | bytes:
    """Socket address from NOTIFY_SOCKET: ``@x`` -> abstract ``\\0x``."""
    if raw.startswith("@"):
        return b"\0" + raw[1:].encode()
    return raw


class SdNotifier:
    """Notifier bound to the environment's NOTIFY_SOCKET (or an explicit one).

    :param environ: environment to read (default ``os.environ``).
    """

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        raw = env.get("NOTIFY_SOCKET", "")
        self._addr: str | bytes | None = _address(raw) if raw else None
        self._sock: socket.socket | None = None
        if self._addr is not None:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
        self.errors = 0
        self.watchdog_interval_s = self._watchdog(env)

    @staticmethod
    def _watchdog(env: Mapping[str, str]) -> float | None:
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        if not usec:
            return None
        if pid and pid.isdigit() and int(pid) != os.getpid():
            return None  # meant for another process
        try:
            v = int(usec)
        except ValueError:
            log.warning("ignoring malformed WATCHDOG_USEC=%r", usec)
            return None
        return v * 1e-6 if v > 0 else None

    @property
    def enabled(self) -> bool:
        """True when a notify socket is configured."""
        return self._sock is not None

    @property
    def ping_interval_s(self) -> float | None:
        """How often to send WATCHDOG=1: half the watchdog interval (None: no watchdog)."""
        return None if self.watchdog_interval_s is None else self.watchdog_interval_s / 2.0

    def notify(self, message: str) -> bool:
        """Send one datagram; True if sent (False without socket or on error)."""
        if self._sock is None or self._addr is None:
            return False
        try:
            self._sock.sendto(message.encode(), socket.MSG_DONTWAIT, self._addr)
            return True
        except OSError as exc:
            self.errors += 1
            if self.errors == 1:
                log.warning("sd_notify to %r failed: %s", self._addr, exc)
            return False

    def ready(self, status: str = "") -> bool:
        """READY=1 (plus a STATUS line if given)."""
        return self.notify("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def watchdog(self) -> bool:
        """WATCHDOG=1 — only call while the loop is healthy."""
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        """STATUS=<one line> shown by ``systemctl status``."""
        return self.notify("STATUS=" + text.replace("\n", " "))

    def stopping(self, status: str = "") -> bool:
        """STOPPING=1 at the start of shutdown."""
        return self.notify("STOPPING=1" + (f"\nSTATUS={status}" if status else ""))

    def close(self) -> None:
        """Close the socket."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
