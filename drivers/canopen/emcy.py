"""CANopen EMCY (emergency) frames decoded into readable faults (CiA 301 / CiA 402).

An EMCY frame on COB-ID ``0x80 + node`` carries 8 bytes::

    <u16 error code, little endian> <u8 error register 0x1001> <5 bytes manufacturer data>

Error code ``0x0000`` means "error reset / no error" (the drive left the fault).
:func:`describe_code` returns the most specific entry of the CiA 301/402 table
(exact code, then the code's group).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from capstan.models.common.errors import ProtocolError

#: CiA 301 (communication) and CiA 402 (drive profile) emergency error codes.
EMCY_CODES: dict[int, str] = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x2000: "current",
    0x2100: "current, device input side",
    0x2200: "current inside the device",
    0x2300: "current, device output side",
    0x2310: "continuous over-current",
    0x2320: "short circuit / earth leakage",
    0x2330: "earth leakage",
    0x2340: "short circuit",
    0x3000: "voltage",
    0x3100: "mains voltage",
    0x3110: "mains over-voltage",
    0x3120: "mains under-voltage",
    0x3200: "voltage inside the device",
    0x3210: "DC link over-voltage",
    0x3220: "DC link under-voltage",
    0x3300: "output voltage",
    0x4000: "temperature",
    0x4100: "ambient temperature",
    0x4200: "device temperature",
    0x4210: "excess temperature, device",
    0x4300: "drive temperature",
    0x4310: "excess temperature, drive",
    0x5000: "device hardware",
    0x5400: "power section",
    0x5441: "power stage, enable input",
    0x6000: "device software",
    0x6100: "internal software",
    0x6200: "user software",
    0x6300: "data set",
    0x7000: "additional modules",
    0x7100: "power",
    0x7110: "brake chopper",
    0x7120: "motor",
    0x7121: "motor blocked",
    0x7300: "sensor",
    0x7305: "incremental sensor 1 fault",
    0x7310: "speed",
    0x7320: "position",
    0x8000: "monitoring",
    0x8100: "communication",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8150: "CAN-ID collision",
    0x8200: "protocol error",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8230: "DAM MPDO not processed, destination object not available",
    0x8240: "unexpected SYNC data length",
    0x8250: "RPDO timeout",
    0x8300: "torque control",
    0x8311: "excess torque",
    0x8400: "velocity / speed controller",
    0x8500: "position controller",
    0x8600: "positioning controller",
    0x8611: "following error",
    0x8700: "sync controller",
    0x9000: "external error",
    0xF000: "additional functions",
    0xFF00: "device specific",
}

#: Bits of the error register (0x1001), CiA 301.
ERROR_REGISTER_BITS: dict[int, str] = {
    0: "generic",
    1: "current",
    2: "voltage",
    3: "temperature",
    4: "communication",
    5: "device profile specific",
    7: "manufacturer specific",
}

_EMCY = struct.Struct("<HB5s")


def describe_code(code: int) -> str:
    """Readable text of an EMCY error code: the most specific table entry.

    Lookup order: exact code, then ``code & 0xFFF0``, ``0xFF00``, ``0xF000``;
    manufacturer-specific codes (0xFFxx) map to "device specific".
    """
    for mask in (0xFFFF, 0xFFF0, 0xFF00, 0xF000):
        text = EMCY_CODES.get(code & mask)
        if text is not None and (mask == 0xFFFF or code & mask != 0 or code == 0):
            return text
    return f"unknown error code 0x{code:04X}"


def describe_register(register: int) -> list[str]:
    """Names of the bits set in an error register (0x1001)."""
    return [name for bit, name in ERROR_REGISTER_BITS.items() if register & (1 << bit)]


@dataclass(frozen=True)
class EmcyFault:
    """One decoded EMCY frame.

    :ivar code: 16-bit emergency error code.
    :ivar register: error register (0x1001) at the time of the EMCY.
    :ivar vendor_data: 5 manufacturer-specific bytes.
    :ivar t_s: receive time [s] (the clock of the caller).
    """

    code: int
    register: int
    vendor_data: bytes
    t_s: float = 0.0

    @property
    def is_reset(self) -> bool:
        """True for the "error reset / no error" EMCY (code 0x0000)."""
        return self.code == 0

    @property
    def description(self) -> str:
        """Readable text of :attr:`code`."""
        return describe_code(self.code)

    def __str__(self) -> str:
        regs = ", ".join(describe_register(self.register)) or "none"
        return (f"EMCY 0x{self.code:04X} ({self.description}); error register 0x{self.register:02X}"
                f" [{regs}]; vendor data {self.vendor_data.hex()}")


def decode_emcy(data: bytes | bytearray, t_s: float = 0.0) -> EmcyFault:
    """Decode the 8 data bytes of an EMCY frame.

    :raises ProtocolError: if the frame is shorter than 3 bytes.
    """
    if len(data) < 3:
        raise ProtocolError(f"EMCY frame needs at least 3 data bytes, got {len(data)}")
    padded = bytes(data[:8]).ljust(8, b"\x00")
    code, register, vendor = _EMCY.unpack(padded)
    return EmcyFault(code=code, register=register, vendor_data=vendor, t_s=t_s)


def encode_emcy(code: int, register: int, vendor_data: bytes = b"") -> bytes:
    """The 8 data bytes of an EMCY frame (used by the simulated drive)."""
    return _EMCY.pack(code & 0xFFFF, register & 0xFF, bytes(vendor_data[:5]).ljust(5, b"\x00"))
