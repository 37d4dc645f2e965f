"""The units of a CiA 402 drive's feedback, read from the drive at start-up (SDO), never assumed.

What :func:`read_drive_units` reads, where the drive's EDS lists the object:

* 0x608F position encoder resolution (increments : motor revolutions),
* 0x6091 gear ratio (motor revolutions : shaft revolutions),
* 0x6092 feed constant (feed : shaft revolutions; read and reported only: capstan's
  axis is rotary and the SI unit object says what the numbers mean),
* 0x60A8 SI unit position, 0x60A9 SI unit velocity (:mod:`~capstan.drivers.canopen.si_units`),
* 0x6076 motor rated torque [mNm] (the unit of 0x6071/0x6077 is 1/1000 of it).

From them it derives the scale of each TPDO value on the *reported shaft* (after the
gear): rad per unit of 0x6064, rad/s per unit of 0x606C, Nm of 1000 per mille. An angle
unit (rad, degree, revolution with a prefix) is an angle of the shaft the drive's gear
0x6091 drives (the motor's where the drive lists no 0x6091); increments are counts of
the motor encoder (0x608F), divided by the gear ratio.

Each value the ``motor:`` configuration states (``encoder_counts_per_rev`` = units of
0x6064 per motor revolution, ``velocity_units_per_rev_s`` = units of 0x606C per motor
rev/s, ``gear_ratio``, ``rated_torque_Nm``) is checked against the drive's: a difference is
refused with :class:`DriveUnitsError` naming the key, the object, the drive's value and
the configuration's. A value the configuration leaves out is the drive's; a value neither
states is refused (ConfigError naming the key and the missing object).

With ``motor.units: write``, :func:`write_configured_units` first writes 0x60A8/0x60A9 from
the configured ``encoder_counts_per_rev`` / ``velocity_units_per_rev_s`` (the SI unit code
that makes them, read back), not stored in the drive's non-volatile memory; the check then
runs as always. The gear, encoder resolution and rated torque are never written.

Start-up only: SDO through canopen's client, never on the per-cycle path.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import canopen

from capstan.drivers.canopen.config import MotorConfig
from capstan.drivers.canopen.sdo_access import has_object, sdo_read, sdo_write
from capstan.drivers.canopen.si_units import LINEAR_UNITS, SiUnit, code_for
from capstan.models.common.errors import ConfigError, DriverError

logger = logging.getLogger(__name__)

#: relative difference above which a configured unit contradicts the drive's (the units are
#: exact ratios of integers: anything but rounding of the configured decimal is a mismatch)
UNIT_RTOL = 1e-6
#: the same for the rated torque (0x6076 holds whole mNm)
TORQUE_RTOL = 0.005


class DriveUnitsError(ConfigError):
    """The drive's units contradict the configuration (or cannot be used): key, object, both values."""


@dataclass(frozen=True)
class DriveUnits:
    """Scale factors of the drive's feedback, and what the drive said.

    :ivar position_rad_per_unit: reported-shaft angle of one unit of 0x6064 [rad].
    :ivar velocity_rad_s_per_unit: reported-shaft speed of one unit of 0x606C [rad/s].
    :ivar rated_torque_Nm: torque of 1000 per mille of 0x6071/0x6077 [Nm].
    :ivar position_units_per_rev: units of 0x6064 per motor revolution.
    :ivar velocity_units_per_rev_s: units of 0x606C per motor rev/s.
    :ivar gear_ratio: motor revolutions per reported-shaft revolution.
    :ivar reported: the objects as the drive reported them (``{"0x60A9": "0x00B44700 (rpm)"}``).
    :ivar source: where each value came from (``{"velocity_units_per_rev_s": "drive 0x60A9"}``).
    """

    position_rad_per_unit: float
    velocity_rad_s_per_unit: float
    rated_torque_Nm: float
    position_units_per_rev: float
    velocity_units_per_rev_s: float
    gear_ratio: float
    reported: dict[str, str] = field(default_factory=dict)
    source: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The units as a JSON-ready mapping (the log's ``capstan.drive_units`` metadata)."""
        return {"position_rad_per_unit": self.position_rad_per_unit,
                "velocity_rad_s_per_unit": self.velocity_rad_s_per_unit,
                "rated_torque_Nm": self.rated_torque_Nm,
                "position_units_per_rev": self.position_units_per_rev,
                "velocity_units_per_rev_s": self.velocity_units_per_rev_s,
                "gear_ratio": self.gear_ratio, "reported": dict(self.reported), "source": dict(self.source)}

    @classmethod
    def from_config(cls, cfg: MotorConfig) -> "DriveUnits | None":
        """The units as the configuration alone states them (before start-up); None unless it
        states the position and velocity units and the rated torque."""
        if None in (cfg.encoder_counts_per_rev, cfg.velocity_units_per_rev_s, cfg.rated_torque_Nm):
            return None
        gear = cfg.gear_ratio or 1.0
        return cls(2 * math.pi / cfg.encoder_counts_per_rev / gear, 2 * math.pi / cfg.velocity_units_per_rev_s / gear,
                   cfg.rated_torque_Nm, float(cfg.encoder_counts_per_rev), cfg.velocity_units_per_rev_s, gear,
                   source={"all": "config"})


def _ratio(node: canopen.RemoteNode, index: int) -> tuple[int, int] | None:
    """(sub 1, sub 2) of a numerator/denominator object, None where the EDS lacks it."""
    if not (has_object(node, index, 1) and has_object(node, index, 2)):
        return None
    return sdo_read(node, index, 1), sdo_read(node, index, 2)


def _check(key: str, configured: float | None, drive: float, what: str, unit: str, rtol: float = UNIT_RTOL) -> None:
    """Refuse a configured value that differs from the drive's (key, object, both values)."""
    if configured is not None and abs(configured - drive) > rtol * abs(drive):
        raise DriveUnitsError(f"motor.{key}", f"the drive reports {what}: {drive:.9g} {unit}; the config "
                              f"states {configured:.9g} {unit}. Remove motor.{key} to use the drive's value, "
                              f"or correct it (docs/drive-bring-up.md, 'Units refused at start-up')")


def read_drive_units(node: canopen.RemoteNode, cfg: MotorConfig) -> DriveUnits:
    """Read the unit objects over SDO, derive the scales, check them against ``cfg``.

    :raises DriveUnitsError: if a configured value contradicts the drive's (key, object, values),
        or the drive reports a unit capstan cannot use (linear, unknown code).
    :raises ConfigError: if neither the drive nor the configuration gives a value.
    :raises DriverError: (SdoRefusedError, DeviceTimeoutError) if a read fails (object named).
    """
    reported: dict[str, str] = {}
    source: dict[str, str] = {}

    enc = _ratio(node, 0x608F)
    inc_per_rev: float | None = None
    if enc is not None:
        reported["0x608F"] = f"{enc[0]} inc / {enc[1]} rev"
        if enc[0] > 0 and enc[1] > 0:
            inc_per_rev = enc[0] / enc[1]
    gear = _ratio(node, 0x6091)
    if gear is not None:
        reported["0x6091"] = f"{gear[0]} motor rev / {gear[1]} shaft rev"
        if not (gear[0] > 0 and gear[1] > 0):
            raise DriveUnitsError("motor.gear_ratio", f"the drive's gear ratio 0x6091 = {gear[0]}:{gear[1]} "
                                  f"is not a ratio of positive integers")
        drive_gear = gear[0] / gear[1]
        _check("gear_ratio", cfg.gear_ratio, drive_gear,
               f"gear ratio 0x6091 = {gear[0]}:{gear[1]}", "motor revs per shaft rev")
        gear_ratio, source["gear_ratio"] = drive_gear, "drive 0x6091"
    else:
        drive_gear = 1.0
        gear_ratio = cfg.gear_ratio if cfg.gear_ratio is not None else 1.0
        source["gear_ratio"] = "config" if cfg.gear_ratio is not None else "1 (the drive lists no 0x6091)"
    feed = _ratio(node, 0x6092)
    if feed is not None:
        reported["0x6092"] = f"{feed[0]} feed / {feed[1]} shaft rev"
    # the drive's gear is in its own angle units; the driver divides only by a gear the drive lacks
    outside_gear = gear_ratio / drive_gear

    pos_rad = _angle_scale(node, 0x60A8, "SI unit position", "encoder_counts_per_rev", cfg.encoder_counts_per_rev,
                           inc_per_rev, drive_gear, outside_gear, reported, source, time_unit=False)
    vel_rad_s = _angle_scale(node, 0x60A9, "SI unit velocity", "velocity_units_per_rev_s",
                             cfg.velocity_units_per_rev_s, inc_per_rev, drive_gear, outside_gear, reported,
                             source, time_unit=True)
    rated = _rated_torque_Nm(node, cfg, reported, source)
    units = DriveUnits(pos_rad, vel_rad_s, rated, 2 * math.pi / (gear_ratio * pos_rad),
                       2 * math.pi / (gear_ratio * vel_rad_s), gear_ratio, reported, source)
    logger.info("drive %d units: 0x6064 %.6g rad/unit (%.6g units/motor rev), 0x606C %.6g rad/s/unit "
                "(%.6g units per motor rev/s), rated torque %.4g Nm, gear %.6g; drive reported %s",
                node.id, units.position_rad_per_unit, units.position_units_per_rev,
                units.velocity_rad_s_per_unit, units.velocity_units_per_rev_s, rated, gear_ratio,
                reported or "no unit objects")
    return units


def _angle_scale(node: canopen.RemoteNode, index: int, name: str, key: str, configured: float | None,
                 inc_per_rev: float | None, drive_gear: float, outside_gear: float, reported: dict[str, str],
                 source: dict[str, str], time_unit: bool) -> float:
    """Reported-shaft rad (or rad/s) per unit of 0x6064 (0x606C) from 0x60A8 (0x60A9) and 0x608F."""
    quantity = "0x606C" if time_unit else "0x6064"
    per = "motor rev/s" if time_unit else "motor rev"
    unit: SiUnit | None = None
    if has_object(node, index):
        unit = SiUnit.decode(sdo_read(node, index))
        reported[f"0x{index:04X}"] = str(unit)
        if unit.numerator in LINEAR_UNITS:
            raise DriveUnitsError(f"motor.{key}", f"the drive reports {quantity} in {unit} (0x{index:04X} {name}), "
                                  f"a linear unit; capstan's drive is rotary: set 0x{index:04X} to an angle unit")
        seconds = 1.0
        if time_unit:
            if unit.seconds is None:
                raise DriveUnitsError(f"motor.{key}", f"0x{index:04X} ({name}) = {unit}: the denominator is "
                                      f"not a time unit capstan knows (s, min, h)")
            seconds = unit.seconds
        elif unit.denominator:
            raise DriveUnitsError(f"motor.{key}", f"0x{index:04X} ({name}) = {unit}: a position unit has no "
                                  f"denominator")
        if unit.is_increments:
            if inc_per_rev is None:
                raise DriveUnitsError(f"motor.{key}", f"0x{index:04X} ({name}) = {unit} counts encoder "
                                      f"increments, but the drive gives no 0x608F encoder resolution")
            motor_rad = 2 * math.pi / inc_per_rev * 10.0 ** unit.exponent / seconds
            scale = motor_rad / drive_gear / outside_gear
            what = f"0x{index:04X} ({name}) = {unit} with 0x608F = {reported['0x608F']}"
        elif unit.radians is not None:
            scale = unit.radians / seconds / outside_gear
            what = f"0x{index:04X} ({name}) = {unit}"
            if drive_gear != 1.0:
                what += f" of the shaft behind gear 0x6091 = {reported['0x6091']}"
        else:
            raise DriveUnitsError(f"motor.{key}", f"0x{index:04X} ({name}) = {unit}: unit code "
                                  f"0x{unit.numerator:02X} is not an angle capstan knows (rad, degree, "
                                  f"revolution, increments)")
        gear_total = drive_gear * outside_gear
        _check(key, configured, 2 * math.pi / (gear_total * scale), what, f"units of {quantity} per {per}")
        source[key] = f"drive 0x{index:04X}"
        return scale
    if not time_unit and inc_per_rev is not None:   # no 0x60A8: 0x6064 counts increments (CiA 402)
        _check(key, configured, inc_per_rev, f"no 0x60A8, so increments, and 0x608F (position encoder "
               f"resolution) = {reported['0x608F']}", f"units of 0x6064 per {per}")
        source[key] = "drive 0x608F"
        return 2 * math.pi / inc_per_rev / drive_gear / outside_gear
    if configured is None:
        raise ConfigError(f"motor.{key}", f"required: the drive lists no 0x{index:04X} ({name})"
                          + ("" if time_unit else " and no 0x608F (position encoder resolution)")
                          + f", so the unit of {quantity} must be configured")
    source[key] = "config"
    return 2 * math.pi / configured / drive_gear / outside_gear


def _rated_torque_Nm(node: canopen.RemoteNode, cfg: MotorConfig, reported: dict[str, str],
                     source: dict[str, str]) -> float:
    if has_object(node, 0x6076):
        raw = sdo_read(node, 0x6076)
        reported["0x6076"] = f"{raw} mNm"
        if not raw > 0:
            raise DriveUnitsError("motor.rated_torque_Nm", f"the drive's motor rated torque 0x6076 = {raw} mNm "
                                  f"is not positive")
        _check("rated_torque_Nm", cfg.rated_torque_Nm, raw / 1000.0,
               f"motor rated torque 0x6076 = {raw} mNm", "Nm", TORQUE_RTOL)
        source["rated_torque_Nm"] = "drive 0x6076"
        return raw / 1000.0
    if cfg.rated_torque_Nm is None:
        raise ConfigError("motor.rated_torque_Nm", f"required: the EDS {cfg.eds} has no 0x6076")
    source["rated_torque_Nm"] = "config"
    return cfg.rated_torque_Nm


def write_configured_units(node: canopen.RemoteNode, cfg: MotorConfig) -> dict[str, str]:
    """Write 0x60A8/0x60A9 so the drive serves the configured units (``motor.units: write``).

    :returns: ``{"0x60A9": "0x00B44700 (rpm)", ...}`` of what was written and read back.
    :raises DriveUnitsError: if the drive lacks the object or no SI unit code makes the
        configured value (key, object and value named).
    :raises DriverError: if the value read back differs (object named), or an SDO fails.
    """
    enc = _ratio(node, 0x608F)
    inc_per_rev = enc[0] / enc[1] if enc is not None and enc[0] > 0 and enc[1] > 0 else None
    gear = _ratio(node, 0x6091)
    drive_gear = gear[0] / gear[1] if gear is not None and gear[0] > 0 and gear[1] > 0 else 1.0
    written: dict[str, str] = {}
    for index, key, value, time_unit in ((0x60A8, "encoder_counts_per_rev", cfg.encoder_counts_per_rev, False),
                                         (0x60A9, "velocity_units_per_rev_s", cfg.velocity_units_per_rev_s, True)):
        if value is None:
            continue
        if not has_object(node, index):
            raise DriveUnitsError(f"motor.{key}", f"motor.units is 'write' but the drive lists no 0x{index:04X}")
        code = code_for(float(value), inc_per_rev, drive_gear, time_unit)
        if code is None:
            raise DriveUnitsError(f"motor.{key}", f"motor.units is 'write' but no 0x{index:04X} unit code gives "
                                  f"{value:.9g} units per motor rev{'/s' if time_unit else ''} (encoder "
                                  f"{inc_per_rev}, gear {drive_gear:.9g})")
        sdo_write(node, index, 0, code)
        back = sdo_read(node, index)
        if back != code:
            raise DriverError(f"drive {node.id}: 0x{index:04X} reads back 0x{back:08X} after writing 0x{code:08X}")
        written[f"0x{index:04X}"] = str(SiUnit.decode(code))
        logger.warning("drive %d: 0x%04X set to %s from motor.%s (motor.units: write; not stored in the drive)",
                       node.id, index, SiUnit.decode(code), key)
    return written
