"""CiA 402 SI unit codes (0x60A8 SI unit position, 0x60A9 SI unit velocity): decode and encode.

An SI unit object is an UNSIGNED32 (CiA 402-2, the "factor group"; the same layout in the
Nanotec, Synapticon and maxon manuals):

* bits 31-24: prefix, a signed power of ten (``0xFF`` = 10^-1, ``0xFD`` = 10^-3);
* bits 23-16: the unit (CiA 303-2 code) of the numerator;
* bits 15-8: the unit of the denominator (``0x00`` none, for a position);
* bits 7-0: reserved (0).

The angle and time codes capstan understands (CiA 303-2): 0x10 radian, 0x41 degree,
0xB4 revolution, 0xB5 increment (of the position encoder, 0x608F); 0x03 second,
0x47 minute, 0x48 hour. 0x01 metre (a linear axis) is recognised and refused by the
caller: capstan's drive turns a capstan.

Examples: 0x00B44700 rpm (the Nanotec C5-E default of 0x60A9), 0xFF410000 tenths of a
degree (its 0x60A8 default), 0x00B50000 increments, 0x00B50300 increments per second,
0xFDB44700 milli-rpm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: angle units: code -> (symbol, radians per unit); None: increments of the encoder (0x608F)
ANGLE_UNITS: dict[int, tuple[str, float | None]] = {
    0x10: ("rad", 1.0), 0x41: ("deg", math.pi / 180.0), 0xB4: ("rev", 2.0 * math.pi), 0xB5: ("inc", None),
}
#: time units: code -> (symbol, seconds per unit)
TIME_UNITS: dict[int, tuple[str, float]] = {0x03: ("s", 1.0), 0x47: ("min", 60.0), 0x48: ("h", 3600.0)}
#: linear units (refused: capstan's drive is rotary)
LINEAR_UNITS: dict[int, str] = {0x01: "m"}


@dataclass(frozen=True)
class SiUnit:
    """One decoded SI unit object.

    :ivar code: the raw UNSIGNED32.
    :ivar exponent: power of ten of the prefix.
    :ivar numerator: unit code of the numerator (CiA 303-2).
    :ivar denominator: unit code of the denominator (0: none).
    """

    code: int
    exponent: int
    numerator: int
    denominator: int

    @classmethod
    def decode(cls, code: int) -> "SiUnit":
        """Split an SI unit object into its fields (no check of the codes)."""
        code &= 0xFFFFFFFF
        prefix = code >> 24
        return cls(code, prefix - 256 if prefix & 0x80 else prefix, (code >> 16) & 0xFF, (code >> 8) & 0xFF)

    @staticmethod
    def encode(exponent: int, numerator: int, denominator: int = 0) -> int:
        """The UNSIGNED32 of a prefix exponent and unit codes."""
        return ((exponent & 0xFF) << 24) | ((numerator & 0xFF) << 16) | ((denominator & 0xFF) << 8)

    @property
    def is_increments(self) -> bool:
        """True if the numerator counts encoder increments (its size comes from 0x608F)."""
        return self.numerator == 0xB5

    @property
    def radians(self) -> float | None:
        """Radians of one unit of the numerator times the prefix; None for increments or an
        unknown code."""
        unit = ANGLE_UNITS.get(self.numerator)
        if unit is None or unit[1] is None:
            return None
        return unit[1] * 10.0 ** self.exponent

    @property
    def seconds(self) -> float | None:
        """Seconds of the denominator; None if it is not a known time unit."""
        unit = TIME_UNITS.get(self.denominator)
        return None if unit is None else unit[1]

    def __str__(self) -> str:
        num = ANGLE_UNITS.get(self.numerator, (LINEAR_UNITS.get(self.numerator, f"unit 0x{self.numerator:02X}"),))[0]
        prefix = f"{10.0 ** self.exponent:g} " if self.exponent else ""
        text = f"{prefix}{num}"
        if self.denominator:
            den = TIME_UNITS.get(self.denominator, (f"unit 0x{self.denominator:02X}",))[0]
            text += f"/{den}"
        if (self.numerator, self.denominator) == (0xB4, 0x47):
            text = f"{prefix}rpm"  # revolutions per minute
        return f"0x{self.code:08X} ({text})"


#: candidate (numerator, denominator) codes, in order of preference, for a position / a velocity
_POSITION_CANDIDATES = ((0xB5, 0x00), (0x41, 0x00), (0xB4, 0x00), (0x10, 0x00))
_VELOCITY_CANDIDATES = ((0xB4, 0x47), (0xB5, 0x03), (0x10, 0x03), (0x41, 0x03), (0xB4, 0x03))
_EXPONENTS = (0, -1, 1, -2, 2, -3, 3, -4, 4, -5, 5, -6, 6)


def code_for(units_per_motor_rev: float, increments_per_rev: float | None, gear_ratio: float,
             time_unit: bool, rtol: float = 1e-9) -> int | None:
    """The SI unit code whose unit makes ``units_per_motor_rev`` units per motor revolution
    (per motor rev/s for ``time_unit``), or None if no code does.

    :param increments_per_rev: 0x608F of the drive (None: increments are not offered).
    :param gear_ratio: the drive's 0x6091 (motor revolutions per shaft revolution).
    """
    for numerator, denominator in (_VELOCITY_CANDIDATES if time_unit else _POSITION_CANDIDATES):
        seconds = TIME_UNITS[denominator][1] if denominator else 1.0
        if numerator == 0xB5:
            if not increments_per_rev:
                continue
            base = increments_per_rev * seconds           # units per motor rev(/s) at prefix 10^0
        else:
            base = 2 * math.pi / ANGLE_UNITS[numerator][1] * seconds / gear_ratio
        for exponent in _EXPONENTS:
            if abs(base * 10.0 ** -exponent - units_per_motor_rev) <= rtol * units_per_motor_rev:
                return SiUnit.encode(exponent, numerator, denominator)
    return None
