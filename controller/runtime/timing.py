"""Loop timing: absolute-deadline sleeping and cycle statistics.

:class:`DeadlineSleeper` keeps a loop on absolute deadlines ``t0 + k * period``: it
sleeps with ``clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`` until a short tail
before the deadline, then busy-waits the tail. An overrun (the cycle's work ran past
the next deadline) skips the missed slots so the phase is kept, counts the missed
cycles and tracks the streak of consecutive late cycles. The clock and the sleep
function are injectable so the policy is tested without real time.

:class:`LoopStats` accumulates period jitter, wake latency and compute time without
allocating per cycle: a one-second window (exact percentiles, reported every second)
and whole-run histograms with 1 µs bins (percentiles of the entire run). The success
rate follows libfranka's ``control_command_success_rate``: the fraction of the last
100 cycles that met their deadline.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import math
import os
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

CLOCK_MONOTONIC = 1
TIMER_ABSTIME = 1
EINTR = 4

#: number of recent cycles over which the success rate is computed (as libfranka)
SUCCESS_WINDOW = 100

#: upper edge of the whole-run histograms [µs]; larger values land in the last bin
HIST_MAX_US = 100_000


def _make_abs_sleep() -> Callable[[int], int]:
    """Return ``sleep_until_ns(t_ns) -> wake_ns``: an absolute sleep on CLOCK_MONOTONIC.

    ``wake_ns`` is stamped in native code right after the kernel returned and *before*
    the GIL is taken again (a Numba ``nogil`` function calling libc), so the caller can
    measure how long another thread of the process kept it waiting for the GIL. Numba
    cannot cache a function holding ctypes pointers, so it compiles here (~0.5 s, once
    per process). Falls back to plain ctypes (wake_ns = -1: not measured) and, without
    ``clock_nanosleep``, to a relative ``time.sleep``.
    """
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6", use_errno=True)
        fn = libc.clock_nanosleep
        now_fn = libc.clock_gettime
    except (OSError, AttributeError):
        def sleep_rel(t_ns: int) -> int:
            dt = (t_ns - time.monotonic_ns()) * 1e-9
            if dt > 0:
                time.sleep(dt)
            return -1
        return sleep_rel
    fn.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p]
    fn.restype = ctypes.c_int
    now_fn.argtypes = [ctypes.c_int, ctypes.c_void_p]
    now_fn.restype = ctypes.c_int
    ts = np.zeros(2, dtype=np.int64)       # struct timespec {tv_sec, tv_nsec} on LP64
    out = np.zeros(2, dtype=np.int64)
    try:
        from numba import njit

        @njit(nogil=True)
        def _sleep_stamp(ts_: np.ndarray, out_: np.ndarray) -> None:  # pragma: no cover - compiled
            while fn(CLOCK_MONOTONIC, TIMER_ABSTIME, ts_.ctypes.data, 0) == EINTR:
                pass
            now_fn(CLOCK_MONOTONIC, out_.ctypes.data)

        def sleep_stamped(t_ns: int) -> int:
            ts[0], ts[1] = divmod(t_ns, 1_000_000_000)
            _sleep_stamp(ts, out)
            return int(out[0]) * 1_000_000_000 + int(out[1])
        sleep_stamped(time.monotonic_ns())  # compile now, not in the first cycle
        return sleep_stamped
    except Exception as exc:  # noqa: BLE001 - any Numba failure: keep the plain sleep
        logging.getLogger(__name__).warning("GIL-wait probe unavailable (%s); sleeping without it", exc)

    def sleep_abs(t_ns: int) -> int:
        ts[0], ts[1] = divmod(t_ns, 1_000_000_000)
        while fn(CLOCK_MONOTONIC, TIMER_ABSTIME, ts.ctypes.data, None) == EINTR:
            pass
        return -1
    return sleep_abs


_shared_sleep: Callable[[int], int] | None = None


def shared_abs_sleep() -> Callable[[int], int]:
    """The process-wide absolute sleep of :func:`_make_abs_sleep`, built (compiled) on
    first use; call it once before any deadline matters."""
    global _shared_sleep
    if _shared_sleep is None:
        _shared_sleep = _make_abs_sleep()
    return _shared_sleep


class DeadlineSleeper:
    """Absolute-deadline pacing of a periodic loop.

    :param period_s: loop period [s], > 0.
    :param busy_tail_s: the last part before each deadline spent busy-waiting [s], >= 0.
    :param now_ns: monotonic clock in ns (default ``time.monotonic_ns``, CLOCK_MONOTONIC).
    :param sleep_until_ns: absolute sleep on the same clock returning the native wake
        stamp or -1 (default: clock_nanosleep with the GIL-wait probe).
    :raises ValueError: on a non-positive period or negative tail.
    """

    def __init__(self, period_s: float, busy_tail_s: float = 150e-6,
                 now_ns: Callable[[], int] = time.monotonic_ns,
                 sleep_until_ns: Callable[[int], int | None] | None = None) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        if busy_tail_s < 0:
            raise ValueError(f"busy_tail_s must be >= 0, got {busy_tail_s}")
        self.period_ns = int(round(period_s * 1e9))
        self.tail_ns = int(round(busy_tail_s * 1e9))
        self._now = now_ns
        self._sleep = sleep_until_ns if sleep_until_ns is not None else shared_abs_sleep()
        self.deadline_ns = 0
        #: cycles that finished after the following deadline
        self.overruns = 0
        #: deadline slots skipped because of overruns
        self.missed = 0
        #: current run of consecutive late cycles
        self.streak = 0
        #: longest streak seen
        self.max_streak = 0
        #: time from the kernel wake-up to Python running again in the last wait [ns]
        #: (waiting for the GIL held by another thread; 0 when not measured)
        self.gil_wait_ns = 0

    def start(self) -> int:
        """Set the first deadline one period from now; return it [ns]."""
        self.deadline_ns = self._now() + self.period_ns
        return self.deadline_ns

    def wait(self) -> tuple[int, bool]:
        """Wait for the current deadline and advance to the next one.

        Called at the end of a cycle's work. If the work already ran past the
        deadline the cycle is late: no waiting, the missed slots are skipped (the next
        deadline is the first one still in the future) and counted.

        :returns: (wake time [ns], late) — late is True if the deadline had passed.
        """
        now = self._now()
        dl = self.deadline_ns
        if now > dl:
            skipped = (now - dl) // self.period_ns
            self.overruns += 1
            self.missed += skipped
            self.streak += 1
            if self.streak > self.max_streak:
                self.max_streak = self.streak
            self.deadline_ns = dl + (skipped + 1) * self.period_ns
            return now, True
        self.streak = 0
        self.gil_wait_ns = 0
        if dl - now > self.tail_ns:
            stamp = self._sleep(dl - self.tail_ns)
            now = self._now()
            if stamp is not None and stamp > 0:
                self.gil_wait_ns = max(now - stamp, 0)
        now = self._now()
        while now < dl:
            now = self._now()
        self.deadline_ns = dl + self.period_ns
        return now, False


@dataclass
class WindowReport:
    """Timing of one reporting window (normally one second).

    Jitter is ``|measured period - nominal period|``; latency is wake time minus
    deadline (what cyclictest reports). All times in µs.
    """

    cycles: int
    jitter_p50_us: float
    jitter_p99_us: float
    jitter_p999_us: float
    jitter_max_us: float
    latency_p99_us: float
    compute_p50_us: float
    compute_p99_us: float
    compute_max_us: float
    late: int
    success_rate: float
    gil_wait_max_us: float = 0.0

    def status_line(self) -> str:
        """Short one-line summary for logs and the systemd status."""
        return (f"jitter p50/p99/p99.9/max {self.jitter_p50_us:.0f}/{self.jitter_p99_us:.0f}/"
                f"{self.jitter_p999_us:.0f}/{self.jitter_max_us:.0f} us, compute p99 "
                f"{self.compute_p99_us:.0f} us, GIL wait max {self.gil_wait_max_us:.0f} us, late {self.late}, "
                f"success {self.success_rate:.2f}")


def _nearest_rank(sorted_values: np.ndarray, q: float) -> float:
    """Nearest-rank percentile (q in [0, 100]) of an ascending, non-empty array."""
    n = len(sorted_values)
    return float(sorted_values[min(n, max(1, int(math.ceil(q * n / 100.0 - 1e-9)))) - 1])


def _hist_percentile_us(hist: np.ndarray, q: float) -> float:
    """Percentile (q in [0, 100]) of a 1 µs-bin histogram, as the bin's upper edge [µs]."""
    n = int(hist.sum())
    if n == 0:
        return math.nan
    rank = max(1, int(math.ceil(q * n / 100.0 - 1e-9)))
    idx = int(np.searchsorted(np.cumsum(hist), rank))
    return float(idx + 1) if idx < HIST_MAX_US else float(HIST_MAX_US)


class LoopStats:
    """Per-cycle timing statistics without per-cycle allocation.

    :param period_s: nominal period [s].
    :param window_cycles: cycles per reporting window (1 s at 1 kHz = 1000).
    """

    def __init__(self, period_s: float, window_cycles: int = 1000) -> None:
        self.period_s = float(period_s)
        self.window_cycles = int(window_cycles)
        self._jit = np.zeros(self.window_cycles)
        self._lat = np.zeros(self.window_cycles)
        self._cmp = np.zeros(self.window_cycles)
        self._n = 0
        self._late_win = 0
        self._recent = np.zeros(SUCCESS_WINDOW, dtype=np.bool_)
        self._recent_i = 0
        self._recent_n = 0
        self.hist_jitter = np.zeros(HIST_MAX_US + 1, dtype=np.int64)
        self.hist_latency = np.zeros(HIST_MAX_US + 1, dtype=np.int64)
        self.hist_gil = np.zeros(HIST_MAX_US + 1, dtype=np.int64)
        self._gil_win_max = 0.0
        self.gil_wait_max_us = 0.0
        self.cycles = 0
        self.late_cycles = 0
        self.jitter_max_us = 0.0
        self.compute_max_us = 0.0
        _nearest_rank(np.sort(self._jit[:2]), 50.0)   # first-call costs here, not in the loop

    def add(self, period_s: float, latency_s: float, compute_s: float, late: bool,
            gil_wait_s: float = 0.0) -> None:
        """Account one cycle: measured period [s], wake latency [s], compute time [s],
        time spent waiting for the GIL after the wake-up [s]."""
        jit_us = abs(period_s - self.period_s) * 1e6
        lat_us = max(latency_s, 0.0) * 1e6
        cmp_us = compute_s * 1e6
        i = self._n
        if i < self.window_cycles:
            self._jit[i] = jit_us
            self._lat[i] = lat_us
            self._cmp[i] = cmp_us
            self._n = i + 1
        self.hist_jitter[min(int(jit_us), HIST_MAX_US)] += 1
        self.hist_latency[min(int(lat_us), HIST_MAX_US)] += 1
        gil_us = gil_wait_s * 1e6
        self.hist_gil[min(int(gil_us), HIST_MAX_US)] += 1
        if gil_us > self._gil_win_max:
            self._gil_win_max = gil_us
            if gil_us > self.gil_wait_max_us:
                self.gil_wait_max_us = gil_us
        if jit_us > self.jitter_max_us:
            self.jitter_max_us = jit_us
        if cmp_us > self.compute_max_us:
            self.compute_max_us = cmp_us
        self._recent[self._recent_i] = late
        self._recent_i = (self._recent_i + 1) % SUCCESS_WINDOW
        if self._recent_n < SUCCESS_WINDOW:
            self._recent_n += 1
        self.cycles += 1
        if late:
            self.late_cycles += 1
            self._late_win += 1

    @property
    def window_full(self) -> bool:
        """True once the current window holds ``window_cycles`` cycles."""
        return self._n >= self.window_cycles

    def success_rate(self) -> float:
        """Fraction of the last 100 cycles (fewer at start) that met their deadline."""
        if self._recent_n == 0:
            return 1.0
        return 1.0 - float(self._recent[:self._recent_n].sum()) / self._recent_n

    def take_window(self) -> WindowReport:
        """Summarise the current window and start a new one."""
        n = self._n
        if n == 0:
            nan = math.nan
            rep = WindowReport(0, nan, nan, nan, nan, nan, nan, nan, nan, 0, self.success_rate())
        else:
            j = np.sort(self._jit[:n])
            c = np.sort(self._cmp[:n])
            lat = np.sort(self._lat[:n])
            rep = WindowReport(n, _nearest_rank(j, 50.0), _nearest_rank(j, 99.0), _nearest_rank(j, 99.9),
                               float(j[-1]), _nearest_rank(lat, 99.0), _nearest_rank(c, 50.0),
                               _nearest_rank(c, 99.0), float(c[-1]), self._late_win, self.success_rate(),
                               self._gil_win_max)
        self._n = 0
        self._late_win = 0
        self._gil_win_max = 0.0
        return rep

    def run_summary(self) -> dict[str, float]:
        """Whole-run figures (µs, 1 µs histogram resolution; max exact)."""
        return {
            "cycles": self.cycles,
            "late": self.late_cycles,
            "jitter_p50_us": _hist_percentile_us(self.hist_jitter, 50.0),
            "jitter_p99_us": _hist_percentile_us(self.hist_jitter, 99.0),
            "jitter_p999_us": _hist_percentile_us(self.hist_jitter, 99.9),
            "jitter_max_us": self.jitter_max_us,
            "latency_p99_us": _hist_percentile_us(self.hist_latency, 99.0),
            "latency_p999_us": _hist_percentile_us(self.hist_latency, 99.9),
            "compute_max_us": self.compute_max_us,
            "gil_wait_p999_us": _hist_percentile_us(self.hist_gil, 99.9),
            "gil_wait_max_us": self.gil_wait_max_us,
        }


def process_cpu_s(pid: int | None = None) -> float:
    """CPU time (user + system) of a process [s], from /proc; own process if pid is None.

    :raises OSError: if the process does not exist.
    """
    if pid is None:
        t = os.times()
        return t.user + t.system
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / tick
