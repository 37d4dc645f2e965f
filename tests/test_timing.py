"""Sleeping policy and timing statistics of the 1 kHz loop (fake clock, no real time)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from capstan.controller.runtime.timing import DeadlineSleeper, LoopStats, process_cpu_s

MS = 1_000_000


class FakeClock:
    """Monotonic ns clock; each read advances by ``tick_ns`` (models a busy-wait spin)."""

    def __init__(self, t0_ns: int = 10 * MS, tick_ns: int = 1_000) -> None:
        self.t = t0_ns
        self.tick_ns = tick_ns
        self.sleeps: list[int] = []

    def now(self) -> int:
        self.t += self.tick_ns
        return self.t

    def sleep_until(self, t_ns: int) -> None:
        self.sleeps.append(t_ns)
        self.t = max(self.t, t_ns)


def make(period_ms: float = 1.0, tail_us: float = 150.0) -> tuple[DeadlineSleeper, FakeClock]:
    clk = FakeClock()
    s = DeadlineSleeper(period_ms * 1e-3, tail_us * 1e-6, now_ns=clk.now, sleep_until_ns=clk.sleep_until)
    return s, clk


def test_sleeps_until_tail_before_deadline_then_spins_to_it() -> None:
    s, clk = make()
    dl = s.start()
    wake, late = s.wait()
    assert not late
    assert clk.sleeps == [dl - 150_000]          # kernel sleep ends a tail before the deadline
    assert dl <= wake < dl + 2 * clk.tick_ns     # busy-wait reaches the deadline itself
    assert s.deadline_ns == dl + MS              # next deadline is absolute: +1 period


def test_deadlines_stay_absolute_despite_work_time() -> None:
    s, clk = make()
    dl0 = s.start()
    for k in range(1, 50):
        clk.t += 300_000 + 7_000 * (k % 5)       # variable work, always < period
        s.wait()
        assert s.deadline_ns == dl0 + k * MS     # no drift accumulates
    assert s.overruns == 0 and s.missed == 0


def test_short_remaining_time_only_spins() -> None:
    s, clk = make()
    dl = s.start()
    clk.t = dl - 100_000                         # less than the 150 µs tail left
    wake, late = s.wait()
    assert clk.sleeps == [] and not late and wake >= dl


def test_overrun_skips_missed_slots_keeps_phase_and_counts() -> None:
    s, clk = make()
    dl = s.start()
    clk.t = dl + 2 * MS + 300_000                # work ran 2.3 periods past the deadline
    wake, late = s.wait()
    assert late and s.overruns == 1 and s.missed == 2
    assert s.deadline_ns == dl + 3 * MS          # first future slot on the original grid
    assert (s.deadline_ns - dl) % MS == 0


def test_streak_counts_consecutive_late_cycles_and_resets() -> None:
    s, clk = make()
    s.start()
    for _ in range(3):
        clk.t = s.deadline_ns + 10_000           # each cycle 10 µs late
        s.wait()
    assert s.streak == 3 and s.max_streak == 3
    s.wait()                                     # on time again
    assert s.streak == 0 and s.max_streak == 3 and s.overruns == 3


def test_rejects_bad_period() -> None:
    with pytest.raises(ValueError, match="period_s"):
        DeadlineSleeper(0.0)
    with pytest.raises(ValueError, match="busy_tail_s"):
        DeadlineSleeper(1e-3, -1e-6)


def test_window_percentiles_match_known_distribution() -> None:
    st = LoopStats(1e-3, window_cycles=1000)
    # jitter 0..999 µs uniformly: p50 ~ 499.5, p99 ~ 989, max 999
    for i in range(1000):
        st.add(1e-3 + i * 1e-6, i * 1e-6, 20e-6, late=False)
    assert st.window_full
    rep = st.take_window()
    assert rep.cycles == 1000
    assert rep.jitter_p50_us == pytest.approx(499.5, abs=0.6)
    assert rep.jitter_p99_us == pytest.approx(989.0, abs=1.1)
    assert rep.jitter_max_us == pytest.approx(999.0, abs=1e-6)
    assert rep.compute_p99_us == pytest.approx(20.0)
    assert rep.success_rate == 1.0
    assert not st.window_full                    # a new window started


def test_success_rate_is_fraction_of_last_100_on_time() -> None:
    st = LoopStats(1e-3)
    for i in range(300):
        st.add(1e-3, 0.0, 1e-5, late=(i >= 290))  # last 10 late
    assert st.success_rate() == pytest.approx(0.90)
    for _ in range(100):
        st.add(1e-3, 0.0, 1e-5, late=False)
    assert st.success_rate() == 1.0              # old lates have left the window
    assert st.late_cycles == 10


def test_run_summary_histogram_percentiles() -> None:
    st = LoopStats(1e-3, window_cycles=100)
    rng = np.random.default_rng(1)
    jit_us = rng.integers(0, 50, size=10_000).astype(float)
    jit_us[:10] = 3000.0                          # 0.1 % outliers of 3 ms
    for j in jit_us:
        st.add(1e-3 + j * 1e-6, j * 1e-6, 1e-5, late=False)
        if st.window_full:
            st.take_window()
    s = st.run_summary()
    assert s["cycles"] == 10_000
    assert s["jitter_p50_us"] == pytest.approx(np.percentile(jit_us, 50), abs=1.5)
    assert 49 <= s["jitter_p99_us"] <= 50        # the 1 µs bin holding the 99th percentile
    assert s["jitter_p999_us"] <= 50             # 10 outliers are exactly the top 0.1 %
    assert s["jitter_max_us"] == pytest.approx(3000.0, abs=1e-6)


def test_empty_window_reports_nan() -> None:
    rep = LoopStats(1e-3).take_window()
    assert rep.cycles == 0 and math.isnan(rep.jitter_p99_us)


def test_real_clock_pacing_is_absolute() -> None:
    """20 real cycles of 2 ms: the elapsed time is 20 periods, not 20 periods + overhead."""
    s = DeadlineSleeper(2e-3, 200e-6)
    t0 = s.start() - s.period_ns
    for _ in range(20):
        s.wait()
    elapsed_ns = time.monotonic_ns() - t0
    assert elapsed_ns >= 20 * 2 * MS
    assert s.deadline_ns - t0 == 21 * 2 * MS


def test_process_cpu_time_of_self_and_pid() -> None:
    import os
    assert process_cpu_s() > 0.0
    assert process_cpu_s(os.getpid()) >= 0.0


def test_gil_wait_probe_sees_a_thread_holding_the_gil() -> None:
    """A thread stuck in one long C call (``sum(range(n))`` never drops the GIL) keeps the
    woken loop thread waiting; the native wake stamp makes that wait visible."""
    import threading
    s = DeadlineSleeper(2e-3, 0.0)
    s.start()
    quiet = []
    for _ in range(20):
        s.wait()
        quiet.append(s.gil_wait_ns)
    hog_done = threading.Event()

    def hog() -> None:
        time.sleep(0.02)                 # let the loop thread be asleep when the hog starts
        t0 = time.perf_counter()
        sum(range(10_000_000))
        hog_done.hold_s = time.perf_counter() - t0  # type: ignore[attr-defined]
        hog_done.set()

    s.start()
    th = threading.Thread(target=hog)
    th.start()
    waits = []
    while not hog_done.is_set():
        s.wait()
        waits.append(s.gil_wait_ns)
    th.join()
    hold_ms = hog_done.hold_s * 1e3  # type: ignore[attr-defined]
    assert hold_ms > 20.0
    # the wait that ended when the hog finished covers most of its GIL hold
    assert max(waits) * 1e-6 > 0.5 * hold_ms
    assert np.median(quiet) * 1e-6 < 1.0
