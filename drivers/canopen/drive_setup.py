"""SDO start-up configuration of a CiA 402 drive (standard CiA 301/402 objects only).

Used by :class:`capstan.drivers.canopen.motor.CanopenMotor` while the drive is NMT
PRE-OPERATIONAL. What is written, in order:

1. 0x6502 read: the configured mode must be listed (bit 3 profile torque, bit 9 CST);
2. rated torque: 0x6076 [mNm] where the EDS has it (must agree with a configured
   value), else the configured ``rated_torque_Nm``;
3. PDOs (CiA 301 procedure: COB-ID invalid, type, mapping count 0, entries, count,
   COB-ID valid): RPDO1 = 0x6040 + 0x6071, TPDO1 = 0x6041 + 0x6061 + 0x6064,
   TPDO2 = 0x606C + 0x6077, all transmission type 1 (every SYNC); TPDO inhibit time
   and event timer 0; every other RPDO/TPDO the EDS offers is made invalid;
4. interpolation period 0x60C2 = cycle period (if the EDS has it);
5. producer heartbeat 0x1017; mode 0x6060, verified on 0x6061;
6. last, consumer heartbeat 0x1016 sub 1 = (daemon node id, consumer time): from
   then on the drive stops when the daemon's heartbeat stops.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import canopen

from capstan.drivers.canopen.cia402 import OpMode, SUPPORTED_MODE_BIT
from capstan.drivers.canopen.config import MotorConfig
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
    :ivar rpdo_cob: COB-ID of RPDO1; :ivar tpdo1_cob:, :ivar tpdo2_cob: of the TPDOs.
    """

    rated_torque_Nm: float
    rpdo_cob: int
    tpdo1_cob: int
    tpdo2_cob: int


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
    :raises ConfigError: if the rated torque is unknown or contradicts 0x6076.
    :raises StateTransitionError: if 0x6061 does not show ``mode`` in time.
    :raises canopen.SdoAbortedError: / ``SdoCommunicationError`` from the SDO client.
    """
    od, sdo, nid = node.object_dictionary, node.sdo, cfg.node_id
    bit = SUPPORTED_MODE_BIT[mode]
    if 0x6502 in od:
        supported = int(sdo[0x6502].raw)
        if not supported >> bit & 1:
            raise DriverError(f"drive {nid} does not support mode {int(mode)} ({mode.name}): "
                              f"0x6502 = 0x{supported:08X} lacks bit {bit}")
    rated = _rated_torque_Nm(node, cfg)
    rpdo_cob = _map_pdo(node, 0x1400, 0x1600, 0x200 + nid, RPDO1_MAP)
    tpdo1_cob = _map_pdo(node, 0x1800, 0x1A00, 0x180 + nid, TPDO1_MAP)
    tpdo2_cob = _map_pdo(node, 0x1801, 0x1A01, 0x280 + nid, TPDO2_MAP)
    for base, first in ((0x1400, 1), (0x1800, 2)):
        for n in range(first, 512):
            if base + n not in od:
                break
            cob = int(sdo[base + n][1].raw)
            if not cob & 0x80000000:
                sdo[base + n][1].raw = cob | 0x80000000  # unused PDO: invalid
    if 0x60C2 in od:
        ms = cfg.cycle_period_s * 1000.0
        value, exp = (round(ms), -3) if abs(ms - round(ms)) < 1e-9 else (round(ms * 10), -4)
        sdo[0x60C2][1].raw = value
        sdo[0x60C2][2].raw = exp
    else:
        logger.warning("EDS %s has no 0x60C2; interpolation period not set", cfg.eds)
    sdo[0x1017].raw = max(1, round(cfg.drive_heartbeat_period_s * 1000))
    sdo[0x6060].raw = int(mode)
    deadline = time.monotonic() + mode_timeout_s
    while (shown := int(sdo[0x6061].raw)) != int(mode):
        if time.monotonic() > deadline:
            raise StateTransitionError(f"drive {nid}: 0x6061 shows mode {shown}, not the written "
                                       f"mode {int(mode)} ({mode.name}), after {mode_timeout_s} s")
        time.sleep(0.005)
    sdo[0x1016][1].raw = (cfg.master_node_id << 16) | min(0xFFFF, round(cfg.consumer_timeout_s * 1000))
    return SetupResult(rated, rpdo_cob, tpdo1_cob, tpdo2_cob)


def _rated_torque_Nm(node: canopen.RemoteNode, cfg: MotorConfig) -> float:
    if 0x6076 in node.object_dictionary:
        drive_Nm = int(node.sdo[0x6076].raw) / 1000.0
        if cfg.rated_torque_Nm is not None and abs(drive_Nm - cfg.rated_torque_Nm) > 0.005 * drive_Nm:
            raise ConfigError("motor.rated_torque_Nm", f"{cfg.rated_torque_Nm} Nm contradicts the "
                              f"drive's rated torque 0x6076 = {drive_Nm} Nm")
        rated = drive_Nm
    elif cfg.rated_torque_Nm is None:
        raise ConfigError("motor.rated_torque_Nm", f"required: the EDS {cfg.eds} has no 0x6076")
    else:
        rated = cfg.rated_torque_Nm
    if not rated > 0:
        raise ConfigError("motor.rated_torque_Nm", f"rated torque must be > 0, got {rated}")
    return rated


def _map_pdo(node: canopen.RemoteNode, comm: int, mapping: int, default_cob: int,
             entries: tuple[int, ...]) -> int:
    sdo = node.sdo
    cob = int(sdo[comm][1].raw) & 0x7FF or default_cob
    sdo[comm][1].raw = cob | 0x80000000
    sdo[comm][2].raw = 1  # synchronous, every SYNC
    sdo[mapping][0].raw = 0
    for k, word in enumerate(entries, start=1):
        sdo[mapping][k].raw = word
    sdo[mapping][0].raw = len(entries)
    if comm >= 0x1800:
        od_comm = node.object_dictionary[comm]
        for sub in (3, 5):  # inhibit time, event timer
            if sub in od_comm:
                sdo[comm][sub].raw = 0
    sdo[comm][1].raw = cob
    return cob
