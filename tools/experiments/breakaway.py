"""Breakaway friction after rests, measured from a run of the link use case.

While the link rests, the transmission's friction holds whatever the hand pulls with:
the controller keeps ``tau_in`` at the gravity (+ feedforward) reference, so the measured
friction ``tau_f = tau_in - (r_in / r_out) tau_out`` (load cells at both ends) grows with
the hand's pull until the sheath lets go. Its peak at motion onset is the breakaway
friction; the friction a while later in the same stroke, once the joint slides fast, is
the sliding friction. Their ratio is 1 for Coulomb friction without stiction and
``1 + A (1 - exp(-rest/tau_age))`` with dwell-dependent stiction of amplitude ``A``.

Detection on the measured rate: speed smoothed over 20 ms; a rest is below
:data:`REST_RAD_S`, an onset the first sample above :data:`MOVING_RAD_S` after a rest;
the breakaway window is the ``0.3 s`` before the onset to ``50 ms`` after it; the sliding
friction is the median over the stroke's samples beyond :data:`SLIDE_RAD` slid and
faster than :data:`SLIDE_SPEED_RAD_S`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

REST_RAD_S = 0.02
MOVING_RAD_S = 0.05
SMOOTH_S = 0.02
SLIDE_RAD = 0.3
SLIDE_SPEED_RAD_S = 0.2
MIN_SLIDE_SAMPLES = 50


@dataclass(frozen=True)
class Breakaway:
    """One motion onset after a rest.

    :ivar t_s: onset time [s]. :ivar rest_s: duration of the rest before it [s].
    :ivar peak_Nm: breakaway friction (peak in the motion direction) [Nm].
    :ivar sliding_Nm: sliding friction later in the stroke [Nm] (NaN if the stroke was too short).
    """

    t_s: float
    rest_s: float
    peak_Nm: float
    sliding_Nm: float

    @property
    def ratio(self) -> float:
        """Breakaway over sliding friction [-] (NaN without a sliding figure)."""
        return self.peak_Nm / self.sliding_Nm if self.sliding_Nm > 0 else float("nan")


def breakaways(t_s: np.ndarray, tau_in_Nm: np.ndarray, tau_out_Nm: np.ndarray, dq_out_rad_s: np.ndarray,
               ratio_out_in: float = 1.0) -> list[Breakaway]:
    """Every motion onset after a rest, with its breakaway and sliding friction.

    :param ratio_out_in: ``r_in / r_out`` (the output torque referred to the input).
    """
    t = np.asarray(t_s, float)
    f = np.asarray(tau_in_Nm, float) - ratio_out_in * np.asarray(tau_out_Nm, float)
    v = np.asarray(dq_out_rad_s, float)
    n = t.shape[0]
    if n < 3:
        return []
    dt = float(np.median(np.diff(t)))
    k = max(1, int(round(SMOOTH_S / dt)))
    speed = np.convolve(np.abs(v), np.ones(k) / k, mode="same")
    moving = speed > MOVING_RAD_S
    resting = speed < REST_RAD_S
    out: list[Breakaway] = []
    rest_start: float | None = None
    for i in range(1, n):
        if resting[i] and rest_start is None:
            rest_start = float(t[i])
        if moving[i] and not moving[i - 1] and rest_start is not None:
            s = float(np.sign(v[i])) or 1.0
            j = i
            while j < n and moving[j]:
                j += 1
            seg = np.arange(i, j)
            slide = np.cumsum(np.abs(v[seg]) * dt)
            fast = seg[(slide > SLIDE_RAD) & (np.abs(v[seg]) > SLIDE_SPEED_RAD_S)]
            window = (t > t[i] - 0.3) & (t < t[i] + 0.05)
            sliding = float(np.median(s * f[fast])) if fast.shape[0] >= MIN_SLIDE_SAMPLES else float("nan")
            out.append(Breakaway(float(t[i]), float(t[i]) - rest_start, float(np.max(s * f[window])), sliding))
        if moving[i]:
            rest_start = None
    return out
