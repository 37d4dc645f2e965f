"""The units the simulated drive serves 0x6064 and 0x606C in, from its object dictionary.

CiA 402-2 factor group as a drive applies it: 0x60A8 (0x60A9) declares the unit of 0x6064
(0x606C) (:mod:`capstan.drivers.canopen.si_units`); increments count the motor encoder
(0x608F, else the motor's ``encoder_counts_per_rev``), an angle unit is of the shaft behind
the gear 0x6091. A dictionary without 0x60A8/0x60A9 serves increments (per second): CiA 402's
default user unit.
"""

from __future__ import annotations

import math
from typing import Callable

from capstan.drivers.canopen.si_units import SiUnit


def _ratio(value: Callable[[int, int], int | None], has: Callable[[int], bool], index: int) -> float:
    """sub 1 / sub 2 of a factor-group object (1 where the dictionary lacks it).

    :raises ValueError: if either is not a positive integer.
    """
    if not has(index):
        return 1.0
    num, den = int(value(index, 1) or 0), int(value(index, 2) or 0)
    if num <= 0 or den <= 0:
        raise ValueError(f"0x{index:04X} = {num}:{den} is not a ratio of positive integers")
    return num / den


def wire_units_per_rad(value: Callable[[int, int], int | None], has: Callable[[int], bool],
                       encoder_counts_per_rev: int) -> tuple[float, float]:
    """(units of 0x6064 per motor-shaft rad, units of 0x606C per motor-shaft rad/s).

    :param value: ``value(index, sub)`` of the dictionary.
    :param has: ``has(index)``: the dictionary lists the object.
    :param encoder_counts_per_rev: the motor encoder's increments per revolution.
    :raises ValueError: for a unit code, encoder resolution or gear the drive cannot serve.
    """
    inc_per_rev = _ratio(value, has, 0x608F) if has(0x608F) else encoder_counts_per_rev
    inc_per_rad = inc_per_rev / (2 * math.pi)
    out = []
    for index, time_unit in ((0x60A8, False), (0x60A9, True)):
        if not has(index):
            out.append(inc_per_rad)
            continue
        unit = SiUnit.decode(int(value(index, 0) or 0))
        seconds = unit.seconds if time_unit else (1.0 if unit.denominator == 0 else None)
        if seconds is None:
            raise ValueError(f"0x{index:04X} = {unit}: not a {'velocity' if time_unit else 'position'} unit")
        if unit.is_increments:
            out.append(inc_per_rad * seconds / 10.0 ** unit.exponent)
        elif unit.radians is None:
            raise ValueError(f"0x{index:04X} = {unit}: not an angle unit this drive serves")
        else:
            out.append(seconds / unit.radians / _ratio(value, has, 0x6091))
    return out[0], out[1]
