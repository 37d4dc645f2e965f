"""SDO start-up configuration of a CiA 402 drive (standard CiA 301/402 objects only).

Used by :class:`capstan.drivers.canopen.motor.CanopenMotor` while the drive is NMT
PRE-OPERATIONAL. What is written, in order:

1. 0x6502 read: the configured mode must be listed (bit 3 profile torque, bit 9 CST);
2. units (:mod:`~capstan.drivers.canopen.drive_units`): 0x608F, 0x6091, 0x6092, 0x60A8,
   0x60A9 and the rated torque 0x6076 [mNm] read where the EDS has them; every value the
   configuration states must agree with the drive's (else refused, object and both values
   named), a value it leaves out is the drive's; with ``motor.units: write`` 0x60A8/0x60A9
   are first written from the configured units;
3. EMCY COB-ID read from 0x1014 (where the EDS has it; bit 31 set: the drive sends none);
4. PDOs (CiA 301 procedure: COB-ID invalid, type, mapping count 0, entries, count,
   COB-ID valid): RPDO1 = 0x6040 + 0x6071, TPDO1 = 0x6041 + 0x6061 + 0x6064,
   TPDO2 = 0x606C + 0x6077, all transmission type 1 (every SYNC); TPDO inhibit time
   and event timer 0; every other RPDO/TPDO the EDS offers is made invalid. COB-IDs
   are read-modify-written: bits 29 (frame format) and 30 (no RTR) keep the drive's
   value, only bit 31 (valid) and, where zero, the CAN-ID are changed;
5. interpolation period 0x60C2 = cycle period as the exact (value, index) pair
   value x 10^index s (refused if no UNSIGNED8 value represents it exactly);
6. producer heartbeat 0x1017; the safety objects of
   :func:`capstan.drivers.canopen.bringup.write_safety_objects` (0x6007, 0x1029,
   0x605A, 0x605B, 0x6072, each read back); mode 0x6060, verified on 0x6061;
7. last, consumer heartbeat 0x1016 sub 1 = (daemon node id, consumer time): from
   then on the drive stops when the daemon's heartbeat stops.

Every SDO error names index:sub-index, the value and the abort text
(:mod:`capstan.drivers.canopen.sdo_access`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from fractions import Fraction

import canopen

from capstan.drivers.canopen.cia402 import OpMode, SUPPORTED_MODE_BIT
from capstan.drivers.canopen.bringup import write_safety_objects
from capstan.drivers.canopen.config import MotorConfig
from capstan.drivers.canopen.drive_units import DriveUnits, read_drive_units, write_configured_units
from capstan.drivers.canopen.sdo_access import has_object, sdo_read, sdo_write
from capstan.models.common.errors import ConfigError, DriverError, StateTransitionError

logger = logging.getLogger(__name__)


class ObjectMissingError(DriverError):
    """The drive's object dictionary lacks an object capstan requires."""


#: objects the driver cannot work without (CiA 301 / CiA 402)
REQUIRED_OBJECTS: dict[int, str] = {
    0x1016: "consumer heartbeat time", 0x1017: "producer heartbeat time",
    0x1400: "RPDO1 communication", 0x1600: "RPDO1 mapping",
    0x1800: "TPDO1 communication", 0x1A00: "TPDO1 mapping",
    0x1801: "TPDO2 communication", 0x1A01: "TPDO2 mapping",
    0x6040: "controlword", 0x6041: "statusword", 0x6060: "modes of operation",
    0x6061: "modes of operation display", 0x6064: "position actual value",
    0x606C: "velocity actual value", 0x6071: "target torque", 0x6077: "torque actual value",
}

RPDO1_MAP = (0x60400010, 0x60710010)
TPDO1_MAP = (0x60410010, 0x60610008, 0x60640020)
TPDO2_MAP = (0x606C0020, 0x60770010)


@dataclass(frozen=True)
class SetupResult:
    """What the cyclic I/O needs from the set-up.

    :ivar rated_torque_Nm: torque of 1000 per mille [Nm].
    :ivar rpdo_cob: CAN-ID of RPDO1; :ivar tpdo1_cob:, :ivar tpdo2_cob: of the TPDOs.
    :ivar emcy_cob: CAN-ID of the drive's EMCY (0x1014), 0 if it sends none.
    :ivar safety: safety objects as read back from the drive (``"0x6072": 300``).
    :ivar units: the feedback's scales as the drive reported them.
    """

    units: DriveUnits
    rpdo_cob: int
    tpdo1_cob: int
    tpdo2_cob: int
    emcy_cob: int = 0
    safety: dict[str, int] = field(default_factory=dict)

    @property
    def rated_torque_Nm(self) -> float:
        """Torque of 1000 per mille [Nm]."""
        return self.units.rated_torque_Nm


def check_required_objects(od: canopen.ObjectDictionary, eds: str) -> None:
    """Refuse an object dictionary that lacks a required object or mapping capacity.

    :raises ObjectMissingError: naming every missing object.
    """
    missing = [f"0x{i:04X} ({name})" for i, name in REQUIRED_OBJECTS.items() if i not in od]
    if missing:
        raise ObjectMissingError(f"EDS {eds} lacks required object(s): {', '.join(missing)}")
    for index, entries in ((0x1600, RPDO1_MAP), (0x1A00, TPDO1_MAP), (0x1A01, TPDO2_MAP)):
        obj = od[index]
        absent = [k for k in range(len(entries) + 1) if k not in obj]
        if absent:
            raise ObjectMissingError(f"EDS {eds}: PDO mapping 0x{index:04X} has no sub-index "
                                     f"{absent[0]}; {len(entries)} entries are needed")
    if 1 not in od[0x1016]:
        raise ObjectMissingError(f"EDS {eds}: 0x1016 (consumer heartbeat time) has no sub-index 1")


def configure_drive(node: canopen.RemoteNode, cfg: MotorConfig, mode: OpMode,
                    mode_timeout_s: float) -> SetupResult:
    """Configure the drive over SDO (see the module docstring).

    :raises DriverError: if 0x6502 lacks ``mode``.
    :raises ConfigError: if a unit or the rated torque is unknown, or
        :class:`~capstan.drivers.canopen.drive_units.DriveUnitsError` if it contradicts the drive's.
    :raises StateTransitionError: if 0x6061 does not show ``mode`` in time.
    :raises canopen.SdoAbortedError: / ``SdoCommunicationError`` from the SDO client.
    """
    od, nid = node.object_dictionary, cfg.node_id
    bit = SUPPORTED_MODE_BIT[mode]
    if 0x6502 in od:
        supported = sdo_read(node, 0x6502)
        if not supported >> bit & 1:
            raise DriverError(f"drive {nid} does not support mode {int(mode)} ({mode.name}): "
                              f"0x6502 = 0x{supported:08X} lacks bit {bit}")
    if cfg.units == "write":
        write_configured_units(node, cfg)
    units = read_drive_units(node, cfg)
    emcy_cob = 0x80 + nid
    if has_object(node, 0x1014):
        word = sdo_read(node, 0x1014)
        emcy_cob = 0 if word & 0x80000000 else word & 0x7FF
        if not emcy_cob:
            logger.warning("drive %d: 0x1014 = 0x%08X, the drive sends no EMCY", nid, word)
    rpdo_cob = _map_pdo(node, 0x1400, 0x1600, 0x200 + nid, RPDO1_MAP)
    tpdo1_cob = _map_pdo(node, 0x1800, 0x1A00, 0x180 + nid, TPDO1_MAP)
    tpdo2_cob = _map_pdo(node, 0x1801, 0x1A01, 0x280 + nid, TPDO2_MAP)
    for base, first in ((0x1400, 1), (0x1800, 2)):
        for n in range(first, 512):
            if base + n not in od:
                break
            cob = sdo_read(node, base + n, 1)
            if not cob & 0x80000000:
                sdo_write(node, base + n, 1, cob | 0x80000000)  # unused PDO: invalid, bits 29/30 kept
    if 0x60C2 in od:
        value, index = interpolation_period(cfg.cycle_period_s)
        sdo_write(node, 0x60C2, 1, value)
        sdo_write(node, 0x60C2, 2, index)
    else:
        logger.warning("EDS %s has no 0x60C2; interpolation period not set", cfg.eds)
    sdo_write(node, 0x1017, 0, max(1, round(cfg.drive_heartbeat_period_s * 1000)))
    safety = write_safety_objects(node, cfg, units.rated_torque_Nm)
    sdo_write(node, 0x6060, 0, int(mode))
    deadline = time.monotonic() + mode_timeout_s
    while (shown := sdo_read(node, 0x6061)) != int(mode):
        if time.monotonic() > deadline:
            raise StateTransitionError(f"drive {nid}: 0x6061 shows mode {shown}, not the written "
                                       f"mode {int(mode)} ({mode.name}), after {mode_timeout_s} s")
        time.sleep(0.005)
    sdo_write(node, 0x1016, 1, (cfg.master_node_id << 16) | min(0xFFFF, round(cfg.consumer_timeout_s * 1000)))
    return SetupResult(units, rpdo_cob, tpdo1_cob, tpdo2_cob, emcy_cob, safety)


def interpolation_period(period_s: float) -> tuple[int, int]:
    """0x60C2 (value, index) with value x 10^index = ``period_s`` exactly (CiA 402-2).

    The smallest index with an integer value 1..255 is taken (0.25 ms -> (25, -5),
    1 ms -> (1, -3), 0.255 s -> (255, -3)); the period is taken as the decimal it prints as.

    :raises ConfigError: if no UNSIGNED8 value with an index in -128..63 represents the period.
    """
    exact = Fraction(repr(float(period_s)))
    for index in range(0, -11, -1):
        value = exact / Fraction(10) ** index
        if value.denominator == 1:
            if 1 <= value <= 255:
                return int(value), index
            break
    for index in range(1, 64):
        value = exact / Fraction(10) ** index
        if value.denominator == 1 and 1 <= value <= 255:
            return int(value), index
    raise ConfigError("motor.cycle_period_s", f"{period_s} s cannot be written to 0x60C2 exactly as "
                      f"value x 10^index with value 1..255")


def _map_pdo(node: canopen.RemoteNode, comm: int, mapping: int, default_cob: int,
             entries: tuple[int, ...]) -> int:
    """Map one PDO (CiA 301 procedure); the CAN-ID it uses.

    The COB-ID is read-modify-written: bits 29 and 30 keep what the drive holds (a drive
    without RTR refuses a TPDO COB-ID with bit 30 clear), the CAN-ID stays unless zero.
    """
    word = sdo_read(node, comm, 1)
    can_id = word & 0x7FF or default_cob
    upper = word & 0x60000000
    if word & 0x20000000:
        raise DriverError(f"drive {node.id}: 0x{comm:04X}:01 = 0x{word:08X} uses a 29-bit CAN-ID; "
                          f"capstan maps 11-bit PDOs only")
    if not word & 0x80000000:
        sdo_write(node, comm, 1, upper | 0x80000000 | can_id)
    sdo_write(node, comm, 2, 1)  # synchronous, every SYNC
    sdo_write(node, mapping, 0, 0)
    for k, entry in enumerate(entries, start=1):
        sdo_write(node, mapping, k, entry)
    sdo_write(node, mapping, 0, len(entries))
    if comm >= 0x1800:
        for sub in (3, 5):  # inhibit time, event timer
            if has_object(node, comm, sub):
                sdo_write(node, comm, sub, 0)
    sdo_write(node, comm, 1, upper | can_id)
    return can_id
