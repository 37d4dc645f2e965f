"""Bring-up steps of a CiA 402 drive that a real drive needs before the PDO set-up.

* :func:`wait_for_boot` — a drive takes 1-5 s after power-on; until then it answers
  nothing. Start-up listens for its boot-up message (CiA 301 heartbeat COB-ID with
  state 0x00) and polls SDO 0x1000 with back-off, up to ``boot_timeout_s``, logging a
  progress line every second.
* :func:`recover_fault_at_start` — a drive found in FAULT: the heartbeat-loss fault
  0x8130 the previous daemon caused by dying (or by a stop before 0x1016 was disarmed)
  is reset and named in the log; any other fault refuses the start with its code and
  text unless ``motor.fault_reset_at_start`` is set.
* :func:`write_safety_objects` — 0x6007 (abort connection option), 0x1029 sub 1
  (communication error behaviour), 0x605A/0x605B (quick-stop/shutdown option) where the
  drive has them, and 0x6072 (max torque) from ``max_torque_Nm``; each read back.
"""

from __future__ import annotations

import logging
import threading
import time

import canopen

from capstan.drivers.canopen.cia402 import State402, decode_statusword, describe_statusword
from capstan.drivers.canopen.config import MotorConfig
from capstan.drivers.canopen.emcy import describe_code
from capstan.drivers.canopen.sdo_access import SdoRefusedError, has_object, sdo_read, sdo_write
from capstan.models.common.errors import (ConfigError, DeviceTimeoutError, DriveFaultError, DriverError,
                                          StateTransitionError)

logger = logging.getLogger(__name__)

#: EMCY code of a heartbeat / life-guard error (CiA 301): the fault a dead master leaves
HEARTBEAT_ERROR = 0x8130
#: first and longest pause between SDO polls of a booting drive [s]
BOOT_BACKOFF_S = (0.05, 1.0)
#: SDO response timeout while polling a booting drive [s] (short: the boot-up message or the
#: next poll then ends the wait within about this much after the drive is up)
BOOT_POLL_SDO_TIMEOUT_S = 0.1
#: time the drive is given to leave FAULT after the reset edge [s]
FAULT_RESET_TIMEOUT_S = 1.0


def wait_for_boot(network: canopen.Network, node: canopen.RemoteNode, timeout_s: float) -> float:
    """Block until the drive answers SDO (boot-up message seen or polled); the time waited [s].

    :raises DeviceTimeoutError: if neither a boot-up message nor an SDO answer came within
        ``timeout_s`` (the message names the node, the COB-IDs and the number of tries).
    """
    nid = node.id
    booted = threading.Event()

    def on_heartbeat(can_id: int, data: bytearray, timestamp: float) -> None:
        booted.set()  # boot-up (0x00) or the heartbeat of a drive already running

    network.subscribe(0x700 + nid, on_heartbeat)
    sdo_timeout_s, node.sdo.RESPONSE_TIMEOUT = node.sdo.RESPONSE_TIMEOUT, BOOT_POLL_SDO_TIMEOUT_S
    t0 = time.monotonic()
    pause, tries, next_report = BOOT_BACKOFF_S[0], 0, t0 + 1.0
    try:
        while True:
            tries += 1
            try:
                try:
                    sdo_read(node, 0x1000)
                except SdoRefusedError:
                    pass  # an answer, even a refusal: the drive is up
                waited = time.monotonic() - t0
                if tries > 1:
                    logger.info("drive %d answered after %.2f s (%d SDO tries)", nid, waited, tries)
                return waited
            except DeviceTimeoutError:
                pass
            now = time.monotonic()
            if now - t0 >= timeout_s:
                raise DeviceTimeoutError(
                    f"drive {nid} did not boot within {timeout_s} s (motor.boot_timeout_s): "
                    f"no boot-up message on 0x{0x700 + nid:03X} and no SDO answer on 0x{0x580 + nid:03X} "
                    f"to {tries} reads of 0x1000; check power, node id and bit rate")
            if now >= next_report:
                logger.info("waiting for drive %d to boot: %.1f s of %.1f s", nid, now - t0, timeout_s)
                next_report = now + 1.0
            if booted.wait(min(pause, max(0.0, t0 + timeout_s - now))):
                booted.clear()
                pause = BOOT_BACKOFF_S[0]
            else:
                pause = min(2 * pause, BOOT_BACKOFF_S[1])
    finally:
        node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
        network.unsubscribe(0x700 + nid, on_heartbeat)


def fault_code(node: canopen.RemoteNode) -> int:
    """The drive's current error code: 0x603F, else the newest entry of 0x1003 (0 if none)."""
    if has_object(node, 0x603F):
        code = sdo_read(node, 0x603F) & 0xFFFF
        if code:
            return code
    if has_object(node, 0x1003, 1) and sdo_read(node, 0x1003, 0) > 0:
        return sdo_read(node, 0x1003, 1) & 0xFFFF
    return 0


def recover_fault_at_start(node: canopen.RemoteNode, cfg: MotorConfig) -> int | None:
    """Reset a drive found in FAULT if the fault is the daemon's own (0x8130) or reset is asked for.

    :returns: the error code that was reset, or None if the drive was not in FAULT.
    :raises DriveFaultError: for any other fault without ``fault_reset_at_start`` (code and text named).
    :raises StateTransitionError: if the drive stays in FAULT after the reset edge.
    """
    nid = node.id
    sw = sdo_read(node, 0x6041)
    if decode_statusword(sw) not in (State402.FAULT, State402.FAULT_REACTION_ACTIVE):
        return None
    code = fault_code(node)
    what = f"0x{code:04X} ({describe_code(code)})" if code else "no error code in 0x603F/0x1003"
    if code == HEARTBEAT_ERROR:
        logger.warning("drive %d is in FAULT %s: the previous daemon's heartbeat stopped (killed, or "
                       "stopped without disarming 0x1016); resetting the fault", nid, what)
    elif cfg.fault_reset_at_start:
        logger.warning("drive %d is in FAULT %s; resetting it because motor.fault_reset_at_start is set",
                       nid, what)
    else:
        raise DriveFaultError(f"drive {nid} is in FAULT at start-up: {what}; statusword "
                              f"{describe_statusword(sw)}. Not reset automatically: find the cause, "
                              f"then reset it at the drive or set motor.fault_reset_at_start: true")
    sdo_write(node, 0x6040, 0, 0x0000)   # bit 7 low, then high: a rising edge (transition 15)
    sdo_write(node, 0x6040, 0, 0x0080)
    deadline = time.monotonic() + FAULT_RESET_TIMEOUT_S
    while decode_statusword(sw := sdo_read(node, 0x6041)) in (State402.FAULT, State402.FAULT_REACTION_ACTIVE):
        if time.monotonic() > deadline:
            raise StateTransitionError(f"drive {nid} stays in FAULT {what} after the fault reset "
                                       f"(transition 15); statusword {describe_statusword(sw)}")
        time.sleep(0.01)
    sdo_write(node, 0x6040, 0, 0x0000)
    logger.info("drive %d: fault %s reset; statusword %s", nid, what, describe_statusword(sw))
    return code


def max_torque_permille(cfg: MotorConfig, rated_torque_Nm: float) -> int:
    """0x6072 for ``max_torque_Nm`` [per mille of the rated torque].

    :raises ConfigError: if the limit does not fit 0x6072 (UNSIGNED16).
    """
    value = round(cfg.max_torque_Nm / rated_torque_Nm * 1000.0)
    if not 1 <= value <= 0xFFFF:
        raise ConfigError("motor.max_torque_Nm", f"{cfg.max_torque_Nm} Nm is {value} per mille of the rated "
                          f"torque {rated_torque_Nm} Nm; 0x6072 holds 1..65535")
    return value


def write_safety_objects(node: canopen.RemoteNode, cfg: MotorConfig, rated_torque_Nm: float) -> dict[str, int]:
    """Write the safety objects from the configuration and read each back.

    :returns: ``{"0x6007": value, ...}`` of what the drive holds now.
    :raises DriverError: if a value read back differs from the value written (object named).
    :raises SdoRefusedError: if the drive refuses a value (object, value and abort text named).
    """
    plan = [(0x6007, 0, cfg.abort_connection_option, "abort connection option (motor.abort_connection_option)"),
            (0x1029, 1, cfg.comm_error_behaviour, "communication error behaviour (motor.comm_error_behaviour)"),
            (0x605A, 0, cfg.quick_stop_option, "quick stop option (motor.quick_stop_option)"),
            (0x605B, 0, cfg.shutdown_option, "shutdown option (motor.shutdown_option)"),
            (0x6072, 0, max_torque_permille(cfg, rated_torque_Nm), "max torque (motor.max_torque_Nm)")]
    held: dict[str, int] = {}
    for index, sub, value, what in plan:
        if not has_object(node, index, sub):
            logger.warning("drive %d: the EDS %s has no 0x%04X:%02X %s; not set", node.id, cfg.eds,
                           index, sub, what)
            continue
        sdo_write(node, index, sub, value)
        back = sdo_read(node, index, sub)
        if back != value:
            raise DriverError(f"drive {node.id}: 0x{index:04X}:{sub:02X} {what} reads back {back} "
                              f"after writing {value}")
        held[f"0x{index:04X}"] = back
    if "0x6007" not in held:
        logger.warning("drive %d: without 0x6007 whether the drive stops when the daemon dies depends on "
                       "its firmware", node.id)
    return held
