"""Real-time setup of the loop's process and thread.

Two stages, because locking memory is slow and scheduling must not leak:

:func:`prepare` (before the drive is enabled; may take seconds)
  - ``mlockall(MCL_CURRENT | MCL_FUTURE)`` through ctypes, so no page fault in the loop;
  - a probe that SCHED_FIFO at the configured priority is permitted (set and undone);
  - ``gc.collect(); gc.freeze(); gc.disable()`` — existing objects move to the permanent
    generation and no collection pause can hit a cycle (:func:`restore` undoes it).

:func:`apply` (right before the first cycle; microseconds)
  - CPU affinity (``os.sched_setaffinity``) of the loop thread;
  - SCHED_FIFO with SCHED_RESET_ON_FORK for the loop thread only — driver threads
    started earlier (the CAN receive thread) and child processes (the log writer)
    keep normal scheduling and do not compete at real-time priority;
  - a short GIL switch interval, bounding how long another Python thread of the process
    can keep the loop thread waiting for the GIL after it wakes.

When a step is not permitted (no CAP_SYS_NICE / RLIMIT_RTPRIO, memlock limit, CPU not
present), :attr:`RealtimeMode.WARN` logs one clear warning per step and carries on;
:attr:`RealtimeMode.ENFORCE` raises :class:`capstan.models.common.errors.RealtimeError` naming every
step that failed — already in :func:`prepare`, before any torque can flow;
:attr:`RealtimeMode.OFF` does nothing but the GC freeze.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
import os
import sys
import threading
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, Callable

from capstan.models.common.errors import RealtimeError

log = logging.getLogger(__name__)

MCL_CURRENT = 1
MCL_FUTURE = 2


class RealtimeMode(IntEnum):
    """How strictly real-time scheduling is required."""

    OFF = 0
    WARN = 1
    ENFORCE = 2

    @staticmethod
    def parse(name: str) -> "RealtimeMode":
        """``"off" | "warn" | "enforce"`` -> mode.

        :raises ValueError: on any other name.
        """
        try:
            return RealtimeMode[name.upper()]
        except KeyError:
            raise ValueError(f"unknown realtime mode {name!r}; one of off, warn, enforce") from None


@dataclass(frozen=True)
class RealtimeSettings:
    """:ivar mode: see :class:`RealtimeMode`.
    :ivar priority: SCHED_FIFO priority 1..99.
    :ivar cpus: CPUs to pin to (empty: leave the affinity alone).
    :ivar lock_memory: call mlockall.
    :ivar gil_switch_interval_s: ``sys.setswitchinterval`` value [s] (0: leave as is).
    :ivar helper_priority: SCHED_FIFO priority of the process's other threads (below
        ``priority``; 0: leave them alone), see :func:`apply_to_threads`.
    """

    mode: RealtimeMode = RealtimeMode.WARN
    priority: int = 80
    cpus: tuple[int, ...] = ()
    lock_memory: bool = True
    gil_switch_interval_s: float = 200e-6
    helper_priority: int = 0


@dataclass
class RealtimeReport:
    """What :func:`apply` achieved; ``failures`` holds one readable line per failed step."""

    fifo: bool = False
    mlock: bool = False
    affinity: bool = False
    gc_frozen: bool = False
    failures: list[str] = field(default_factory=list)
    warned: list[str] = field(default_factory=list)
    prev_switch_interval_s: float = 0.0
    prev_gc_enabled: bool = True


def _default_mlockall() -> Callable[[int], int]:
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    fn = libc.mlockall
    fn.argtypes = [ctypes.c_int]
    fn.restype = ctypes.c_int

    def mlockall(flags: int) -> int:
        if fn(flags) != 0:
            return ctypes.get_errno()
        return 0
    return mlockall


def prepare(settings: RealtimeSettings, *, mlockall: Callable[[int], int] | None = None,
            setscheduler: Callable[[int, int, Any], None] | None = None) -> RealtimeReport:
    """The slow part, before the drive is enabled: mlockall (can take seconds in a large
    process), a probe that SCHED_FIFO is permitted, then the GC freeze.

    The system calls are injectable for tests (``mlockall(flags) -> errno`` and the
    ``os.sched_setscheduler`` signature).

    :raises RealtimeError: in ENFORCE mode if memory locking or SCHED_FIFO is not permitted.
    """
    rep = RealtimeReport()
    if settings.mode != RealtimeMode.OFF:
        if settings.lock_memory:
            err = (mlockall or _default_mlockall())(MCL_CURRENT | MCL_FUTURE)
            if err == 0:
                rep.mlock = True
            else:
                rep.failures.append(
                    f"mlockall failed: {os.strerror(err)} (needs CAP_IPC_LOCK or LimitMEMLOCK=infinity)")
        setscheduler = setscheduler or os.sched_setscheduler
        try:
            policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
            setscheduler(0, os.SCHED_FIFO, os.sched_param(settings.priority))
            setscheduler(0, policy, param)
        except OSError as exc:
            rep.failures.append(_fifo_failure(settings, exc))
        _check(settings, rep)
    rep.prev_gc_enabled = gc.isenabled()
    gc.collect()
    gc.freeze()
    gc.disable()
    rep.gc_frozen = True
    return rep


def apply(settings: RealtimeSettings, rep: RealtimeReport, *,
          setscheduler: Callable[[int, int, Any], None] | None = None,
          setaffinity: Callable[[int, Any], None] | None = None) -> RealtimeReport:
    """The fast part, for the loop thread right before the first cycle: CPU affinity,
    SCHED_FIFO (with SCHED_RESET_ON_FORK, so no child process inherits it) and the GIL
    switch interval. Threads the drivers started earlier keep normal scheduling.

    :raises RealtimeError: in ENFORCE mode if affinity or SCHED_FIFO cannot be set.
    """
    rep.failures = [f for f in rep.failures if f.startswith("mlockall")]
    if settings.mode != RealtimeMode.OFF:
        setaffinity = setaffinity or os.sched_setaffinity
        setscheduler = setscheduler or os.sched_setscheduler
        if settings.cpus:
            try:
                setaffinity(0, set(settings.cpus))
                rep.affinity = True
            except (OSError, ValueError) as exc:
                rep.failures.append(f"CPU affinity {sorted(settings.cpus)} not set: {exc}")
        try:
            setscheduler(0, os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0),
                         os.sched_param(settings.priority))
            rep.fifo = True
        except OSError as exc:
            rep.failures.append(_fifo_failure(settings, exc))
        _check(settings, rep)
    rep.prev_switch_interval_s = sys.getswitchinterval()
    if settings.gil_switch_interval_s > 0:
        sys.setswitchinterval(settings.gil_switch_interval_s)
    return rep


def apply_to_threads(settings: RealtimeSettings, rep: RealtimeReport, threads: list[threading.Thread], *,
                     setscheduler: Callable[[int, int, Any], None] | None = None,
                     setaffinity: Callable[[int, Any], None] | None = None) -> list[str]:
    """Give the process's helper threads (a driver's CAN receive thread) SCHED_FIFO at
    ``settings.helper_priority`` and the loop's CPUs: on a loaded machine a normal-priority
    receive thread is starved for milliseconds and the loop sees stale feedback, while
    below the loop's priority it can only run while the loop sleeps (its GIL hold is
    bounded by the switch interval).

    :returns: names of the threads changed.
    :raises RealtimeError: in ENFORCE mode if a thread cannot be changed.
    """
    done: list[str] = []
    if settings.mode == RealtimeMode.OFF or settings.helper_priority <= 0:
        return done
    setaffinity = setaffinity or os.sched_setaffinity
    setscheduler = setscheduler or os.sched_setscheduler
    for th in threads:
        tid = th.native_id
        if tid is None or not th.is_alive():
            continue
        try:
            if settings.cpus:
                setaffinity(tid, set(settings.cpus))
            setscheduler(tid, os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0),
                         os.sched_param(settings.helper_priority))
            done.append(th.name)
        except OSError as exc:
            rep.failures.append(f"thread {th.name!r}: SCHED_FIFO {settings.helper_priority} not set: "
                                f"{exc.strerror or exc}")
    _check(settings, rep)
    return done


def _fifo_failure(settings: RealtimeSettings, exc: OSError) -> str:
    return (f"SCHED_FIFO priority {settings.priority} not permitted: {exc.strerror or exc} "
            "(needs CAP_SYS_NICE or LimitRTPRIO)")


def _check(settings: RealtimeSettings, rep: RealtimeReport) -> None:
    """Raise in ENFORCE mode, warn once per failed step otherwise."""
    if not rep.failures:
        return
    if settings.mode == RealtimeMode.ENFORCE:
        restore(rep)
        raise RealtimeError("realtime: enforce, but " + "; ".join(rep.failures))
    for line in rep.failures:
        if line not in rep.warned:
            rep.warned.append(line)
            log.warning("real-time setup: %s; the loop runs with worse timing", line)


def restore(rep: RealtimeReport) -> None:
    """Undo the GC freeze and the switch interval (scheduling stays as it is)."""
    if rep.gc_frozen:
        gc.unfreeze()
        if rep.prev_gc_enabled:
            gc.enable()
        rep.gc_frozen = False
    if rep.prev_switch_interval_s > 0:
        sys.setswitchinterval(rep.prev_switch_interval_s)


def drop_to_normal_scheduling() -> None:
    """Return the calling thread to SCHED_OTHER (e.g. before slow shutdown work)."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError as exc:  # pragma: no cover - dropping priority is always permitted
        log.debug("could not drop to SCHED_OTHER: %s", exc)
