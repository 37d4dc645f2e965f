"""Quality of the motor command where it is made: per statistics window and for the run.

What a person holding the link feels as buzz, and what heats and wears the motor:

* ``cmd_std_Nm`` — standard deviation of the command in the window [Nm];
* ``cmd_change_rms_Nm`` — rms of the cycle-to-cycle change [Nm per cycle];
* ``cmd_hf_share`` — share of the command's power (mean removed, Hann window) above
  :data:`SPLIT_HZ` [-];
* ``rate_limit_hits`` — cycles whose change reached the safety stage's rate clamp
  (``dtau_max_Nm_s * dt``; the clamp shaped the command);
* ``tau_in_std_Nm`` — standard deviation of the filtered input torque (at rest: the
  sensor-noise floor the loop leaves) [Nm].

:meth:`CommandQuality.add` costs a store and two compares per cycle (no allocation); the
spectrum is computed once per window, outside the time-critical part of the cycle (where
the timing statistics are reduced as well).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

#: frequency above which command power counts as buzz [Hz]
SPLIT_HZ = 20.0


@dataclass(frozen=True)
class CommandReport:
    """Command quality of one window or of the run (see the module docstring)."""

    cycles: int
    cmd_std_Nm: float
    cmd_change_rms_Nm: float
    cmd_hf_share: float
    rate_limit_hits: int
    tau_in_std_Nm: float

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


class CommandQuality:
    """Collects the command and tau_in of each running cycle.

    :param window_cycles: cycles per statistics window (> 0).
    :param period_s: control period [s].
    :param rate_step_Nm: the rate clamp per cycle (``dtau_max_Nm_s * dt``) [Nm]; 0 = none.
    :raises ValueError: on a non-positive window or period.
    """

    def __init__(self, window_cycles: int, period_s: float, rate_step_Nm: float) -> None:
        if window_cycles <= 0 or not period_s > 0:
            raise ValueError(f"need window_cycles > 0 and period_s > 0, got {window_cycles}, {period_s}")
        self._cmd = np.zeros(window_cycles)
        self._tin = np.zeros(window_cycles)
        self._n = 0
        self._hits = 0
        self._prev = math.nan
        self._dt = float(period_s)
        self._hit_level = rate_step_Nm * (1.0 - 1e-9) if rate_step_Nm > 0 else math.inf
        # run totals
        self._cycles = 0
        self._sum = self._sumsq = 0.0
        self._tin_sum = self._tin_sumsq = 0.0
        self._dsq = 0.0
        self._nd = 0
        self._hf = self._pw = 0.0
        self._hits_total = 0

    def add(self, tau_cmd_Nm: float, tau_in_Nm: float) -> None:
        """Record one running cycle (call once per cycle)."""
        if self._n < len(self._cmd):
            self._cmd[self._n] = tau_cmd_Nm
            self._tin[self._n] = tau_in_Nm
            self._n += 1
        if self._prev == self._prev:          # not NaN: a previous running cycle exists
            if abs(tau_cmd_Nm - self._prev) >= self._hit_level:
                self._hits += 1
        self._prev = tau_cmd_Nm

    def break_sequence(self) -> None:
        """The next command does not follow the previous one (arming, ramp-down)."""
        self._prev = math.nan

    def take_window(self) -> CommandReport:
        """Figures of the cycles added since the last call; folds them into the run totals."""
        n = self._n
        c, t = self._cmd[:n], self._tin[:n]
        hits = self._hits
        self._n = 0
        self._hits = 0
        if n == 0:
            return CommandReport(0, math.nan, math.nan, math.nan, hits, math.nan)
        d = np.diff(c)
        x = (c - c.mean()) * np.hanning(n)
        p = np.abs(np.fft.rfft(x)) ** 2
        f = np.fft.rfftfreq(n, self._dt)
        pw = float(p[1:].sum())
        hf = float(p[f > SPLIT_HZ].sum())
        self._cycles += n
        self._sum += float(c.sum())
        self._sumsq += float(np.dot(c, c))
        self._tin_sum += float(t.sum())
        self._tin_sumsq += float(np.dot(t, t))
        self._dsq += float(np.dot(d, d))
        self._nd += len(d)
        self._hf += hf
        self._pw += pw
        self._hits_total += hits
        return CommandReport(n, float(c.std()), float(np.sqrt(np.mean(d * d))) if len(d) else 0.0,
                             hf / pw if pw > 0 else 0.0, hits, float(t.std()))

    def run_report(self) -> CommandReport:
        """Figures over every completed window of the run (std from the run's sums, the
        high-frequency share as total power above the split over total power)."""
        n = self._cycles
        if n == 0:
            return CommandReport(0, math.nan, math.nan, math.nan, self._hits_total, math.nan)

        def std(s: float, sq: float) -> float:
            return math.sqrt(max(sq / n - (s / n) ** 2, 0.0))

        return CommandReport(n, std(self._sum, self._sumsq),
                             math.sqrt(self._dsq / self._nd) if self._nd else 0.0,
                             self._hf / self._pw if self._pw > 0 else 0.0, self._hits_total,
                             std(self._tin_sum, self._tin_sumsq))
