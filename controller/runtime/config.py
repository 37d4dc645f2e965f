"""Validated configuration of the daemon (``config/rig.yaml``, ``config/hil.yaml``).

Sections::

    controller:  passed to ControllerConfig.from_mapping (validated there)
    motor:       {backend: <name>, ...backend options}     see drivers.registry
    imu:         {backend: <name>, ...}
    load_cells:  {backend: <name>, ...}
    logging:     {dir, ring_records, fault_history_cycles, on_writer_loss: restart|stop,
                  max_writer_restarts}
    realtime:    {mode: off|warn|enforce, priority, helper_priority, cpus, lock_memory,
                  gil_switch_interval_s}
    loop:        {period_s, busy_tail_s, overrun_streak_fault, sensor_fresh_s, ramp_down_s,
                  startup_timeout_s, stats_interval_s, limits: {...}}
    lab_override: {reason, ranges, margins}   controller/runtime/plausibility.py

Safety-relevant keys must also lie in plausible ranges
(:data:`capstan.controller.runtime.plausibility.PLAUSIBLE_RANGES`) and the gains must meet
the loop's stability margins (checked when the daemon builds its controller), unless
``lab_override`` says otherwise with a reason.

Every invalid value raises :class:`capstan.models.common.errors.ConfigError` naming the dotted key.
Relative paths (``logging.dir``) are resolved against the config file's directory's
parent, so ``config/rig.yaml`` with ``dir: runs/logs`` logs to ``<repo>/runs/logs``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from capstan.controller.runtime.plausibility import LabOverride, check_plausible, lab_override_from_mapping
from capstan.controller.runtime.realtime import RealtimeMode, RealtimeSettings
from capstan.models.common.config_tools import (get_bool, get_choice, get_float, get_int, load_yaml,
                                 reject_unknown, section)
from capstan.models.common.errors import ConfigError

SECTIONS = frozenset({"controller", "motor", "imu", "load_cells", "logging", "realtime", "loop", "hil",
                      "lab_override"})


@dataclass(frozen=True)
class Limits:
    """Limits checked every cycle; a violation is a fault.

    :ivar q_out_min_rad: lowest allowed joint angle [rad].
    :ivar q_out_max_rad: highest allowed joint angle [rad].
    :ivar dq_out_max_rad_s: largest allowed |joint rate| [rad/s].
    :ivar dq_m_max_rad_s: largest allowed |motor velocity| [rad/s].
    :ivar tension_min_N: lowest allowed cable tension (slack guard) [N].
    :ivar tension_max_N: highest allowed cable tension [N].
    """

    q_out_min_rad: float = -2.0
    q_out_max_rad: float = 2.0
    dq_out_max_rad_s: float = 10.0
    dq_m_max_rad_s: float = 20.0
    tension_min_N: float = 5.0
    tension_max_N: float = 600.0


@dataclass(frozen=True)
class LoopSettings:
    """Loop pacing, fault thresholds and shutdown behaviour (all SI).

    :ivar period_s: control period [s].
    :ivar busy_tail_s: busy-wait before each deadline [s].
    :ivar overrun_streak_fault: this many consecutive late cycles is a fault.
    :ivar sensor_fresh_s: at start-up, every device must have delivered data this
        recently before READY (afterwards staleness is the step's STALE_* check) [s].
    :ivar startup_timeout_s: time for all devices to deliver fresh data, and for the loop to
        hold its period, after enable [s].
    :ivar arm_on_time_cycles: the loop arms (starts commanding torque) only after this many
        consecutive on-time cycles with every device fresh; late cycles before arming are
        not a fault (the command is zero), only a start-up timeout.
    :ivar ramp_down_s: torque ramp to zero on SIGTERM/SIGINT [s].
    :ivar stats_interval_s: timing statistics reporting interval [s].
    :ivar limits: see :class:`Limits`.
    """

    period_s: float = 1e-3
    busy_tail_s: float = 150e-6
    overrun_streak_fault: int = 10
    sensor_fresh_s: float = 0.02
    startup_timeout_s: float = 5.0
    ramp_down_s: float = 0.2
    stats_interval_s: float = 1.0
    limits: Limits = field(default_factory=Limits)
    arm_on_time_cycles: int = 200


@dataclass(frozen=True)
class LoggingSettings:
    """:ivar dir: directory for MCAP logs and fault reports.
    :ivar ring_records: capacity of the shared-memory ring [records].
    :ivar fault_history_cycles: cycles attached to a fault report (the last N).
    :ivar on_writer_loss: ``restart`` the log writer into a new file when it dies (the gap
        written as an event), or ``stop`` the loop (torque ramped to zero).
    :ivar max_writer_restarts: writer deaths tolerated under ``restart``; one more stops.
    :ivar rotate_size_MB: start a new file at this size [MB] (0 = never).
    :ivar rotate_age_s: start a new file after this long [s] (0 = never).
    :ivar keep_newest_GB: delete the oldest files beyond this total [GB] (0 = keep all).
    """

    dir: Path = Path("runs/logs")
    ring_records: int = 8192
    fault_history_cycles: int = 500
    on_writer_loss: str = "restart"
    max_writer_restarts: int = 3
    rotate_size_MB: float = 0.0
    rotate_age_s: float = 0.0
    keep_newest_GB: float = 0.0


@dataclass(frozen=True)
class DaemonConfig:
    """The whole daemon configuration. ``controller`` and the device sections stay
    mappings: their owners validate them (controller config, driver backends)."""

    controller: Mapping[str, Any]
    motor: Mapping[str, Any]
    imu: Mapping[str, Any]
    load_cells: Mapping[str, Any]
    logging: LoggingSettings
    realtime: RealtimeSettings
    loop: LoopSettings
    hil: Mapping[str, Any]
    source: Path | None = None
    raw: Mapping[str, Any] = field(default_factory=dict)
    lab_override: LabOverride = field(default_factory=LabOverride)
    overridden: tuple[str, ...] = ()

    @staticmethod
    def load(path: str | Path) -> "DaemonConfig":
        """Load and validate a YAML file.

        :raises ConfigError: naming the offending key.
        """
        p = Path(path)
        return DaemonConfig.from_mapping(load_yaml(p), base_dir=p.resolve().parent.parent, source=p)

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], base_dir: Path | None = None,
                     source: Path | None = None) -> "DaemonConfig":
        """Validate a parsed mapping; relative log dirs resolve against ``base_dir``.

        :raises ConfigError: naming the offending key.
        """
        reject_unknown(cfg, SECTIONS)
        override = lab_override_from_mapping(section(cfg, "lab_override", required=False))
        devices = {}
        for role in ("motor", "imu", "load_cells"):
            sec = section(cfg, role)
            if not isinstance(sec.get("backend"), str) or not sec.get("backend"):
                raise ConfigError(f"{role}.backend", "missing; the device backend name (see drivers.registry)")
            devices[role] = sec
        loop = _loop(section(cfg, "loop", required=False))
        overridden = tuple(check_plausible(cfg, override))   # after the sections' own checks
        return DaemonConfig(
            controller=section(cfg, "controller"),
            motor=devices["motor"], imu=devices["imu"], load_cells=devices["load_cells"],
            logging=_logging(section(cfg, "logging", required=False), base_dir),
            realtime=_realtime(section(cfg, "realtime", required=False)),
            loop=loop,
            hil=section(cfg, "hil", required=False),
            source=source,
            raw=dict(cfg),
            lab_override=override,
            overridden=overridden,
        )


def _logging(c: Mapping[str, Any], base_dir: Path | None) -> LoggingSettings:
    p = "logging"
    reject_unknown(c, {"dir", "ring_records", "fault_history_cycles", "on_writer_loss", "max_writer_restarts",
                       "rotate_size_MB", "rotate_age_s", "keep_newest_GB"}, p)
    d = LoggingSettings()
    raw = c.get("dir", str(d.dir))
    if not isinstance(raw, str) or not raw:
        raise ConfigError(f"{p}.dir", f"must be a directory path, got {raw!r}")
    path = Path(raw).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = base_dir / path
    return LoggingSettings(path, get_int(c, "ring_records", p, d.ring_records, min_value=64),
                           get_int(c, "fault_history_cycles", p, d.fault_history_cycles, min_value=1),
                           get_choice(c, "on_writer_loss", ("restart", "stop"), p, d.on_writer_loss),
                           get_int(c, "max_writer_restarts", p, d.max_writer_restarts, min_value=0, max_value=100),
                           _size(c, "rotate_size_MB", p, 1.0), _size(c, "rotate_age_s", p, 10.0),
                           _size(c, "keep_newest_GB", p, 0.01))


def _size(c: Mapping[str, Any], key: str, p: str, smallest: float) -> float:
    """A rotation/retention setting: 0 (off) or a finite value >= ``smallest``."""
    v = get_float(c, key, p, 0.0)
    if v != 0.0 and not (math.isfinite(v) and v >= smallest):
        raise ConfigError(f"{p}.{key}", f"must be 0 (off) or a finite value >= {smallest}, got {v}")
    return v


def _realtime(c: Mapping[str, Any]) -> RealtimeSettings:
    p = "realtime"
    reject_unknown(c, {"mode", "priority", "cpus", "lock_memory", "gil_switch_interval_s", "helper_priority"}, p)
    d = RealtimeSettings()
    mode = get_choice(c, "mode", ("off", "warn", "enforce"), p, d.mode.name.lower())
    cpus = c.get("cpus", [])
    if cpus is None:
        cpus = []
    if not isinstance(cpus, list) or not all(isinstance(x, int) and not isinstance(x, bool) and x >= 0
                                             for x in cpus):
        raise ConfigError(f"{p}.cpus", f"must be a list of CPU numbers >= 0, got {cpus!r}")
    prio = get_int(c, "priority", p, d.priority, 1, 99)
    helper = get_int(c, "helper_priority", p, max(prio - 10, 1), 0, 99)
    if helper >= prio:
        raise ConfigError(f"{p}.helper_priority", f"must be below priority ({prio}), got {helper}")
    return RealtimeSettings(RealtimeMode.parse(mode), prio,
                            tuple(cpus), get_bool(c, "lock_memory", p, d.lock_memory),
                            get_float(c, "gil_switch_interval_s", p, d.gil_switch_interval_s,
                                      min_value=0.0, max_value=0.1), helper)


def _loop(c: Mapping[str, Any]) -> LoopSettings:
    p = "loop"
    d = LoopSettings()
    keys = {"period_s", "busy_tail_s", "overrun_streak_fault", "sensor_fresh_s", "startup_timeout_s",
            "ramp_down_s", "stats_interval_s", "limits", "arm_on_time_cycles"}
    reject_unknown(c, keys, p)

    def pos(key: str) -> float:
        return get_float(c, key, p, getattr(d, key), min_value=0.0, min_exclusive=True)

    period = get_float(c, "period_s", p, d.period_s, min_value=1e-4, max_value=0.1)
    tail = get_float(c, "busy_tail_s", p, d.busy_tail_s, min_value=0.0)
    if tail >= period:
        raise ConfigError(f"{p}.busy_tail_s", f"must be shorter than period_s ({period}), got {tail}")
    out = LoopSettings(period, tail, get_int(c, "overrun_streak_fault", p, d.overrun_streak_fault, min_value=1),
                       pos("sensor_fresh_s"),
                       pos("startup_timeout_s"), get_float(c, "ramp_down_s", p, d.ramp_down_s, min_value=0.0),
                       pos("stats_interval_s"), _limits(section(c, "limits", p, required=False)),
                       get_int(c, "arm_on_time_cycles", p, d.arm_on_time_cycles, min_value=1))
    if out.sensor_fresh_s < period:
        raise ConfigError(f"{p}.sensor_fresh_s", f"must be >= period_s ({period}), got {out.sensor_fresh_s}")
    return out


def _limits(c: Mapping[str, Any]) -> Limits:
    p = "loop.limits"
    d = Limits()
    reject_unknown(c, set(Limits.__dataclass_fields__), p)
    vals = {k: get_float(c, k, p, getattr(d, k)) for k in Limits.__dataclass_fields__}
    for lo, hi in (("q_out_min_rad", "q_out_max_rad"), ("tension_min_N", "tension_max_N")):
        if not vals[lo] < vals[hi]:
            raise ConfigError(f"{p}.{hi}", f"must be > {lo} ({vals[lo]}), got {vals[hi]}")
    for k in ("dq_out_max_rad_s", "dq_m_max_rad_s"):
        if not vals[k] > 0 or math.isinf(vals[k]):
            raise ConfigError(f"{p}.{k}", f"must be > 0, got {vals[k]}")
    return Limits(**vals)
