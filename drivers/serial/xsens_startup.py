"""Start-up conversation with an Xsens MTi: find the line rate, configure, verify by read-back.

Blocking, used by :meth:`capstan.drivers.serial.xsens.XsensImu.start` and ``capstan imu
setup``; nothing here runs in the control cycle.

1. **Find the device** (:func:`find_device`): GoToConfig at the configured rate, then
   (``baud_search``) at the standard rates, 115200 Bd (the factory default) first; up to
   ``retries`` rounds over the list, one ``timeout_s`` wait per rate.
2. **Move it to the running rate** (:func:`switch_baudrate`), if it was found elsewhere:
   SetBaudrate (0x18, stored in the device's non-volatile memory and effective after a
   reset), Reset (0x40), reopen the port at the running rate, answer the device's WakeUp
   (0x3E) with WakeUpAck so that it stays in config mode, and confirm with GoToConfig.
3. **Configure and verify** (:func:`configure_output`): SetOutputConfiguration (0xC0);
   its acknowledgement (0xC1) is *not* compared with the request (devices answer with
   what they keep of it, e.g. only the first items); the configuration is then read
   back (ReqOutputConfiguration: 0xC0 without data) and checked for the items and rates
   the controller needs (:func:`check_output_configuration`).
"""

from __future__ import annotations

import logging
import time
from typing import Any

from capstan.drivers.interfaces import LinkStats
from capstan.drivers.serial.xbus import XbusParser, build_message
from capstan.drivers.serial.xsens_config import SEARCH_BAUDRATES, XsensConfig, baud_code
from capstan.drivers.serial.xsens_protocol import (
    FREQ_EVERY_PACKET, XDI_TYPE_MASK, Mid, decode_output_configuration, encode_output_configuration,
    error_name, xdi_name,
)
from capstan.models.common.errors import DeviceTimeoutError, ProtocolError

log = logging.getLogger(__name__)

SET_BAUDRATE = 0x18
SET_BAUDRATE_ACK = 0x19
RESET = 0x40
RESET_ACK = 0x41
#: longest wait for the WakeUp of a device rebooting after Reset [s]
REBOOT_WAIT_S = 3.0


class XbusLink:
    """Request/acknowledge exchanges over an open pyserial port (blocking, start-up only).

    :param port: open pyserial port (``baudrate`` writable; ptys accept any rate).
    :param parser: the driver's frame parser (shares its ``stats``).
    :param stats: counters: every frame received counts as good here.
    :param name: port name for messages.
    :param timeout_s: wait for each acknowledgement [s].
    :param retries: attempts of :meth:`request`.
    """

    def __init__(self, port: Any, parser: XbusParser, stats: LinkStats, name: str,
                 timeout_s: float, retries: int) -> None:
        self.port = port
        self.parser = parser
        self.stats = stats
        self.name = name
        self.timeout_s = timeout_s
        self.retries = retries

    def set_baudrate(self, baudrate: int) -> None:
        """Reopen the line at ``baudrate`` [Bd] and drop what was received at the old rate.

        :raises OSError: if the port refuses the rate (pyserial's SerialException).
        """
        self.port.baudrate = baudrate
        self.port.reset_input_buffer()
        self.parser.reset()

    def wait_for(self, mid: int, timeout_s: float, request_mid: int = -1) -> bytes | None:
        """Data of the next message ``mid`` within ``timeout_s``, None on timeout.

        A WakeUp from a rebooting device is answered with WakeUpAck (the device then stays
        in config mode); every received frame counts as good.

        :raises ProtocolError: on an Error (0x42) message from the device.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            self.port.timeout = min(remaining, 0.05)
            chunk = self.port.read(max(1, self.port.in_waiting))
            self.port.timeout = 0
            for rmid, rdata in self.parser.feed(chunk):
                self.stats.good_frames += 1  # stream packets before the ack are dropped
                if rmid == Mid.WAKE_UP:
                    self.port.write(build_message(Mid.WAKE_UP_ACK))
                if rmid == mid:
                    return rdata
                if rmid == Mid.ERROR:
                    code = rdata[0] if rdata else -1
                    raise ProtocolError(f"Xsens on {self.name} replied Error {code} ({error_name(code)}) "
                                        f"to MID 0x{request_mid:02X}")

    def exchange(self, mid: int, data: bytes, ack: int, attempts: int) -> bytes | None:
        """Send ``mid`` up to ``attempts`` times; the acknowledgement's data, None if none came.

        :raises ProtocolError: on an Error (0x42) reply.
        """
        msg = build_message(mid, data)
        for _ in range(attempts):
            self.port.write(msg)
            got = self.wait_for(ack, self.timeout_s, mid)
            if got is not None:
                return got
        return None

    def request(self, mid: int, data: bytes, ack: int) -> bytes:
        """Send ``mid`` (``retries`` attempts) and return the acknowledgement's data.

        :raises DeviceTimeoutError: if no acknowledgement arrives.
        :raises ProtocolError: on an Error (0x42) reply.
        """
        got = self.exchange(mid, data, ack, self.retries)
        if got is None:
            raise DeviceTimeoutError(f"Xsens on {self.name}: no ack 0x{ack:02X} to MID 0x{mid:02X} after "
                                     f"{self.retries} x {self.timeout_s} s at {self.port.baudrate} Bd")
        return got


def find_device(link: XbusLink, cfg: XsensConfig) -> int:
    """Line rate at which the device acknowledges GoToConfig [Bd]; it is then in config mode.

    :raises DeviceTimeoutError: naming the rates tried and what to do.
    :raises OSError: if the port fails.
    """
    rates = [cfg.baudrate]
    if cfg.baud_search:
        rates += [r for r in SEARCH_BAUDRATES if r != cfg.baudrate]
    for _ in range(cfg.retries):
        for bd in rates:
            link.set_baudrate(bd)
            if link.exchange(Mid.GO_TO_CONFIG, b"", Mid.GO_TO_CONFIG_ACK, attempts=1) is not None:
                return bd
            log.debug("Xsens on %s: no GoToConfig ack at %d Bd", cfg.port, bd)
    hint = ("check power, cable and port" if cfg.baud_search else
            "the device may run at another rate: set imu.baud_search: true or run "
            f"`capstan imu setup {cfg.port}`")
    raise DeviceTimeoutError(f"Xsens on {cfg.port}: no answer to GoToConfig at {', '.join(map(str, rates))} Bd "
                             f"({cfg.retries} round(s) of {cfg.timeout_s} s each); {hint}")


def switch_baudrate(link: XbusLink, to_baudrate: int) -> None:
    """Store ``to_baudrate`` [Bd] in the device (in config mode), reset it, reopen, confirm.

    :raises DeviceTimeoutError: if an acknowledgement or the confirmation at the new rate
        does not arrive.
    :raises ProtocolError: if the device refuses the rate (Error BAUDRATE_INVALID).
    :raises ConfigError: if the MT protocol has no code for the rate.
    """
    link.request(SET_BAUDRATE, bytes((baud_code(to_baudrate),)), SET_BAUDRATE_ACK)
    link.request(RESET, b"", RESET_ACK)
    link.set_baudrate(to_baudrate)
    if link.wait_for(Mid.WAKE_UP, REBOOT_WAIT_S, RESET) is None:
        log.warning("Xsens on %s: no WakeUp at %d Bd after Reset; trying GoToConfig", link.name, to_baudrate)
    link.request(Mid.GO_TO_CONFIG, b"", Mid.GO_TO_CONFIG_ACK)


def _rate_ok(want_hz: int, got_hz: int, packet_rate_hz: int) -> bool:
    if want_hz == FREQ_EVERY_PACKET:  # "with every packet": 0xFFFF, 0, or the device's maximum
        return got_hz in (0, FREQ_EVERY_PACKET) or got_hz >= packet_rate_hz
    return got_hz == want_hz


def check_output_configuration(got: list[tuple[int, int]], want: list[tuple[int, int]], port: str) -> None:
    """Check a read-back output configuration against what the controller needs.

    Every wanted item must be present with the same XDI (type, precision, coordinate
    system) and its rate: the same frequency, or for "every packet" (0xFFFF) items
    0xFFFF, 0 or at least the packet rate. Extra items are allowed (logged).

    :raises ProtocolError: naming every missing item and wrong rate.
    """
    have: dict[int, int] = {}
    for xdi, freq in got:
        have.setdefault(xdi, freq)
    packet_rate = max((f for _, f in want if f != FREQ_EVERY_PACKET), default=1)
    problems = []
    for xdi, freq in want:
        need = "every packet" if freq == FREQ_EVERY_PACKET else f"{freq} Hz"
        if xdi not in have:
            alt = [x for x in have if x & XDI_TYPE_MASK == xdi & XDI_TYPE_MASK]
            problems.append(f"{xdi_name(xdi)} at {need} is missing"
                            + (f" (the device sends {xdi_name(alt[0])})" if alt else ""))
        elif not _rate_ok(freq, have[xdi], packet_rate):
            problems.append(f"{xdi_name(xdi)} is at {have[xdi]} Hz, the controller needs {need}")
    if problems:
        raise ProtocolError(f"Xsens on {port}: output configuration read back from the device: "
                            + "; ".join(problems))
    extra = [xdi_name(x) for x in have if x not in dict(want)]
    if extra:
        log.info("Xsens on %s also outputs %s", port, ", ".join(extra))


def configure_output(link: XbusLink, items: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Send the output configuration, read it back, check it; returns the read-back items.

    :raises ProtocolError: if the read-back lacks an item or rate the controller needs,
        or the device answers with an Error.
    :raises DeviceTimeoutError: if an acknowledgement does not arrive.
    """
    ack = link.request(Mid.SET_OUTPUT_CONFIGURATION, encode_output_configuration(items), Mid.OUTPUT_CONFIGURATION)
    if ack != encode_output_configuration(items):
        log.debug("Xsens on %s acknowledged the output configuration with %d of %d items",
                  link.name, len(ack) // 4, len(items))
    readback = link.request(Mid.SET_OUTPUT_CONFIGURATION, b"", Mid.OUTPUT_CONFIGURATION)
    got = decode_output_configuration(readback)
    check_output_configuration(got, items, link.name)
    return got
