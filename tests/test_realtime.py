"""Real-time setup: warn when not permitted, refuse in enforce mode, GC frozen and restored."""

from __future__ import annotations

import errno
import gc
import logging
import os
import subprocess
import sys
import textwrap

import pytest

from capstan.controller.runtime import realtime
from capstan.controller.runtime.realtime import RealtimeMode, RealtimeSettings
from capstan.models.common.errors import RealtimeError


def _deny_sched(pid: int, policy: int, param: object) -> None:
    raise PermissionError(errno.EPERM, "Operation not permitted")


CALLS: list[tuple[int, int]] = []


def _ok_sched(pid: int, policy: int, param: object) -> None:
    CALLS.append((policy, param.sched_priority))  # type: ignore[attr-defined]


def _ok_aff(pid: int, cpus: object) -> None:
    pass


@pytest.fixture(autouse=True)
def _restore_gc():
    interval = sys.getswitchinterval()
    yield
    gc.unfreeze()
    gc.enable()
    sys.setswitchinterval(interval)


def test_parse_mode() -> None:
    assert RealtimeMode.parse("enforce") is RealtimeMode.ENFORCE
    with pytest.raises(ValueError, match="strict"):
        RealtimeMode.parse("strict")


def test_all_permitted() -> None:
    CALLS.clear()
    s = RealtimeSettings(cpus=(0,))
    rep = realtime.prepare(s, mlockall=lambda f: 0, setscheduler=_ok_sched)
    assert rep.mlock and rep.gc_frozen and not rep.fifo      # FIFO only probed (set and undone)
    assert CALLS[0] == (os.SCHED_FIFO, 80) and CALLS[1][0] == os.sched_getscheduler(0)
    assert not gc.isenabled() and gc.get_freeze_count() > 0
    realtime.apply(s, rep, setscheduler=_ok_sched, setaffinity=_ok_aff)
    assert rep.fifo and rep.affinity and not rep.failures
    assert CALLS[-1] == (os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, 80)   # children do not inherit it
    assert sys.getswitchinterval() == pytest.approx(200e-6)
    realtime.restore(rep)
    assert gc.isenabled() and gc.get_freeze_count() == 0


def test_warn_mode_logs_each_failed_step_once_and_continues(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="capstan.controller.runtime.realtime")
    s = RealtimeSettings(mode=RealtimeMode.WARN)
    rep = realtime.prepare(s, mlockall=lambda f: errno.ENOMEM, setscheduler=_deny_sched)
    realtime.apply(s, rep, setscheduler=_deny_sched, setaffinity=_ok_aff)
    assert not rep.fifo and not rep.mlock and rep.gc_frozen
    text = caplog.text
    assert text.count("SCHED_FIFO priority 80 not permitted") == 1
    assert "mlockall failed" in text and "memory" in text.lower()


def test_enforce_mode_refuses_in_prepare_before_any_device_starts() -> None:
    with pytest.raises(RealtimeError, match="SCHED_FIFO"):
        realtime.prepare(RealtimeSettings(mode=RealtimeMode.ENFORCE), mlockall=lambda f: 0,
                         setscheduler=_deny_sched)
    assert gc.isenabled()                     # refused before freezing anything
    with pytest.raises(RealtimeError, match="mlockall"):
        realtime.prepare(RealtimeSettings(mode=RealtimeMode.ENFORCE), mlockall=lambda f: errno.EPERM,
                         setscheduler=_ok_sched)


def test_enforce_mode_rejects_missing_cpu() -> None:
    def bad_aff(pid: int, cpus: object) -> None:
        raise OSError(errno.EINVAL, "Invalid argument")
    s = RealtimeSettings(mode=RealtimeMode.ENFORCE, cpus=(7,))
    rep = realtime.prepare(s, mlockall=lambda f: 0, setscheduler=_ok_sched)
    with pytest.raises(RealtimeError, match=r"CPU affinity \[7\]"):
        realtime.apply(s, rep, setscheduler=_ok_sched, setaffinity=bad_aff)
    assert gc.isenabled()                     # the refusal undid the GC freeze


def test_off_mode_touches_no_scheduling() -> None:
    def boom(*a: object) -> None:
        raise AssertionError("must not be called")
    s = RealtimeSettings(mode=RealtimeMode.OFF)
    rep = realtime.prepare(s, mlockall=boom, setscheduler=boom)  # type: ignore[arg-type]
    realtime.apply(s, rep, setscheduler=boom, setaffinity=boom)
    assert rep.gc_frozen and not rep.fifo


_CHILD = textwrap.dedent("""
    import os, sys
    from capstan.controller.runtime import realtime
    from capstan.controller.runtime.realtime import RealtimeMode, RealtimeSettings
    from capstan.models.common.errors import RealtimeError
    if os.getuid() == 0:
        os.setgroups([]); os.setgid(65534); os.setuid(65534)   # an unprivileged user
    mode = RealtimeMode.parse(sys.argv[1])
    try:
        s = RealtimeSettings(mode=mode, priority=50, lock_memory=False)
        rep = realtime.apply(s, realtime.prepare(s))
    except RealtimeError as exc:
        print("REFUSED", exc); sys.exit(3)
    print("FIFO", rep.fifo, os.sched_getscheduler(0) == os.SCHED_FIFO)
""")


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="Linux only")
@pytest.mark.parametrize("mode", ["warn", "enforce"])
def test_real_unprivileged_process(mode: str) -> None:
    """Without the privilege the real kernel call fails: warn keeps running, enforce refuses."""
    if os.getuid() != 0:
        pytest.skip("needs root to drop to an unprivileged user")
    import resource
    soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
    if soft != 0:
        pytest.skip("RLIMIT_RTPRIO permits SCHED_FIFO for every user here")
    res = subprocess.run([sys.executable, "-c", _CHILD, mode], capture_output=True, text=True, timeout=30)
    if mode == "warn":
        assert res.returncode == 0, res.stderr
        assert "FIFO False False" in res.stdout
        assert "not permitted" in res.stderr
    else:
        assert res.returncode == 3
        assert "REFUSED" in res.stdout and "SCHED_FIFO priority 50" in res.stdout


def test_real_privileged_process_gets_fifo_and_mlock() -> None:
    if os.getuid() != 0:
        pytest.skip("needs CAP_SYS_NICE")
    code = ("from capstan.controller.runtime import realtime as r; import os;"
            "s = r.RealtimeSettings(mode=r.RealtimeMode.ENFORCE, priority=10, cpus=(0,));"
            "rep = r.apply(s, r.prepare(s));"
            "print(rep.fifo, rep.mlock, os.sched_getscheduler(0) == os.SCHED_FIFO | os.SCHED_RESET_ON_FORK,"
            " os.sched_getaffinity(0))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["True", "True", "True", "{0}"]
