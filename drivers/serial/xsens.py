"""The :class:`capstan.drivers.interfaces.Imu` for an Xsens MTi on a serial port (pyserial).

``start()`` runs the configuration handshake (GoToConfig -> SetOutputConfiguration ->
GoToMeasurement, each acknowledged; an Error message 0x42 or a missing ack raises);
``poll()`` is non-blocking: it reads every available byte, parses every complete
frame, counts good/bad frames, counter gaps and resyncs in ``stats`` and returns the
newest sample.

Joint mapping (shared with the simulated device :class:`capstan.drivers.sim.serial_devices.SimXsens`):
the joint angle is the *twist* of the reported orientation about the configured
sensor axis ``a`` (x, y or z), ``twist = 2 atan2(q_a, q0)``, and
``q_out_rad = wrap(sign * twist + offset_rad)`` into (-pi, pi];
``dq_out_rad_s = sign * omega_a`` from the rate of turn (sensor frame). With Euler
output the angles (roll, pitch, yaw, degrees, Xsens ZYX convention) are first turned
back into the quaternion, so pitch beyond +-90 deg maps correctly. The sensor axis
``a`` must be parallel to the joint axis, which must be fixed in the world: then
``q = q0 * rot(a, theta)`` and the twist is ``twist(q0) + theta`` exactly, for any
mounting tilt ``q0`` (``offset_rad`` absorbs ``twist(q0)``). Changing the coordinate
system (ENU/NED/NWU) changes the reference frame: re-check ``sign`` and ``offset_rad``.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Mapping

from capstan.drivers.interfaces import ImuSample, LinkStats
from capstan.drivers.serial.port_io import port_fd, read_available
from capstan.drivers.serial.xsens_protocol import (
    FREQ_EVERY_PACKET, CoordSys, Mid, MtData2, Precision, XbusParser, Xdi, build_message,
    decode_output_configuration, encode_output_configuration, error_name, parse_mtdata2,
)
from capstan.models.common.config_tools import get_choice, get_float, get_int, reject_unknown
from capstan.models.common.errors import ConfigError, DeviceTimeoutError, DriverError, ProtocolError
from capstan.models.common.wire_units import NS_TO_S, Derivation, scale_ops, seconds_from_ns

log = logging.getLogger(__name__)

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
                   "coordinates", "joint_axis", "sign", "offset_rad", "timeout_s", "retries"})


@dataclass(frozen=True)
class XsensConfig:
    """IMU settings (section ``imu`` of ``config/serial_devices.yaml``).

    :ivar port: serial device path, e.g. ``/dev/ttyUSB0`` (or a pty slave path).
    :ivar baudrate: line rate [Bd]; must carry the configured stream.
    :ivar output_rate_hz: orientation / rate-of-turn output rate [Hz], divides 400.
    :ivar orientation: quaternion or Euler angles.
    :ivar precision: number format of orientation and rate of turn.
    :ivar coord_sys: coordinate system bits of the orientation item.
    :ivar joint_axis: sensor axis aligned with the joint.
    :ivar sign: +1 or -1, joint direction relative to the sensor axis.
    :ivar offset_rad: joint angle when the twist about the axis is zero [rad].
    :ivar timeout_s: wait for each acknowledgement [s].
    :ivar retries: attempts per handshake step.
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
            timeout_s=get_float(cfg, "timeout_s", prefix, default=0.5, min_value=0.0, min_exclusive=True),
            retries=get_int(cfg, "retries", prefix, default=3, min_value=1),
        )
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


# --------------------------------------------------------------------------- joint mapping

def wrap_pi(x: float) -> float:
    """Wrap an angle into (-pi, pi] [rad]."""
    y = math.fmod(x + math.pi, 2.0 * math.pi)
    if y <= 0.0:
        y += 2.0 * math.pi
    return y - math.pi


def quaternion_from_euler_deg(roll_deg: float, pitch_deg: float, yaw_deg: float) -> tuple[float, float, float, float]:
    """(q0, q1, q2, q3) of Xsens Euler angles (ZYX: yaw, then pitch, then roll) [deg]."""
    cr, sr = math.cos(math.radians(roll_deg) / 2), math.sin(math.radians(roll_deg) / 2)
    cp, sp = math.cos(math.radians(pitch_deg) / 2), math.sin(math.radians(pitch_deg) / 2)
    cy, sy = math.cos(math.radians(yaw_deg) / 2), math.sin(math.radians(yaw_deg) / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def euler_deg_from_quaternion(q: tuple[float, ...]) -> tuple[float, float, float]:
    """Xsens Euler angles (roll, pitch, yaw) [deg] of a unit quaternion (q0 scalar)."""
    q0, q1, q2, q3 = q
    roll = math.atan2(2 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3)
    pitch = -math.asin(max(-1.0, min(1.0, 2 * (q1 * q3 - q0 * q2))))
    yaw = math.atan2(2 * (q1 * q2 + q0 * q3), q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3)
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)


def twist_angle_rad(q: tuple[float, ...], axis: int) -> float:
    """Rotation angle of quaternion ``q`` about sensor axis ``axis`` (0 x, 1 y, 2 z) [rad]."""
    return wrap_pi(2.0 * math.atan2(q[1 + axis], q[0]))


def joint_from_mtdata2(m: MtData2, cfg: XsensConfig) -> tuple[float, float] | None:
    """(q_out_rad, dq_out_rad_s) of one packet, None if orientation or rate is absent."""
    if m.rate_of_turn_rad_s is None:
        return None
    if m.quaternion is not None:
        q = m.quaternion
    elif m.euler_deg is not None:
        q = quaternion_from_euler_deg(*m.euler_deg)
    else:
        return None
    axis = int(cfg.joint_axis)
    q_out = wrap_pi(cfg.sign * twist_angle_rad(q, axis) + cfg.offset_rad)
    return q_out, cfg.sign * m.rate_of_turn_rad_s[axis]


# --------------------------------------------------------------------------- driver

class XsensImu:
    """Xsens MTi over pyserial; implements :class:`capstan.drivers.interfaces.Imu`.

    :param config: validated settings.
    :param port: an already open pyserial port (tests, ``serial_for_url``); if None,
        ``start()`` opens ``config.port``.
    """

    def __init__(self, config: XsensConfig, port: Any = None) -> None:
        self.config = config
        self.stats = LinkStats()
        self.device_errors = 0
        self.last_error_code = 0
        self.last_packet: MtData2 | None = None
        self._port = port
        self._fd = -1
        self._parser = XbusParser(self.stats)
        self._last_counter = -1
        self._out_cfg = output_configuration(config)

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], prefix: str = "imu") -> XsensImu:
        """Build from the ``imu`` config section.

        :raises ConfigError: on an invalid section.
        """
        return cls(XsensConfig.from_mapping(cfg, prefix))

    # ----------------------------------------------------------- start-up (may block)
    def start(self) -> None:
        """Open the port (if needed) and run the configuration handshake.

        :raises DeviceTimeoutError: if an acknowledgement does not arrive in time.
        :raises ProtocolError: on an Error (0x42) reply or a wrong configuration echo.
        :raises DriverError: if the port cannot be opened.
        """
        if self._port is None:
            import serial  # lazy: only the real backend needs it

            try:
                self._port = serial.Serial(self.config.port, self.config.baudrate, timeout=0)
            except (serial.SerialException, OSError) as exc:
                raise DriverError(f"cannot open IMU port {self.config.port}: {exc}") from exc
        try:
            self._port.timeout = 0
            self._fd = port_fd(self._port)
            self._port.reset_input_buffer()
            self._parser.reset()
            self._request(Mid.GO_TO_CONFIG, b"", Mid.GO_TO_CONFIG_ACK)
            echo = self._request(Mid.SET_OUTPUT_CONFIGURATION, encode_output_configuration(self._out_cfg),
                                 Mid.OUTPUT_CONFIGURATION)
            self._check_echo(echo)
            self._request(Mid.GO_TO_MEASUREMENT, b"", Mid.GO_TO_MEASUREMENT_ACK)
        except OSError as exc:  # serial.SerialException derives from OSError
            raise DriverError(f"IMU port {self.config.port} failed during start-up: {exc}") from exc
        self._last_counter = -1
        log.info("Xsens IMU on %s measuring at %d Hz", self.config.port, self.config.output_rate_hz)

    def _check_echo(self, data: bytes) -> None:
        got = decode_output_configuration(data)
        want = self._out_cfg
        ok = len(got) == len(want) and all(
            gx == wx and (gf == wf or (wf == FREQ_EVERY_PACKET and gf in (0, FREQ_EVERY_PACKET)))
            for (gx, gf), (wx, wf) in zip(got, want))
        if not ok:
            raise ProtocolError(f"Xsens output configuration echo {[(hex(x), f) for x, f in got]} "
                                f"differs from request {[(hex(x), f) for x, f in want]}")

    def _request(self, mid: int, data: bytes, ack: int) -> bytes:
        msg = build_message(mid, data)
        for attempt in range(self.config.retries):
            self._port.write(msg)
            deadline = time.monotonic() + self.config.timeout_s
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._port.timeout = min(remaining, 0.05)
                chunk = self._port.read(max(1, self._port.in_waiting))
                self._port.timeout = 0
                for rmid, rdata in self._parser.feed(chunk):
                    self.stats.good_frames += 1  # stream packets before the ack are dropped
                    if rmid == ack:
                        return rdata
                    if rmid == Mid.ERROR:
                        code = rdata[0] if rdata else -1
                        raise ProtocolError(f"Xsens replied Error {code} ({error_name(code)}) "
                                            f"to MID 0x{mid:02X}")
            log.warning("Xsens: no ack 0x%02X to MID 0x%02X (attempt %d)", ack, mid, attempt + 1)
        raise DeviceTimeoutError(f"Xsens on {self.config.port}: no ack 0x{ack:02X} to MID 0x{mid:02X} "
                                 f"after {self.config.retries} x {self.config.timeout_s} s")

    # ----------------------------------------------------------- per cycle (non-blocking)
    def poll(self) -> ImuSample | None:
        """Read available bytes without blocking; the newest sample, or None.

        :raises DriverError: if the port fails (device unplugged).
        """
        try:
            data = read_available(self._port, self._fd)
        except OSError as exc:  # serial.SerialException derives from OSError
            raise DriverError(f"IMU port {self.config.port} failed: {exc}") from exc
        if not data:
            return None
        newest = None
        stats = self.stats
        for mid, payload in self._parser.feed(data):
            if mid != Mid.MT_DATA2:
                stats.good_frames += 1
                if mid == Mid.ERROR:
                    self.device_errors += 1
                    self.last_error_code = payload[0] if payload else -1
                continue
            try:
                m = parse_mtdata2(payload)
            except ProtocolError:
                stats.bad_frames += 1
                continue
            joint = joint_from_mtdata2(m, self.config)
            if joint is None:
                stats.bad_frames += 1
                continue
            stats.good_frames += 1
            c = m.packet_counter
            if c is not None:
                if self._last_counter >= 0:
                    d = (c - self._last_counter) & 0xFFFF
                    if d:  # d == 0: repeated packet, not a gap
                        stats.counter_gaps += d - 1
                self._last_counter = c
            self.last_packet = m
            newest = (joint, c)
        if newest is None:
            return None
        (q, dq), c = newest
        t_ns = time.monotonic_ns()
        rate = self.last_packet.rate_of_turn_rad_s[int(self.config.joint_axis)]
        return ImuSample(t_s=seconds_from_ns(t_ns), q_out_rad=q, dq_out_rad_s=dq,
                         counter=-1 if c is None else c, t_ns=t_ns, rate_rad_s=rate)

    def derivations(self) -> list[Derivation]:
        """How a log rebuilds ``dq_out_rad_s`` and ``imu_t_s`` from the logged wire values:
        exactly :func:`joint_from_mtdata2` (``sign * rate``) and the receive clock."""
        return [Derivation("dq_out_rad_s", "imu_rate_rad_s", scale_ops(self.config.sign)),
                Derivation("imu_t_s", "imu_t_ns", NS_TO_S)]

    @property
    def rate_is_float32(self) -> bool:
        """True if the sensor sends its rate of turn as float32 (``precision: float32``)."""
        return self.config.precision == Precision.FLOAT32

    def close(self) -> None:
        """Close the port (idempotent)."""
        if self._port is not None:
            self._port.close()
            self._port = None
            self._fd = -1
