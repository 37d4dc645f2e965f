"""One bring-up move, run by the daemon itself: devices, 1 kHz loop, limits, faults, MCAP log.

The daemon (:class:`capstan.controller.runtime.daemon.Daemon`) runs unchanged with a
:class:`ProfileController` in place of the friction-compensation law: each cycle the
controller takes the measurements the loop wrote into its record, checks the bring-up
limits (:class:`capstan.tools.rig.start_config.StepLimits`) and the sensors' freshness,
and returns the torque of a :class:`Profile`. A limit, a stale sensor or the profile's own
refusal latches a fault bit: the loop sends zero torque that cycle, disables the drive and
logs the last cycles (the daemon's fault path); :func:`run_profile` turns it into a
:class:`BringupStop` with the reason in one line. Every move is logged to MCAP like any
daemon run (``logging.dir`` of the START config).
"""

from __future__ import annotations

import copy
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Protocol, TypeVar

import numpy as np

from capstan.controller.law.records import RECORD_DTYPE, FaultBits, new_record
from capstan.controller.runtime.config import DaemonConfig
from capstan.controller.runtime.daemon import Daemon
from capstan.models.common.errors import CapstanError, ControlFaultError, DriverError
from capstan.tools.rig.start_config import BringupStop, RigStart, StepLimits

log = logging.getLogger("capstan.rig")

#: a sensor silent this long stops a move [s] (the load cells send at 1 kHz, the IMU at 400 Hz);
#: time the loop itself did not run (a host stall: the process got no CPU, as the daemon names
#: it) is not the device's silence and is not counted
SENSOR_TIMEOUT_S = 0.05
#: a move that a host stall stopped (the daemon's own diagnosis: its loop got no CPU, so the
#: drive's heartbeat or a sensor looked lost) is repeated from rest; this many attempts in all
HOST_STALL_TRIES = 3


T = TypeVar("T")


def stalled_host(reason: str) -> bool:
    """True if a daemon fault's reason says the host did not run the loop: a host stall the
    daemon diagnosed, or a streak of late cycles (the loop could not keep its period)."""
    return "host stall" in reason or "OVERRUN_STREAK" in reason


def repeat_after_host_stalls(step: str, name: str, once: Callable[[], tuple[T, str]],
                             before_retry: Callable[[], None] | None = None) -> T:
    """Run ``once`` (returns its result and, if the host stopped it, the stop's one-line reason,
    else "") up to :data:`HOST_STALL_TRIES` times; ``before_retry`` runs before each repeat.

    :raises BringupStop: with the last reason if every attempt was stopped by the host (and
        whatever ``once`` raises).
    """
    for attempt in range(1, HOST_STALL_TRIES):
        result, stall = once()
        if not stall:
            return result
        log.warning("%s: %s; repeated from rest (attempt %d of %d)", name, stall, attempt + 1, HOST_STALL_TRIES)
        if before_retry is not None:
            before_retry()
    result, stall = once()
    if stall:
        raise BringupStop(step, stall)
    return result


def loop_limits(L: StepLimits, angle_margin_rad: float = 0.0, rate_factor: float = 1.0) -> dict[str, float]:
    """The daemon's ``loop.limits`` from the START limits: the joint angle widened by
    ``angle_margin_rad`` [rad] and the rates by ``rate_factor`` (a move checks the START limits
    itself, the daemon's are the backstop)."""
    return {"q_out_min_rad": -L.q_out_max_rad - angle_margin_rad, "q_out_max_rad": L.q_out_max_rad + angle_margin_rad,
            "dq_out_max_rad_s": L.dq_out_max_rad_s * rate_factor, "dq_m_max_rad_s": L.dq_m_max_rad_s * rate_factor,
            "tension_min_N": L.tension_min_N, "tension_max_N": L.tension_max_N}


class Profile(Protocol):
    """A torque profile; may adapt to what it measures."""

    def torque_Nm(self, t_s: float, r: Any) -> float:
        """Command at ``t_s`` since the first stepped cycle, given the cycle record ``r``.

        :raises BringupStop: to refuse (e.g. the drive does not move).
        """

    def done(self, t_s: float) -> bool:
        """True once the profile is over."""


@dataclass
class StepData:
    """What one move measured (the stepped cycles, in order) and where it is logged."""

    name: str
    records: np.ndarray
    log_path: str | None

    def col(self, name: str) -> np.ndarray:
        """One field of every stepped cycle."""
        return np.asarray(self.records[name], dtype=float)

    @property
    def t_s(self) -> np.ndarray:
        """Time since the first stepped cycle [s]."""
        t = self.col("t_s")
        return t - t[0] if len(t) else t


class ProfileController:
    """The daemon's controller during a bring-up move (record, warmup, step as the law's).

    :param profile: the torque profile.
    :param limits: the START config's limits.
    :param r_in_m: input pulley radius (the logged input torque) [m].
    :param capacity: cycles kept in memory for the analysis.
    """

    def __init__(self, profile: Profile, limits: StepLimits, r_in_m: float, capacity: int) -> None:
        self.record = new_record()
        self.profile = profile
        self.limits = limits
        self.r_in_m = r_in_m
        self.kept = np.zeros(capacity, dtype=RECORD_DTYPE)
        self.n = 0
        self.reason = ""
        self.finished = False
        self.stop_request: Any = None
        #: called with the reason when a move stops (the daemon's log gets it as an event)
        self.on_stop: Any = None
        self._t0 = math.nan
        self._q_m0 = math.nan
        self._t_prev = math.nan
        #: longest interval the loop itself did not run [s]
        self.longest_gap_s = 0.0

    def warmup(self) -> None:
        """Nothing to compile."""

    def _limit(self, r: Any, t_s: float, gap_s: float) -> str:
        L = self.limits
        if not abs(float(r["q_m_rad"]) - self._q_m0) <= L.q_m_range_rad:
            return f"motor travel {float(r['q_m_rad']) - self._q_m0:+.3f} rad beyond +-{L.q_m_range_rad} rad"
        if not abs(float(r["dq_m_rad_s"])) <= L.dq_m_max_rad_s:
            return f"motor speed {float(r['dq_m_rad_s']):+.3f} rad/s beyond +-{L.dq_m_max_rad_s} rad/s"
        if not abs(float(r["q_out_rad"])) <= L.q_out_max_rad:
            return f"joint angle {float(r['q_out_rad']):+.3f} rad beyond +-{L.q_out_max_rad} rad"
        if not abs(float(r["dq_out_rad_s"])) <= L.dq_out_max_rad_s:
            return f"joint rate {float(r['dq_out_rad_s']):+.3f} rad/s beyond +-{L.dq_out_max_rad_s} rad/s"
        for name in ("T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N"):
            T = float(r[name])
            if not L.tension_min_N <= T <= L.tension_max_N:
                return f"tension {name} {T:.1f} N outside [{L.tension_min_N}, {L.tension_max_N}] N"
        for what, key in (("load cells", "lc_t_s"), ("IMU", "imu_t_s"), ("drive feedback", "motor_t_s")):
            age = t_s - float(r[key])
            if not age <= SENSOR_TIMEOUT_S + gap_s:
                return f"{what} silent for {age * 1e3:.0f} ms (limit {SENSOR_TIMEOUT_S * 1e3:.0f} ms): device lost"
        return ""

    def step(self) -> float:
        """One cycle: limits, then the profile's torque (clamped to ``tau_max_Nm``) [Nm]."""
        r = self.record[0]
        t_abs = float(r["t_s"])
        if math.isnan(self._t0):
            self._t0, self._q_m0 = t_abs, float(r["q_m_rad"])
        t = t_abs - self._t0
        gap = 0.0 if math.isnan(self._t_prev) else max(0.0, t_abs - self._t_prev - 0.001)
        self._t_prev = t_abs
        self.longest_gap_s = max(self.longest_gap_s, gap)
        r["tau_in_Nm"] = self.r_in_m * (float(r["T_up_in_N"]) - float(r["T_lo_in_N"]))
        r["T0_meas_N"] = 0.25 * (float(r["T_up_in_N"]) + float(r["T_up_out_N"]) + float(r["T_lo_out_N"])
                                 + float(r["T_lo_in_N"]))
        if int(r["fault_bits"]):
            return 0.0
        reason = self._limit(r, t_abs, gap)
        tau = 0.0
        if not reason:
            try:
                tau = float(self.profile.torque_Nm(t, r))
            except BringupStop as exc:
                reason = exc.reason
        if reason:
            self.reason = reason
            r["fault_bits"] = int(FaultBits.EXTERNAL_STOP)
            log.error("bring-up move stopped at t=%.3f s: %s", t, reason)
            if self.on_stop is not None:
                self.on_stop(t_abs, reason)
            return 0.0
        tau = max(-self.limits.tau_max_Nm, min(self.limits.tau_max_Nm, tau))
        r["tau_in_des_Nm"] = r["tau_m_raw_Nm"] = r["tau_m_cmd_Nm"] = tau
        if self.n < len(self.kept):
            self.kept[self.n] = r
            self.n += 1
        if not self.finished and self.profile.done(t):
            self.finished = True
            if self.stop_request is not None:
                self.stop_request()
        return tau


def daemon_mapping(start: RigStart, name: str) -> dict[str, Any]:
    """The daemon config of one bring-up move (devices of ``start``; logs under
    ``<logging.dir>/<name>``; loop limits as the START limits)."""
    L = start.limits
    return {
        "controller": {"dt_s": 0.001, "safety": {"tau_max_Nm": L.tau_max_Nm}},
        **{role: dict(sec) for role, sec in start.devices.items()},
        "logging": {"dir": str(start.log_dir / name.replace(" ", "_")), "ring_records": 8192, "fault_history_cycles": 500},
        "realtime": {"mode": "warn", "priority": 80, "lock_memory": False},
        "loop": {"period_s": 0.001, "busy_tail_s": 0.00015, "overrun_streak_fault": 50,
                 "sensor_fresh_s": 0.05, "startup_timeout_s": 5.0, "ramp_down_s": 0.1,
                 "limits": loop_limits(L, angle_margin_rad=0.1, rate_factor=1.5)},
    }


def run_profile(start: RigStart, step: str, name: str, profile: Profile, max_duration_s: float,
                overrides: Mapping[str, Mapping[str, Any]] | None = None) -> StepData:
    """Run ``profile`` through the daemon against the START config's devices.

    :param step: the bring-up step this move belongs to (named in a stop).
    :param name: the move's name (its log folder).
    :param overrides: device-section keys to set for this move (e.g. a corrected IMU sign).
    :raises BringupStop: on a limit, a lost or silent device, a refusal of the profile, or a
        device that does not start — torque zero, drive disabled, the reason in one line.
    """
    raw = daemon_mapping(start, name)
    for role, keys in (overrides or {}).items():
        raw[role] = {**raw[role], **keys}
    cfg = DaemonConfig.from_mapping(raw, source=start.source)
    Path(cfg.logging.dir).mkdir(parents=True, exist_ok=True)
    pristine = copy.deepcopy(vars(profile))       # the profile's state before the move (it may adapt)

    def once() -> tuple[tuple[ProfileController, Daemon], str]:
        ctl, daemon, stall = _run_once(cfg, step, name, profile, max_duration_s, start)
        return (ctl, daemon), stall

    def reset() -> None:                          # in place: the caller reads the profile afterwards
        vars(profile).update(copy.deepcopy(pristine))
    ctl, daemon = repeat_after_host_stalls(step, name, once, reset)
    log.info("%s: %d cycles, log %s", name, ctl.n, daemon.summary.log_path)
    return StepData(name, ctl.kept[:ctl.n].copy(), daemon.summary.log_path)


def _run_once(cfg: DaemonConfig, step: str, name: str, profile: Profile, max_duration_s: float,
              start: RigStart) -> tuple[ProfileController, Daemon, str]:
    """One attempt of :func:`run_profile`; returns the controller, the daemon and, if the move
    stopped on a host stall the daemon diagnosed (the process got no CPU, not a device or the
    profile), that stop's one-line reason ("" otherwise).

    :raises BringupStop: on any other stop, as :func:`run_profile`.
    """
    ctl = ProfileController(profile, start.limits, start.drawing.r_in_m, int(max_duration_s * 1000) + 2000)
    daemon = Daemon(cfg, controller=ctl)
    ctl.stop_request = daemon.request_stop

    def _logged(t_s: float, reason: str) -> None:
        if daemon.sink is not None:
            daemon.sink.fault(t_s, f"bring-up {step} stopped: {reason}", code=int(FaultBits.EXTERNAL_STOP),
                              n_cycles=1)
    ctl.on_stop = _logged
    try:
        daemon.run(duration_s=max_duration_s)
    except ControlFaultError as exc:
        text = (f"{name}: {ctl.reason or exc.reason} (torque zero, drive disabled; log "
                f"{daemon.summary.log_path})")
        if not ctl.reason and stalled_host(exc.reason):
            return ctl, daemon, text
        raise BringupStop(step, text) from None
    except BringupStop:
        raise
    except (DriverError, CapstanError) as exc:     # a device or the log writer failed: no torque was left on
        raise BringupStop(step, f"{name}: {type(exc).__name__}: {exc} (torque zero)") from None
    if not ctl.finished:
        raise BringupStop(step, f"{name}: the move did not finish within {max_duration_s:.0f} s "
                                f"(torque ramped to zero)")
    return ctl, daemon, ""
