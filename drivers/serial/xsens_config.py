"""Settings of the Xsens MTi driver (section ``imu``) and the output configuration they imply.

The output configuration is what the controller needs from the device: PacketCounter
and SampleTimeFine and StatusWord with every packet, orientation (quaternion or Euler
angles, in the configured precision and coordinate system) and rate of turn at
``output_rate_hz``. Baud rates are the ones the MT protocol's SetBaudrate (0x18) can
select; a new MTi leaves the factory at 115200 Bd.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Mapping

from capstan.drivers.serial.xsens_protocol import FREQ_EVERY_PACKET, CoordSys, Precision, Xdi
from capstan.models.common.config_tools import get_bool, get_choice, get_float, get_int, reject_unknown
from capstan.models.common.errors import ConfigError

#: SetBaudrate (0x18) code of each line rate [Bd] (MT Low-Level Communication Protocol)
BAUD_CODES: dict[int, int] = {
    921600: 0x80, 460800: 0x00, 230400: 0x01, 115200: 0x02, 76800: 0x03, 57600: 0x04,
    38400: 0x05, 28800: 0x06, 19200: 0x07, 14400: 0x08, 9600: 0x09, 4800: 0x0B,
}
#: line rate of a new MTi [Bd]
FACTORY_BAUDRATE = 115200
#: order in which start-up searches the rate after the configured one [Bd]
SEARCH_BAUDRATES: tuple[int, ...] = (FACTORY_BAUDRATE, 921600, 460800, 230400, 57600, 38400, 19200, 9600)


def baud_code(baudrate: int) -> int:
    """SetBaudrate code of ``baudrate`` [Bd].

    :raises ConfigError: if the MT protocol cannot select that rate.
    """
    try:
        return BAUD_CODES[baudrate]
    except KeyError:
        raise ConfigError("imu.baudrate", f"{baudrate} Bd is not an MTi rate; one of "
                                          f"{', '.join(str(b) for b in sorted(BAUD_CODES))}") from None


def baudrate_of_code(code: int) -> int | None:
    """Line rate [Bd] of a SetBaudrate code (0x0A is an alias of 921600), None if unknown."""
    if code == 0x0A:
        return 921600
    return next((bd for bd, c in BAUD_CODES.items() if c == code), None)


#: device base rate: output frequencies must divide it
BASE_RATE_HZ = 400


class JointAxis(IntEnum):
    """Sensor axis aligned with the joint axis."""

    X = 0
    Y = 1
    Z = 2


class OrientationOutput(IntEnum):
    """Orientation item requested from the device."""

    QUATERNION = 0
    EULER = 1


_PRECISIONS = {"float32": Precision.FLOAT32, "fp1220": Precision.FP1220,
               "fp1632": Precision.FP1632, "float64": Precision.FLOAT64}
_COORDS = {"enu": CoordSys.ENU, "ned": CoordSys.NED, "nwu": CoordSys.NWU}
_KEYS = frozenset({"port", "baudrate", "output_rate_hz", "orientation", "precision",
                   "coordinates", "joint_axis", "sign", "offset_rad", "timeout_s", "retries",
                   "baud_search"})


@dataclass(frozen=True)
class XsensConfig:
    """IMU settings (section ``imu`` of ``config/serial_devices.yaml``).

    :ivar port: serial device path, e.g. ``/dev/ttyUSB0`` (or a pty slave path).
    :ivar baudrate: running line rate [Bd]; must carry the configured stream and be one
        SetBaudrate can select (:data:`BAUD_CODES`).
    :ivar output_rate_hz: orientation / rate-of-turn output rate [Hz], divides 400.
    :ivar orientation: quaternion or Euler angles.
    :ivar precision: number format of orientation and rate of turn.
    :ivar coord_sys: coordinate system bits of the orientation item.
    :ivar joint_axis: sensor axis aligned with the joint.
    :ivar sign: +1 or -1, joint direction relative to the sensor axis.
    :ivar offset_rad: joint angle when the twist about the axis is zero [rad].
    :ivar timeout_s: wait for each acknowledgement [s], (0, 5].
    :ivar retries: attempts per handshake step (and rounds of the baud-rate search).
    :ivar baud_search: if the device does not answer at ``baudrate``, search the standard
        rates (115200 first), switch the device to ``baudrate`` and store it there.
    """

    port: str
    baudrate: int = 921600
    output_rate_hz: int = 400
    orientation: OrientationOutput = OrientationOutput.QUATERNION
    precision: Precision = Precision.FLOAT32
    coord_sys: CoordSys = CoordSys.ENU
    joint_axis: JointAxis = JointAxis.Z
    sign: float = 1.0
    offset_rad: float = 0.0
    timeout_s: float = 0.5
    retries: int = 3
    baud_search: bool = True

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any], prefix: str = "imu") -> XsensConfig:
        """Validate a mapping (e.g. the ``imu`` section).

        :raises ConfigError: naming the key and the reason.
        """
        reject_unknown(cfg, _KEYS, prefix)
        if not isinstance(cfg.get("port"), str) or not cfg["port"]:
            raise ConfigError(f"{prefix}.port", "missing serial device path (string)")
        sign = get_float(cfg, "sign", prefix, default=1.0)
        if sign not in (1.0, -1.0):
            raise ConfigError(f"{prefix}.sign", f"must be 1 or -1, got {sign}")
        rate = get_int(cfg, "output_rate_hz", prefix, default=400, min_value=1, max_value=BASE_RATE_HZ)
        if BASE_RATE_HZ % rate:
            raise ConfigError(f"{prefix}.output_rate_hz", f"must divide {BASE_RATE_HZ}, got {rate}")
        c = cls(
            port=cfg["port"],
            baudrate=get_int(cfg, "baudrate", prefix, default=921600, min_value=9600),
            output_rate_hz=rate,
            orientation=OrientationOutput[get_choice(cfg, "orientation", ("quaternion", "euler"),
                                                     prefix, "quaternion").upper()],
            precision=_PRECISIONS[get_choice(cfg, "precision", tuple(_PRECISIONS), prefix, "float32")],
            coord_sys=_COORDS[get_choice(cfg, "coordinates", tuple(_COORDS), prefix, "enu")],
            joint_axis=JointAxis[get_choice(cfg, "joint_axis", ("x", "y", "z"), prefix, "z").upper()],
            sign=sign,
            offset_rad=get_float(cfg, "offset_rad", prefix, default=0.0),
            timeout_s=get_float(cfg, "timeout_s", prefix, default=0.5, min_value=0.0, max_value=5.0,
                              min_exclusive=True),  # a real MTi answers in ms; longer hides a wrong rate
            retries=get_int(cfg, "retries", prefix, default=3, min_value=1),
            baud_search=get_bool(cfg, "baud_search", prefix, True),
        )
        if c.baudrate not in BAUD_CODES:
            raise ConfigError(f"{prefix}.baudrate", f"{c.baudrate} Bd is not a rate SetBaudrate can select; one of "
                                                    f"{', '.join(str(b) for b in sorted(BAUD_CODES))}")
        need_bd = 10 * packet_size_bytes(c) * c.output_rate_hz
        if need_bd > c.baudrate:
            raise ConfigError(f"{prefix}.baudrate", f"{c.baudrate} Bd cannot carry {c.output_rate_hz} Hz "
                                                    f"packets of {packet_size_bytes(c)} bytes (needs >= {need_bd})")
        return c


def output_configuration(cfg: XsensConfig) -> list[tuple[int, int]]:
    """The (XDI, frequency) list sent in SetOutputConfiguration."""
    fmt = int(cfg.precision)
    orient = Xdi.QUATERNION if cfg.orientation == OrientationOutput.QUATERNION else Xdi.EULER_ANGLES
    return [
        (Xdi.PACKET_COUNTER, FREQ_EVERY_PACKET),
        (Xdi.SAMPLE_TIME_FINE, FREQ_EVERY_PACKET),
        (orient | fmt | int(cfg.coord_sys), cfg.output_rate_hz),
        (Xdi.RATE_OF_TURN | fmt, cfg.output_rate_hz),
        (Xdi.STATUS_WORD, FREQ_EVERY_PACKET),
    ]


def packet_size_bytes(cfg: XsensConfig) -> int:
    """Bytes of one MTData2 message on the wire with this configuration."""
    width = {Precision.FLOAT32: 4, Precision.FP1220: 4, Precision.FP1632: 6, Precision.FLOAT64: 8}[cfg.precision]
    n_orient = 4 if cfg.orientation == OrientationOutput.QUATERNION else 3
    data = (3 + 2) + (3 + 4) + (3 + n_orient * width) + (3 + 3 * width) + (3 + 4)
    return 4 + data + 1
