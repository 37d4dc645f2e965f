"""The :class:`capstan.drivers.interfaces.Imu` for an Xsens MTi on a serial port (pyserial).

``start()`` finds the device (configured line rate, else a search of the standard
rates and a switch of the device to the configured one), sets the output configuration
and verifies it by read-back, then starts measurement
(:mod:`capstan.drivers.serial.xsens_startup`); ``poll()`` is non-blocking: it reads every available byte, parses every complete
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
from typing import Any, Mapping

from capstan.drivers.interfaces import ImuSample, LinkStats
from capstan.drivers.serial.port_io import port_fd, read_available
from capstan.drivers.serial.xsens_config import (  # noqa: F401  (re-exported: the driver's settings)
    BASE_RATE_HZ, JointAxis, OrientationOutput, XsensConfig, output_configuration, packet_size_bytes,
)
from capstan.drivers.serial.xsens_protocol import (
    LEN_EXTENDED, MAX_DATA_LEN, Mid, MtData2, Precision, XbusParser, mtdata2_max_len, mtdata2_well_formed,
    parse_mtdata2,
)
from capstan.drivers.serial.xsens_startup import XbusLink, configure_output, find_device, switch_baudrate
from capstan.models.common.errors import DriverError, ProtocolError
from capstan.models.common.wire_units import NS_TO_S, Derivation, scale_ops, seconds_from_ns

log = logging.getLogger(__name__)

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
        self._parser = XbusParser(self.stats, validators={Mid.MT_DATA2: mtdata2_well_formed})
        self._last_counter = -1
        self._out_cfg = output_configuration(config)
        self.found_baudrate = 0
        self.output_readback: list[tuple[int, int]] = []

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], prefix: str = "imu") -> XsensImu:
        """Build from the ``imu`` config section.

        :raises ConfigError: on an invalid section.
        """
        return cls(XsensConfig.from_mapping(cfg, prefix))

    # ----------------------------------------------------------- start-up (may block)
    def start(self) -> None:
        """Open the port (if needed), find the device, configure it, verify, measure.

        See :mod:`capstan.drivers.serial.xsens_startup`: GoToConfig at the configured rate
        (then, with ``baud_search``, at the standard rates, 115200 first; a device found
        elsewhere is switched to the configured rate, which it stores), output
        configuration checked by read-back, GoToMeasurement. Afterwards
        ``found_baudrate`` is the rate the device answered at and ``output_readback``
        the configuration it reported.

        :raises DeviceTimeoutError: if the device answers at no rate tried, or an
            acknowledgement does not arrive in time.
        :raises ProtocolError: on an Error (0x42) reply, or if the read-back lacks an
            item or rate the controller needs (the message names them).
        :raises DriverError: if the port cannot be opened or fails.
        """
        if self._port is None:
            import serial  # lazy: only the real backend needs it

            try:
                self._port = serial.Serial(self.config.port, self.config.baudrate, timeout=0)
            except (serial.SerialException, OSError) as exc:
                raise DriverError(f"cannot open IMU port {self.config.port}: {exc}") from exc
        cfg = self.config
        try:
            self._port.timeout = 0
            self._fd = port_fd(self._port)
            self._parser.set_limits()  # replies of any length until measurement mode
            link = XbusLink(self._port, self._parser, self.stats, cfg.port, cfg.timeout_s, cfg.retries)
            self.found_baudrate = find_device(link, cfg)
            if self.found_baudrate != cfg.baudrate:
                log.warning("Xsens on %s answered at %d Bd; switching it to %d Bd (stored in the device)",
                            cfg.port, self.found_baudrate, cfg.baudrate)
                switch_baudrate(link, cfg.baudrate)
            self.output_readback = configure_output(link, self._out_cfg)
            link.request(Mid.GO_TO_MEASUREMENT, b"", Mid.GO_TO_MEASUREMENT_ACK)
            self.bound_stream(self.output_readback)
        except OSError as exc:  # serial.SerialException derives from OSError
            raise DriverError(f"IMU port {cfg.port} failed during start-up: {exc}") from exc
        self._last_counter = -1
        st = self.stats
        log.info("Xsens IMU on %s measuring at %d Hz, %d Bd (start-up: %d frames, %d bytes skipped while "
                 "searching; link counters start now)", cfg.port, cfg.output_rate_hz, cfg.baudrate,
                 st.good_frames, st.bytes_skipped)
        st.good_frames = st.bad_frames = st.counter_gaps = st.resyncs = st.bytes_skipped = 0

    def bound_stream(self, items: list[tuple[int, int]] | None = None) -> None:
        """Bound the parser to what the output configuration can send in measurement mode.

        MTData2 longer than all configured items together, and any other message of
        extended length, is rejected as soon as its length field arrives. With an item of
        unknown size in ``items`` the MTData2 bound stays at the protocol maximum.

        :param items: the device's output configuration (default: the one requested).
        """
        try:
            mt_len = mtdata2_max_len(self._out_cfg if items is None else items)
        except ProtocolError as exc:
            log.warning("Xsens on %s: %s; MTData2 length bounded by the protocol maximum only",
                        self.config.port, exc)
            mt_len = MAX_DATA_LEN
        self._parser.set_limits(LEN_EXTENDED - 1, {Mid.MT_DATA2: mt_len})

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
