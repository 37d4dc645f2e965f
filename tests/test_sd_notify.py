"""sd_notify against a real AF_UNIX datagram socket (path and abstract namespace)."""

from __future__ import annotations

import os
import socket
from pathlib import Path

import pytest

from capstan.controller.runtime.sd_notify import SdNotifier


def _server(addr: str | bytes) -> socket.socket:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(addr)
    s.settimeout(2.0)
    return s


def test_path_socket_receives_ready_watchdog_status_stopping(tmp_path: Path) -> None:
    path = str(tmp_path / "notify")
    srv = _server(path)
    n = SdNotifier({"NOTIFY_SOCKET": path})
    assert n.enabled
    assert n.ready("enabled, sensors healthy")
    assert srv.recv(4096) == b"READY=1\nSTATUS=enabled, sensors healthy"
    assert n.watchdog()
    assert srv.recv(4096) == b"WATCHDOG=1"
    assert n.status("jitter p99 3 us\nsecond line")
    assert srv.recv(4096) == b"STATUS=jitter p99 3 us second line"
    assert n.stopping()
    assert srv.recv(4096) == b"STOPPING=1"
    n.close()
    srv.close()


def test_abstract_namespace_socket() -> None:
    name = f"capstan-test-{os.getpid()}"
    srv = _server(b"\0" + name.encode())
    n = SdNotifier({"NOTIFY_SOCKET": "@" + name})
    assert n.ready()
    assert srv.recv(4096) == b"READY=1"
    n.close()
    srv.close()


def test_without_socket_everything_is_a_noop() -> None:
    n = SdNotifier({})
    assert not n.enabled and n.watchdog_interval_s is None and n.ping_interval_s is None
    assert n.ready() is False and n.watchdog() is False


def test_send_error_is_counted_not_raised(tmp_path: Path) -> None:
    n = SdNotifier({"NOTIFY_SOCKET": str(tmp_path / "nobody-listens")})
    assert n.ready() is False and n.watchdog() is False
    assert n.errors == 2


@pytest.mark.parametrize("env, expected", [
    ({"WATCHDOG_USEC": "2000000"}, 2.0),
    ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(os.getpid())}, 2.0),
    ({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "1"}, None),   # for another process
    ({"WATCHDOG_USEC": "zero"}, None),
    ({"WATCHDOG_USEC": "0"}, None),
])
def test_watchdog_interval_from_environment(env: dict[str, str], expected: float | None) -> None:
    n = SdNotifier(env)
    assert n.watchdog_interval_s == expected
    if expected is not None:
        assert n.ping_interval_s == pytest.approx(expected / 2)
