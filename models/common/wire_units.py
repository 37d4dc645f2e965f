"""Conversions from what a device sends (its wire units) to the SI values the loop uses.

Each driver converts its wire values with the functions of this module, and the same
conversion is described as data (:class:`Derivation`: a source field and a chain of
float64 operations) so that a log which stores only the wire values can rebuild the SI
values bit for bit without importing a driver: :func:`apply_ops` is the one evaluator
(Python floats in a driver, numpy float64 arrays on a whole log, the same IEEE-754
operations in the same order).

Wire units, per device:

* load-cell amplifier: four big-endian float32 bridge signals [mV/V];
  ``T_N = (scale * raw + offset) - tare``;
* CiA 402 drive: position [counts] (int32), velocity [drive units] (int32), torque
  [per mille of the rated torque] (int16); ``pos * rad_per_count``,
  ``vel * rad_s_per_unit``, ``(tq * rated_Nm) / 1000``;
* Xsens IMU: rate of turn about the joint axis [rad/s] as the sensor sends it
  (float32 at ``precision: float32``); ``dq_out = sign * rate``;
* host receive times: integer nanoseconds of the monotonic clock; ``t_s = ns * 1e-9``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence, TypeVar

from capstan.models.common.errors import DataFormatError

T = TypeVar("T")

#: operations a derivation may use (applied left to right: ``x = x <op> value``)
OPS = ("mul", "add", "sub", "div")


def apply_ops(x: T, ops: Sequence[tuple[str, float]]) -> T:
    """Apply ``ops`` to ``x`` in order (``x`` a float or a float64 numpy array).

    :raises DataFormatError: on an unknown operation name.
    """
    for op, v in ops:
        if op == "mul":
            x = x * v  # type: ignore[operator]
        elif op == "add":
            x = x + v  # type: ignore[operator]
        elif op == "sub":
            x = x - v  # type: ignore[operator]
        elif op == "div":
            x = x / v  # type: ignore[operator]
        else:
            raise DataFormatError(f"unknown wire conversion operation {op!r} (one of {', '.join(OPS)})")
    return x


@dataclass(frozen=True)
class Derivation:
    """How one SI field is computed from one wire field.

    :ivar field: the SI field (e.g. ``T_up_in_N``).
    :ivar source: the wire field (e.g. ``lc_up_in_mV_V``).
    :ivar ops: ``(operation, float value)`` pairs, applied in float64 left to right.
    """

    field: str
    source: str
    ops: tuple[tuple[str, float], ...]

    def to_json(self) -> dict[str, Any]:
        """JSON form (``repr`` of floats round-trips exactly)."""
        return {"field": self.field, "source": self.source, "ops": [[op, float(v)] for op, v in self.ops]}

    @classmethod
    def from_json(cls, obj: Any) -> "Derivation":
        """Inverse of :meth:`to_json`.

        :raises DataFormatError: if ``obj`` is malformed or names an unknown operation.
        """
        try:
            ops = tuple((str(op), float(v)) for op, v in obj["ops"])
            d = cls(str(obj["field"]), str(obj["source"]), ops)
        except (KeyError, TypeError, ValueError) as exc:
            raise DataFormatError(f"malformed wire derivation {obj!r}: {exc}") from exc
        for op, _ in ops:
            if op not in OPS:
                raise DataFormatError(f"wire derivation of {d.field}: unknown operation {op!r}")
        return d


def seconds_from_ns(t_ns: int) -> float:
    """Monotonic-clock nanoseconds -> seconds (the only time conversion used)."""
    return t_ns * 1e-9


NS_TO_S: tuple[tuple[str, float], ...] = (("mul", 1e-9),)


def tension_ops(scale_N_per_mV_V: float, offset_N: float, tare_N: float) -> tuple[tuple[str, float], ...]:
    """``T_N = (scale * raw_mV_V + offset) - tare``."""
    return (("mul", float(scale_N_per_mV_V)), ("add", float(offset_N)), ("sub", float(tare_N)))


def motor_torque_ops(rated_torque_Nm: float) -> tuple[tuple[str, float], ...]:
    """``tau_Nm = (permille * rated_Nm) / 1000``."""
    return (("mul", float(rated_torque_Nm)), ("div", 1000.0))


def scale_ops(factor: float) -> tuple[tuple[str, float], ...]:
    """``x * factor`` (position counts, velocity units, the IMU sign)."""
    return (("mul", float(factor)),)
