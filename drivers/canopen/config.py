"""The ``motor:`` configuration section (CANopen CiA 402 drive), validated on load.

See ``config/motor.yaml`` for a documented example. Every invalid value raises
:class:`capstan.models.common.errors.ConfigError` naming the key (``motor.<key>``) and the reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from capstan.models.common.config_tools import get_choice, get_float, get_int, reject_unknown
from capstan.models.common.errors import ConfigError

#: directory of the EDS files shipped with capstan
DATA_DIR = Path(__file__).resolve().parent / "data"

_KEYS = frozenset({
    "backend", "interface", "channel", "bitrate", "node_id", "master_node_id", "eds",
    "mode", "encoder_counts_per_rev", "velocity_units_per_rev_s", "gear_ratio",
    "rated_torque_Nm", "max_torque_Nm", "cycle_period_s", "heartbeat_period_s",
    "drive_heartbeat_period_s", "consumer_timeout_s",
    "boot_timeout_s", "abort_connection_option", "comm_error_behaviour", "quick_stop_option",
    "shutdown_option", "fault_reset_at_start", "units",
})

#: what start-up does with the configured units: check them against the drive's, or write
#: the SI unit objects 0x60A8/0x60A9 from them first (then check)
UNITS_MODES = ("check", "write")

#: 0x6007 abort connection option codes accepted (CiA 402-2): 1 fault, 2 disable voltage,
#: 3 quick stop; 0 ("no action") is refused: the drive would keep the last torque when the
#: daemon dies
ABORT_CONNECTION_OPTIONS = (1, 2, 3)

MODES = ("cst", "profile_torque")


@dataclass(frozen=True)
class MotorConfig:
    """Frozen settings of the CANopen motor (SI units).

    :ivar interface: python-can interface (``socketcan`` on the rig, ``capstan_unix`` simulated).
    :ivar channel: python-can channel (``can0``; a directory for ``capstan_unix``).
    :ivar bitrate: CAN bit rate [bit/s] (ignored by virtual interfaces).
    :ivar node_id: drive node id 1..127.
    :ivar master_node_id: node id whose heartbeat the daemon produces (watched by the drive).
    :ivar eds: path of the drive's EDS/DCF.
    :ivar mode: ``cst`` (mode 10) or ``profile_torque`` (mode 4, only if 0x6502 lists it).
    :ivar encoder_counts_per_rev: units of 0x6064 per motor revolution; None: the drive's
        (0x60A8/0x608F/0x6091, read at start-up, :mod:`~capstan.drivers.canopen.drive_units`).
        A stated value is checked against the drive's and a difference refused.
    :ivar velocity_units_per_rev_s: units of 0x606C per motor rev/s (increments/s: the encoder
        counts; rpm: 60); None: the drive's (0x60A9/0x608F/0x6091), else checked as above.
    :ivar gear_ratio: motor revolutions per revolution of the reported shaft; None: the drive's
        0x6091 (1 where it has none), else checked against it.
    :ivar rated_torque_Nm: rated torque (unit of 0x6071/0x6077 is 1/1000 of it); None: read 0x6076,
        else checked against it.
    :ivar max_torque_Nm: commanded torque is clamped to +-this [Nm].
    :ivar cycle_period_s: control cycle = SYNC period = interpolation period 0x60C2 [s].
    :ivar heartbeat_period_s: period of the daemon's own heartbeat [s].
    :ivar drive_heartbeat_period_s: drive heartbeat 0x1017 [s]; lost after 3 periods.
    :ivar consumer_timeout_s: drive-side consumer time 0x1016 watching the daemon [s].
    :ivar boot_timeout_s: time start-up waits for the drive to boot (boot-up message or an
        SDO answer, polled with back-off) [s].
    :ivar abort_connection_option: 0x6007 written at start-up (1 fault, 2 disable voltage,
        3 quick stop): what the drive does when the daemon's heartbeat stops.
    :ivar comm_error_behaviour: 0x1029 sub 1 written at start-up (0 pre-operational,
        1 no state change, 2 stopped) on a communication error.
    :ivar quick_stop_option: 0x605A written where the drive has it (0..8, CiA 402-2).
    :ivar shutdown_option: 0x605B written where the drive has it (0 disable at once,
        1 ramp down then disable).
    :ivar units: ``check`` (default): the configured units must match the drive's;
        ``write``: 0x60A8/0x60A9 are written over SDO from ``encoder_counts_per_rev`` /
        ``velocity_units_per_rev_s`` (where stated) before the check.
    :ivar fault_reset_at_start: reset a drive found in FAULT at start-up whatever the
        fault (default: only the heartbeat-loss fault 0x8130 the daemon itself caused).
    """

    interface: str = "socketcan"
    channel: str = "can0"
    bitrate: int = 1_000_000
    node_id: int = 1
    master_node_id: int = 127
    eds: str = str(DATA_DIR / "capstan_drive.eds")
    mode: str = "cst"
    encoder_counts_per_rev: int | None = None
    velocity_units_per_rev_s: float | None = None
    gear_ratio: float | None = None
    rated_torque_Nm: float | None = None
    max_torque_Nm: float = 30.0
    cycle_period_s: float = 0.001
    heartbeat_period_s: float = 0.02
    drive_heartbeat_period_s: float = 0.01
    consumer_timeout_s: float = 0.1
    boot_timeout_s: float = 10.0
    abort_connection_option: int = 1
    comm_error_behaviour: int = 0
    quick_stop_option: int = 2
    shutdown_option: int = 0
    fault_reset_at_start: bool = False
    units: str = "check"

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any], prefix: str = "motor",
                     base_dir: str | Path | None = None) -> "MotorConfig":
        """Validate a ``motor:`` mapping.

        :param base_dir: directory relative EDS paths are resolved against
            (default: the current directory, then ``drivers/data``).
        :raises ConfigError: naming the offending key and the reason.
        """
        reject_unknown(cfg, _KEYS, prefix)
        d = cls()
        eds = cfg.get("eds", d.eds)
        if not isinstance(eds, str) or not eds:
            raise ConfigError(f"{prefix}.eds", f"must be a file path, got {eds!r}")
        path = Path(eds).expanduser()
        if not path.is_absolute():
            candidates = [Path(base_dir) / path] if base_dir is not None else [Path.cwd() / path]
            candidates.append(DATA_DIR / path)
            path = next((c for c in candidates if c.is_file()), candidates[0])
        if not path.is_file():
            raise ConfigError(f"{prefix}.eds", f"file not found: {path}")
        counts = cfg.get("encoder_counts_per_rev")
        vel_units = cfg.get("velocity_units_per_rev_s")
        gear = cfg.get("gear_ratio")
        rated = cfg.get("rated_torque_Nm")
        out = cls(
            interface=_get_str(cfg, "interface", prefix, d.interface),
            channel=_get_str(cfg, "channel", prefix, d.channel),
            bitrate=get_int(cfg, "bitrate", prefix, d.bitrate, min_value=10_000, max_value=1_000_000),
            node_id=get_int(cfg, "node_id", prefix, d.node_id, min_value=1, max_value=127),
            master_node_id=get_int(cfg, "master_node_id", prefix, d.master_node_id, min_value=1, max_value=127),
            eds=str(path),
            mode=get_choice(cfg, "mode", MODES, prefix, d.mode),
            encoder_counts_per_rev=None if counts is None else get_int(cfg, "encoder_counts_per_rev", prefix,
                                                                       min_value=1),
            velocity_units_per_rev_s=None if vel_units is None else get_float(
                cfg, "velocity_units_per_rev_s", prefix, min_value=0.0, min_exclusive=True),
            gear_ratio=None if gear is None else get_float(cfg, "gear_ratio", prefix, min_value=0.0,
                                                           min_exclusive=True),
            rated_torque_Nm=None if rated is None else get_float(cfg, "rated_torque_Nm", prefix,
                                                                  min_value=0.0, min_exclusive=True),
            max_torque_Nm=get_float(cfg, "max_torque_Nm", prefix, d.max_torque_Nm, min_value=0.0,
                                    min_exclusive=True),
            cycle_period_s=get_float(cfg, "cycle_period_s", prefix, d.cycle_period_s, min_value=1e-4,
                                     max_value=0.255),
            heartbeat_period_s=get_float(cfg, "heartbeat_period_s", prefix, d.heartbeat_period_s,
                                         min_value=0.001, max_value=65.0),
            drive_heartbeat_period_s=get_float(cfg, "drive_heartbeat_period_s", prefix,
                                               d.drive_heartbeat_period_s, min_value=0.001, max_value=65.0),
            consumer_timeout_s=get_float(cfg, "consumer_timeout_s", prefix, d.consumer_timeout_s,
                                         min_value=0.001, max_value=65.0),
            boot_timeout_s=get_float(cfg, "boot_timeout_s", prefix, d.boot_timeout_s, min_value=0.1,
                                     max_value=300.0),
            abort_connection_option=_get_code(cfg, "abort_connection_option", prefix,
                                              d.abort_connection_option, ABORT_CONNECTION_OPTIONS,
                                              " (0 = no action: the drive would keep the last torque "
                                              "when the daemon dies)"),
            comm_error_behaviour=_get_code(cfg, "comm_error_behaviour", prefix, d.comm_error_behaviour,
                                           (0, 1, 2)),
            quick_stop_option=_get_code(cfg, "quick_stop_option", prefix, d.quick_stop_option,
                                        tuple(range(9))),
            shutdown_option=_get_code(cfg, "shutdown_option", prefix, d.shutdown_option, (0, 1)),
            fault_reset_at_start=_get_bool(cfg, "fault_reset_at_start", prefix, d.fault_reset_at_start),
            units=get_choice(cfg, "units", UNITS_MODES, prefix, d.units),
        )
        if out.node_id == out.master_node_id:
            raise ConfigError(f"{prefix}.master_node_id", f"must differ from node_id {out.node_id}")
        if out.consumer_timeout_s <= out.heartbeat_period_s:
            raise ConfigError(f"{prefix}.consumer_timeout_s",
                              f"must exceed heartbeat_period_s ({out.heartbeat_period_s} s), "
                              f"got {out.consumer_timeout_s} s")
        return out


def _get_str(cfg: Mapping[str, Any], key: str, prefix: str, default: str) -> str:
    val = cfg.get(key, default)
    if not isinstance(val, str) or not val:
        raise ConfigError(f"{prefix}.{key}", f"must be a non-empty string, got {val!r}")
    return val


def _get_code(cfg: Mapping[str, Any], key: str, prefix: str, default: int, allowed: tuple[int, ...],
              why: str = "") -> int:
    val = cfg.get(key, default)
    if isinstance(val, bool) or not isinstance(val, int) or val not in allowed:
        raise ConfigError(f"{prefix}.{key}", f"must be one of {', '.join(map(str, allowed))}, got {val!r}{why}")
    return val


def _get_bool(cfg: Mapping[str, Any], key: str, prefix: str, default: bool) -> bool:
    val = cfg.get(key, default)
    if not isinstance(val, bool):
        raise ConfigError(f"{prefix}.{key}", f"must be true or false, got {val!r}")
    return val
