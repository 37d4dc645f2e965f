"""The start of a bring-up (``config/rig_start.yaml``): devices, drawing values, the
calibration reference and the safety limits — nothing measured.

Sections::

    devices:     {motor: {...}, imu: {...}, load_cells: {...}}   as in a daemon config
    drawing:     {r_in_m, r_out_m, length_m, theta_rad}          pulleys, sheath length, bending
    calibration: {reference: drive_torque, scale_tolerance, rest_s}
    limits:      {tau_max_Nm, dq_m_max_rad_s, q_m_range_rad, q_out_max_rad, dq_out_max_rad_s,
                  tension_min_N, tension_max_N}
    logging:     {dir}

Every invalid value raises :class:`capstan.models.common.errors.ConfigError` naming the key.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from capstan.models.common.config_tools import get_choice, get_float, load_yaml, reject_unknown, section
from capstan.models.common.errors import CapstanError, ConfigError

#: calibration references the workflow can use without a person at the rig
REFERENCES = ("drive_torque",)


class BringupStop(CapstanError):
    """A bring-up step refused to go on (a mismatch, a limit, a lost device); torque is zero.

    :ivar step: the step that stopped (check, calibrate, identify, tune).
    :ivar reason: one line naming what was found.
    """

    def __init__(self, step: str, reason: str) -> None:
        self.step = step
        self.reason = reason
        super().__init__(f"{step}: {reason}")


@dataclass(frozen=True)
class Drawing:
    """Values from the rig's drawings [m, rad]."""

    r_in_m: float
    r_out_m: float
    length_m: float
    theta_rad: float


@dataclass(frozen=True)
class StepLimits:
    """Limits of every bring-up move; any one reached -> zero torque and the step stops.

    :ivar tau_max_Nm: largest commanded motor torque [Nm].
    :ivar dq_m_max_rad_s: largest motor speed [rad/s].
    :ivar q_m_range_rad: largest motor travel from the step's start [rad].
    :ivar q_out_max_rad: largest |joint angle| [rad].
    :ivar dq_out_max_rad_s: largest |joint rate| [rad/s].
    :ivar tension_min_N: lowest tension (slack guard) [N].
    :ivar tension_max_N: highest tension [N].
    """

    tau_max_Nm: float = 4.0
    dq_m_max_rad_s: float = 3.0
    q_m_range_rad: float = 1.0
    q_out_max_rad: float = 0.9
    dq_out_max_rad_s: float = 3.0
    tension_min_N: float = 5.0
    tension_max_N: float = 600.0


@dataclass(frozen=True)
class Calibration:
    """:ivar reference: what the load-cell scale is checked against.
    :ivar scale_tolerance: relative scale error beyond which a channel is named [-].
    :ivar rest_s: still time for the zero and the gyro bias [s]."""

    reference: str = "drive_torque"
    scale_tolerance: float = 0.05
    rest_s: float = 1.0


@dataclass(frozen=True)
class RigStart:
    """A validated START config."""

    devices: Mapping[str, Mapping[str, Any]]
    drawing: Drawing
    calibration: Calibration
    limits: StepLimits
    log_dir: Path
    source: Path | None = None

    @staticmethod
    def load(path: str | Path) -> "RigStart":
        """:raises ConfigError: naming the offending key."""
        p = Path(path)
        return RigStart.from_mapping(load_yaml(p), base_dir=p.resolve().parent.parent, source=p)

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], base_dir: Path | None = None,
                     source: Path | None = None) -> "RigStart":
        """:raises ConfigError: naming the offending key."""
        reject_unknown(cfg, {"devices", "drawing", "calibration", "limits", "logging"})
        dev = section(cfg, "devices")
        reject_unknown(dev, {"motor", "imu", "load_cells"}, "devices")
        devices = {role: dict(section(dev, role, "devices")) for role in ("motor", "imu", "load_cells")}
        for role, sec in devices.items():
            if not isinstance(sec.get("backend"), str):
                raise ConfigError(f"devices.{role}.backend", "missing; the device backend name")
        dr = section(cfg, "drawing")
        reject_unknown(dr, {"r_in_m", "r_out_m", "length_m", "theta_rad"}, "drawing")

        def pos(c: Mapping[str, Any], key: str, prefix: str, default: Any = ...) -> float:
            kw = {} if default is ... else {"default": default}
            return get_float(c, key, prefix, min_value=0.0, min_exclusive=True, **kw)

        drawing = Drawing(pos(dr, "r_in_m", "drawing"), pos(dr, "r_out_m", "drawing"),
                          pos(dr, "length_m", "drawing"), get_float(dr, "theta_rad", "drawing", min_value=0.0))
        ca = section(cfg, "calibration", required=False)
        reject_unknown(ca, {"reference", "scale_tolerance", "rest_s"}, "calibration")
        d = Calibration()
        calib = Calibration(get_choice(ca, "reference", REFERENCES, "calibration", d.reference),
                            get_float(ca, "scale_tolerance", "calibration", d.scale_tolerance, min_value=0.005,
                                      max_value=0.5),
                            get_float(ca, "rest_s", "calibration", d.rest_s, min_value=0.2, max_value=30.0))
        li = section(cfg, "limits")
        dl = StepLimits()
        reject_unknown(li, set(StepLimits.__dataclass_fields__), "limits")
        limits = StepLimits(**{k: pos(li, k, "limits", getattr(dl, k)) for k in StepLimits.__dataclass_fields__})
        if limits.tension_min_N >= limits.tension_max_N:
            raise ConfigError("limits.tension_max_N", f"must exceed tension_min_N ({limits.tension_min_N})")
        max_drive = get_float(devices["motor"], "max_torque_Nm", "devices.motor", 30.0)
        if limits.tau_max_Nm > max_drive:
            raise ConfigError("limits.tau_max_Nm", f"{limits.tau_max_Nm} Nm exceeds devices.motor.max_torque_Nm "
                                                   f"({max_drive} Nm)")
        lg = section(cfg, "logging", required=False)
        reject_unknown(lg, {"dir"}, "logging")
        raw_dir = lg.get("dir", "runs/bringup")
        if not isinstance(raw_dir, str) or not raw_dir:
            raise ConfigError("logging.dir", f"must be a directory path, got {raw_dir!r}")
        log_dir = Path(raw_dir).expanduser()
        if not log_dir.is_absolute() and base_dir is not None:
            log_dir = base_dir / log_dir
        return RigStart(devices, drawing, calib, limits, log_dir, source)

    def with_ports(self, ports: Mapping[str, Any]) -> "RigStart":
        """A copy on a served simulated rig: the drive on its ``capstan_unix`` bus, the IMU and
        the load cells on its ptys (``ports`` of its endpoint line; ``auto`` for a config
        that ``capstan hil`` fills in)."""
        dev = {k: dict(v) for k, v in self.devices.items()}
        dev["motor"].update(interface="capstan_unix", channel=ports["channel"])
        dev["imu"]["port"] = ports["imu_port"]
        dev["load_cells"]["port"] = ports["load_cells_port"]
        return RigStart(dev, self.drawing, self.calibration, self.limits, self.log_dir, self.source)
