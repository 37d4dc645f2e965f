"""User units of the peer drive (CiA 402-2 factor group), written from the specification.

An SI unit object (0x60A8 position, 0x60A9 velocity) is UNSIGNED32: byte 3 the power of ten
(INTEGER8), byte 2 the numerator's unit, byte 1 the denominator's unit, byte 0 reserved.
Unit codes (CiA 303-2) this peer serves: numerator 0xB5 increments of the motor encoder,
0xB4 revolution, 0x41 degree, 0x10 radian (angles of the shaft behind the gear 0x6091);
denominator 0x00 (none: a position), 0x03 second, 0x47 minute, 0x48 hour.

The drive counts increments internally (0x6063); 0x608F says how many per motor revolution,
0x6091 how many motor revolutions per shaft revolution.
"""

from __future__ import annotations

import math

_TURN_IN = {0xB4: 1.0, 0x41: 360.0, 0x10: 2.0 * math.pi}     # one revolution in the unit
_TIME_S = {0x03: 1.0, 0x47: 60.0, 0x48: 3600.0}


class UnitError(ValueError):
    """A unit code the peer does not serve."""


def user_value(code: int, increments: float, encoder: tuple[int, int], gear: tuple[int, int]) -> int:
    """``increments`` (per second for a velocity code) expressed in the unit of ``code``, rounded.

    :param encoder: 0x608F (increments, motor revolutions).
    :param gear: 0x6091 (motor revolutions, shaft revolutions).
    :raises UnitError: for a code, encoder or gear the peer cannot serve.
    """
    power = int.from_bytes(bytes([(code >> 24) & 0xFF]), "little", signed=True)
    numerator, denominator = (code >> 16) & 0xFF, (code >> 8) & 0xFF
    if denominator == 0:
        per_second = 1.0
    elif denominator in _TIME_S:
        per_second = _TIME_S[denominator]      # the quantity per that time unit
    else:
        raise UnitError(f"denominator 0x{denominator:02X}")
    if numerator == 0xB5:
        amount = increments
    elif numerator in _TURN_IN:
        if encoder[0] <= 0 or encoder[1] <= 0 or gear[0] <= 0 or gear[1] <= 0:
            raise UnitError("encoder resolution or gear ratio not set")
        motor_turns = increments * encoder[1] / encoder[0]
        amount = motor_turns * gear[1] / gear[0] * _TURN_IN[numerator]
    else:
        raise UnitError(f"numerator 0x{numerator:02X}")
    return round(amount * per_second * 10.0 ** (-power))
