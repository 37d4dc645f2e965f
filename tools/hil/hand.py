"""The hand of the hardware-in-the-loop rig: an arm impedance moving the link with rests,
and the interaction torque it feels.

The notion of :mod:`capstan.tools.experiments.interaction` (paper §4.5): the arm pulls the link handle toward
a reference motion through its impedance::

    tau_h = K_h (q_ref - q_out) + B_h (dq_ref - dq_out)          applied to the link

``tau_h`` is what a handle force/torque sensor reads: the better the joint hides its
friction, the smaller it is. Unlike the periodic reference of
:class:`capstan.tools.experiments.interaction.HumanModel`, the reference here strokes between
``center - amplitude`` and ``center + amplitude`` with rests and stroke durations taken in
turn from lists, so that runs contain rests of several lengths and several speeds (what
the closure needs to tell a dwell-dependent effect from a velocity-dependent one).

The hand holds the handle only while the drive is in OPERATION ENABLED (the daemon
controls the joint); its clock starts then, so runs with different controllers see the
same hand motion. With ``targets_rad`` the strokes go from target to target in turn
instead (the last target is where the hand grabs the handle): stops at many positions,
reached from both directions, so that what holds the link at rest (stiction, in the
direction of the last motion) does not line up with the position or the load.

Statistics (time-weighted, after ``settle_s``): mean, RMS and maximum
``|tau_h|`` and the mean over strokes of the peak ``|tau_h|`` in the first
``breakaway_window_s`` of each stroke (breaking the link away after a rest).

Config, section ``hil.hand`` (all optional)::

    hand: {stiffness_Nm_rad: 60.0, damping_Nms_rad: 3.0, center_rad: 0.5, amplitude_rad: 0.5,
           targets_rad: [], moves_s: [1.5], rests_s: [1.0], settle_s: 0.5, breakaway_window_s: 0.5}
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Any, Mapping

from capstan.models.common.config_tools import get_float, reject_unknown
from capstan.models.common.errors import ConfigError


def _finite_list(cfg: Mapping[str, Any], key: str, prefix: str) -> tuple[float, ...]:
    val = cfg.get(key, [])
    if not isinstance(val, list) or not all(isinstance(x, (int, float)) and math.isfinite(x) for x in val):
        raise ConfigError(f"{prefix}.{key}", f"must be a list of angles [rad], got {val!r}")
    if len(val) == 1 or any(a == b for a, b in zip(val, val[1:] + val[:1])):
        raise ConfigError(f"{prefix}.{key}", f"needs >= 2 targets, each different from the next, got {val!r}")
    return tuple(float(x) for x in val)


def _positive_list(cfg: Mapping[str, Any], key: str, prefix: str, default: tuple[float, ...]) -> tuple[float, ...]:
    val = cfg.get(key, list(default))
    if (not isinstance(val, list) or not val
            or not all(isinstance(x, (int, float)) and math.isfinite(x) and x > 0 for x in val)):
        raise ConfigError(f"{prefix}.{key}", f"must be a non-empty list of durations > 0 [s], got {val!r}")
    return tuple(float(x) for x in val)


@dataclass(frozen=True)
class HandSettings:
    """Arm impedance and reference motion.

    :ivar stiffness_Nm_rad: K_h [Nm/rad]. :ivar damping_Nms_rad: B_h [Nm s/rad].
    :ivar center_rad: middle of the stroke [rad]. :ivar amplitude_rad: half the stroke [rad].
    :ivar targets_rad: stroke end points, in turn (empty: between center -+ amplitude) [rad].
    :ivar moves_s: stroke durations, used in turn (raised-cosine velocity profile) [s].
    :ivar rests_s: rest durations before each stroke, used in turn [s].
    :ivar settle_s: time after the hand grabs the handle excluded from the statistics [s].
    :ivar breakaway_window_s: window after each stroke onset for the breakaway peak [s].
    """

    stiffness_Nm_rad: float = 60.0
    damping_Nms_rad: float = 3.0
    center_rad: float = 0.5
    amplitude_rad: float = 0.5
    targets_rad: tuple[float, ...] = ()
    moves_s: tuple[float, ...] = (1.5,)
    rests_s: tuple[float, ...] = (1.0,)
    settle_s: float = 0.5
    breakaway_window_s: float = 0.5

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str = "hil.hand") -> "HandSettings":
        """:raises ConfigError: naming the offending key."""
        reject_unknown(cfg, set(HandSettings.__dataclass_fields__), prefix)
        d = HandSettings()
        return HandSettings(
            get_float(cfg, "stiffness_Nm_rad", prefix, d.stiffness_Nm_rad, min_value=0.0),
            get_float(cfg, "damping_Nms_rad", prefix, d.damping_Nms_rad, min_value=0.0),
            get_float(cfg, "center_rad", prefix, d.center_rad),
            get_float(cfg, "amplitude_rad", prefix, d.amplitude_rad, min_value=0.0),
            _finite_list(cfg, "targets_rad", prefix),
            _positive_list(cfg, "moves_s", prefix, d.moves_s),
            _positive_list(cfg, "rests_s", prefix, d.rests_s),
            get_float(cfg, "settle_s", prefix, d.settle_s, min_value=0.0),
            get_float(cfg, "breakaway_window_s", prefix, d.breakaway_window_s, min_value=0.0,
                      min_exclusive=True),
        )


class Hand:
    """Reference motion, impedance torque and interaction statistics of one run."""

    def __init__(self, settings: HandSettings) -> None:
        self.settings = s = settings
        targets = s.targets_rad or (s.center_rad + s.amplitude_rad, s.center_rad - s.amplitude_rad)
        nt = len(targets)
        n = math.lcm(nt, len(s.moves_s), len(s.rests_s))    # strokes until the pattern repeats
        self._starts: list[float] = []                       # stroke onset times in one pattern
        self._segs: list[tuple[float, float, float]] = []    # (from, to, move duration)
        t = 0.0
        for k in range(n):
            t += s.rests_s[k % len(s.rests_s)]
            a, b = targets[(k - 1) % nt], targets[k % nt]
            self._starts.append(t)
            self._segs.append((a, b, s.moves_s[k % len(s.moves_s)]))
            t += s.moves_s[k % len(s.moves_s)]
        self.period_s = t
        self.q_start_rad = targets[-1]
        self._sum_dt = self._sum_abs = self._sum_sq = self._max = 0.0
        self._peaks: list[float] = []
        self._stroke = -1

    def reference(self, t_s: float) -> tuple[float, float]:
        """Reference ``(q_ref_rad, dq_ref_rad_s)`` at hand time ``t_s`` (0 = grabbing the handle at rest)."""
        if t_s <= 0.0:
            return self.q_start_rad, 0.0
        tp = t_s % self.period_s
        k = bisect.bisect_right(self._starts, tp) - 1
        if k < 0:                                    # resting before the first stroke
            return self._segs[-1][1], 0.0
        a, b, move = self._segs[k]
        x = (tp - self._starts[k]) / move
        if x >= 1.0:
            return b, 0.0
        return (a + (b - a) * 0.5 * (1.0 - math.cos(math.pi * x)),
                (b - a) * 0.5 * math.pi / move * math.sin(math.pi * x))

    def torque_Nm(self, t_s: float, q_out_rad: float, dq_out_rad_s: float) -> float:
        """Interaction torque the arm applies to the link at hand time ``t_s`` [Nm]."""
        q_ref, dq_ref = self.reference(t_s)
        s = self.settings
        return s.stiffness_Nm_rad * (q_ref - q_out_rad) + s.damping_Nms_rad * (dq_ref - dq_out_rad_s)

    def stroke_phase(self, t_s: float) -> tuple[int, float]:
        """``(stroke index since the start, time since its onset [s])``; index -1 before the first."""
        if t_s <= 0.0:
            return -1, 0.0
        n_rep, tp = divmod(t_s, self.period_s)
        k = bisect.bisect_right(self._starts, tp) - 1
        if k < 0:
            return int(n_rep) * len(self._starts) - 1, tp + self.period_s - self._starts[-1]
        return int(n_rep) * len(self._starts) + k, tp - self._starts[k]

    def record(self, t_s: float, tau_h_Nm: float, dt_s: float) -> None:
        """Add one sample of ``tau_h`` held over ``dt_s`` at hand time ``t_s`` to the statistics."""
        s = self.settings
        if t_s < s.settle_s:
            return
        a = abs(tau_h_Nm)
        self._sum_dt += dt_s
        self._sum_abs += a * dt_s
        self._sum_sq += a * a * dt_s
        self._max = max(self._max, a)
        k, since = self.stroke_phase(t_s)
        if k >= 0 and since < s.breakaway_window_s:
            if k != self._stroke:
                self._stroke = k
                self._peaks.append(0.0)
            self._peaks[-1] = max(self._peaks[-1], a)

    def stats(self) -> dict[str, float]:
        """Interaction statistics [Nm] over the recorded time (NaN if none) and its length [s]."""
        if self._sum_dt <= 0.0:
            nan = math.nan
            return {"mean_abs_tau_h_Nm": nan, "rms_tau_h_Nm": nan, "max_abs_tau_h_Nm": nan,
                    "mean_breakaway_peak_tau_h_Nm": nan, "strokes": 0, "time_s": 0.0}
        return {"mean_abs_tau_h_Nm": self._sum_abs / self._sum_dt,
                "rms_tau_h_Nm": math.sqrt(self._sum_sq / self._sum_dt),
                "max_abs_tau_h_Nm": self._max,
                "mean_breakaway_peak_tau_h_Nm": (sum(self._peaks) / len(self._peaks)) if self._peaks else math.nan,
                "strokes": len(self._peaks), "time_s": self._sum_dt}
