"""Simulated serial devices on pseudo-terminals: an Xsens MTi and the load-cell amplifier.

Each simulated device writes the real device's bytes into the master side of a pty
pair (``os.openpty``); the driver opens the slave path with pyserial exactly as it
would open ``/dev/ttyUSB0``. The simulated rig process drives them:

- :class:`SimXsens` ``service()`` answers host commands without blocking (GoToConfig,
  SetOutputConfiguration with an echo of the accepted configuration,
  ReqOutputConfiguration, GoToMeasurement, ReqDID, SetBaudrate/ReqBaudrate, Reset with
  WakeUp, WakeUpAck; Error 0x42 for anything unsupported) and ``emit(t, q, dq)`` writes
  one MTData2 packet in measurement mode, using the same joint mapping as
  :mod:`capstan.drivers.serial.xsens` (axis, sign, offset). With ``boot_baudrate`` it
  runs at a line rate of its own, like a real unit (a new MTi boots at 115200 Bd): it
  reads the rate the host set on the pty (the pair shares one termios) and, while the
  two differ, ignores the host's bytes and sends framing garbage instead of its
  messages. SetBaudrate is stored and takes effect at the next Reset.
- :class:`SimLoadCellAmp` ``emit(tensions_N)`` writes one frame in mV/V, the inverse of
  the driver's ``scale_N_per_mV_V``/``offset_N`` (plus an optional bridge bias that a
  tare removes).

Fault injection for tests: ``inject_fault(SerialFault.X, count)`` applies to the next
``count`` emitted frames (corrupt checksum, truncated frame, garbage bytes before the
frame, dropped packet-counter value).
"""

from __future__ import annotations

import math
import struct
import time
from enum import IntEnum
from typing import Any, Mapping

from capstan.drivers.serial.loadcell import LoadCellConfig
from capstan.drivers.serial.loadcell_protocol import N_CHANNELS, build_frame
from capstan.drivers.serial.xsens import (
    BASE_RATE_HZ, JointAxis, XsensConfig, euler_deg_from_quaternion, output_configuration,
)
from capstan.drivers.serial.xsens_config import BAUD_CODES, baudrate_of_code
from capstan.drivers.serial.xsens_protocol import (
    FREQ_EVERY_PACKET, PRECISION_MASK, SAMPLE_TIME_FINE_HZ, XDI_TYPE_MASK, ErrorCode, Mid,
    XbusParser, Xdi, build_message, build_mtdata2_item, decode_output_configuration,
    encode_output_configuration, encode_values,
)
from capstan.drivers.sim.serial_link import (  # noqa: F401  (re-exported: one import for users)
    MAX_PENDING_BYTES, DeviceEndpoint, FaultInjector, PtyPair, SerialFault, open_pty_pair,
)
from capstan.models.common.errors import ProtocolError

STATUS_WORD_OK = 0x00000003  # self-test passed, filter valid
#: time from Reset to the WakeUp message at the stored line rate [s]
REBOOT_S = 0.05


class SimMode(IntEnum):
    """State of the simulated MTi."""

    CONFIG = 0
    MEASUREMENT = 1


_SET_BAUDRATE = 0x18
_RESET = 0x40
_SUPPORTED = {Xdi.PACKET_COUNTER, Xdi.SAMPLE_TIME_FINE, Xdi.QUATERNION, Xdi.EULER_ANGLES,
              Xdi.RATE_OF_TURN, Xdi.STATUS_WORD}


class SimXsens(FaultInjector):
    """A simulated Xsens MTi speaking the MT binary protocol.

    Starts in measurement mode with the output configuration the driver's defaults
    request (as a device configured earlier would). The orientation is the pure
    rotation about the joint axis (no mounting tilt), whatever coordinate-system bits
    are requested; items with a lower frequency than the packet rate are decimated.

    :param fd_or_port: pty master fd, device path or pyserial port.
    :param joint_axis: sensor axis aligned with the joint ("x", "y", "z" or JointAxis).
    :param sign: +1 or -1, as in the driver config.
    :param offset_rad: as in the driver config [rad].
    :param device_id: reported by ReqDID.
    :param seed: seed of the garbage generator.
    :param boot_baudrate: line rate the device starts at [Bd] (115200 for a new unit);
        None: no line-rate emulation (any host rate works, e.g. for non-pty endpoints).
    :raises ProtocolError: if ``boot_baudrate`` is not a rate SetBaudrate can select.
    """

    def __init__(self, fd_or_port: int | str | Any, joint_axis: str | JointAxis = "z", sign: float = 1.0,
                 offset_rad: float = 0.0, device_id: int = 0x037003F8, seed: int = 0,
                 boot_baudrate: int | None = None) -> None:
        super().__init__(seed)
        self._ep = DeviceEndpoint(fd_or_port)
        self.axis = JointAxis[joint_axis.upper()] if isinstance(joint_axis, str) else JointAxis(joint_axis)
        self.sign = float(sign)
        self.offset_rad = float(offset_rad)
        self.device_id = device_id
        self.mode = SimMode.MEASUREMENT
        self.output_config: list[tuple[int, int]] = output_configuration(XsensConfig(port=""))
        self.packet_counter = 0
        self.status_word = STATUS_WORD_OK
        self.host_mids: list[int] = []
        self._parser = XbusParser()
        self._n_emitted = 0
        if boot_baudrate is not None and boot_baudrate not in BAUD_CODES:
            raise ProtocolError(f"simulated MTi: {boot_baudrate} Bd is not an MTi rate")
        self.baudrate = boot_baudrate
        self.stored_baudrate = boot_baudrate
        self.resets = 0
        self.garbled_bytes = 0
        self._wake_at_s: float | None = None

    @classmethod
    def from_config(cls, fd_or_port: int | str | Any, cfg: Mapping[str, Any], seed: int = 0,
                    boot_baudrate: int | None = None) -> SimXsens:
        """Simulated device matching the driver's ``imu`` config section (axis, sign, offset).

        :raises ConfigError: on an invalid section.
        """
        c = XsensConfig.from_mapping(cfg)
        return cls(fd_or_port, c.joint_axis, c.sign, c.offset_rad, seed=seed, boot_baudrate=boot_baudrate)

    def line_matches(self) -> bool:
        """True if the host's line rate is the device's (always, without emulation)."""
        if self.baudrate is None:
            return True
        host = self._ep.line_baudrate()
        return host is None or host == self.baudrate

    def _send(self, data: bytes) -> None:
        """Write bytes as the host receives them: garbage at a mismatched line rate."""
        if not self.line_matches():
            # a UART sampling at the wrong rate sees framing errors: bytes, but no preamble
            data = bytes(b if b != 0xFA else 0x7A for b in self.rng.randbytes(len(data)))
            self.garbled_bytes += len(data)
        self._ep.write(data)

    @property
    def output_rate_hz(self) -> int:
        """Packet rate the configuration asks for [Hz] (the rig calls ``emit`` at it)."""
        rates = [f for _, f in self.output_config if f not in (0, FREQ_EVERY_PACKET)]
        return max(rates) if rates else BASE_RATE_HZ

    @property
    def dropped_bytes(self) -> int:
        """Bytes discarded because the reader did not keep up."""
        return self._ep.dropped_bytes

    def service(self) -> None:
        """Answer pending host commands; never blocks."""
        if self._wake_at_s is not None:
            if time.monotonic() < self._wake_at_s:
                self._ep.read_available()  # rebooting: nobody listens
                self._ep.flush()
                return
            self._wake_at_s = None
            self._reply(Mid.WAKE_UP)
        data = self._ep.read_available()
        if not data:
            self._ep.flush()
            return
        if not self.line_matches():
            self.garbled_bytes += len(data)  # the device's UART sees framing garbage
            self._parser.reset()
            return
        for mid, payload in self._parser.feed(data):
            self.host_mids.append(mid)
            self._handle(mid, payload)

    def _reply(self, mid: int, data: bytes = b"") -> None:
        self._send(build_message(mid, data))

    def _error(self, code: ErrorCode) -> None:
        self._reply(Mid.ERROR, bytes((int(code),)))

    def _handle(self, mid: int, payload: bytes) -> None:
        if mid == Mid.GO_TO_CONFIG:
            self.mode = SimMode.CONFIG
            self._reply(Mid.GO_TO_CONFIG_ACK)
        elif mid == Mid.GO_TO_MEASUREMENT:
            self.mode = SimMode.MEASUREMENT
            self._reply(Mid.GO_TO_MEASUREMENT_ACK)
        elif mid == Mid.REQ_DID:
            self._reply(Mid.DEVICE_ID, struct.pack(">I", self.device_id))
        elif mid == Mid.WAKE_UP_ACK:
            self.mode = SimMode.CONFIG
        elif mid == _SET_BAUDRATE and self.mode == SimMode.CONFIG:
            self._set_baudrate(payload)
        elif mid == _RESET:
            self._reply(_RESET + 1)
            self._ep.flush()
            self.resets += 1
            self.baudrate = self.stored_baudrate
            self.mode = SimMode.MEASUREMENT  # unless the host answers the WakeUp
            self._wake_at_s = time.monotonic() + REBOOT_S
        elif mid == Mid.SET_OUTPUT_CONFIGURATION and self.mode == SimMode.CONFIG and not payload:
            self._reply(Mid.OUTPUT_CONFIGURATION, encode_output_configuration(self.output_config))
        elif mid == Mid.SET_OUTPUT_CONFIGURATION and self.mode == SimMode.CONFIG:
            try:
                items = decode_output_configuration(payload)
            except ProtocolError:
                self._error(ErrorCode.INVALID_PARAM)
                return
            if not items or not all(self._supported(x, f) for x, f in items):
                self._error(ErrorCode.INVALID_PARAM)
                return
            accepted = [(x, FREQ_EVERY_PACKET if x & XDI_TYPE_MASK in (
                Xdi.PACKET_COUNTER, Xdi.SAMPLE_TIME_FINE, Xdi.STATUS_WORD) else f) for x, f in items]
            self.output_config = accepted
            self._reply(Mid.OUTPUT_CONFIGURATION, encode_output_configuration(accepted))
        else:
            self._error(ErrorCode.INVALID_MESSAGE)

    def _set_baudrate(self, payload: bytes) -> None:
        if not payload:  # ReqBaudrate
            rate = self.baudrate if self.baudrate is not None else 921600
            self._reply(_SET_BAUDRATE + 1, bytes((BAUD_CODES[rate],)))
            return
        rate = baudrate_of_code(payload[0]) if len(payload) == 1 else None
        if rate is None:
            self._error(ErrorCode.BAUDRATE_INVALID)
            return
        if self.baudrate is not None:
            self.stored_baudrate = rate  # effective after the next Reset
        self._reply(_SET_BAUDRATE + 1)

    @staticmethod
    def _supported(xdi: int, freq: int) -> bool:
        kind = xdi & XDI_TYPE_MASK
        if kind not in _SUPPORTED:
            return False
        if kind in (Xdi.PACKET_COUNTER, Xdi.SAMPLE_TIME_FINE, Xdi.STATUS_WORD):
            return xdi == kind
        if kind == Xdi.RATE_OF_TURN and xdi & 0x000C:
            return False
        if (xdi & 0x000C) == 0x000C:
            return False
        return freq in (0, FREQ_EVERY_PACKET) or (1 <= freq <= BASE_RATE_HZ and BASE_RATE_HZ % freq == 0)

    def build_packet(self, sample_time_s: float, q_out_rad: float, dq_out_rad_s: float) -> bytes:
        """The MTData2 message for one sample (advances the packet counter)."""
        twist = self.sign * (q_out_rad - self.offset_rad)
        a = int(self.axis)
        q = [math.cos(twist / 2), 0.0, 0.0, 0.0]
        q[1 + a] = math.sin(twist / 2)
        w = [0.0, 0.0, 0.0]
        w[a] = self.sign * dq_out_rad_s
        base = self.output_rate_hz
        items = []
        for xdi, freq in self.output_config:
            kind = xdi & XDI_TYPE_MASK
            if freq not in (0, FREQ_EVERY_PACKET) and self._n_emitted % max(1, base // freq):
                continue
            prec = xdi & PRECISION_MASK
            if kind == Xdi.PACKET_COUNTER:
                value = struct.pack(">H", self.packet_counter)
            elif kind == Xdi.SAMPLE_TIME_FINE:
                value = struct.pack(">I", round(sample_time_s * SAMPLE_TIME_FINE_HZ) & 0xFFFFFFFF)
            elif kind == Xdi.QUATERNION:
                value = encode_values(q, prec)
            elif kind == Xdi.EULER_ANGLES:
                value = encode_values(euler_deg_from_quaternion(tuple(q)), prec)
            elif kind == Xdi.RATE_OF_TURN:
                value = encode_values(w, prec)
            else:
                value = struct.pack(">I", self.status_word)
            items.append(build_mtdata2_item(xdi, value))
        self._n_emitted += 1
        self.packet_counter = (self.packet_counter + 1) & 0xFFFF
        return build_message(Mid.MT_DATA2, b"".join(items))

    def emit(self, sample_time_s: float, q_out_rad: float, dq_out_rad_s: float) -> bool:
        """Write one MTData2 packet if in measurement mode; True if a packet was written.

        :param sample_time_s: device sample time (SampleTimeFine = round(t * 10 kHz)) [s].
        :param q_out_rad: joint angle [rad].
        :param dq_out_rad_s: joint rate [rad/s].
        """
        if self.mode != SimMode.MEASUREMENT or self._wake_at_s is not None:
            self._ep.flush()
            return False
        fault = self._next_fault()
        if fault == SerialFault.DROP_COUNTER:
            self.packet_counter = (self.packet_counter + 1) & 0xFFFF
        frame = self.build_packet(sample_time_s, q_out_rad, dq_out_rad_s)
        self._send(self._damage(frame, fault))
        return True


class SimLoadCellAmp(FaultInjector):
    """A simulated 4-channel load-cell amplifier streaming binary frames.

    :param fd_or_port: pty master fd, device path or pyserial port.
    :param scale_N_per_mV_V: per-channel sensitivity the driver is configured with.
    :param offset_N: per-channel offset the driver is configured with [N].
    :param bias_mV_V: bridge zero error added to the signal (removed by a tare) [mV/V].
    :param seed: seed of the garbage generator.
    """

    def __init__(self, fd_or_port: int | str | Any,
                 scale_N_per_mV_V: tuple[float, ...] | list[float] = (250.0,) * N_CHANNELS,
                 offset_N: tuple[float, ...] | list[float] = (0.0,) * N_CHANNELS,
                 bias_mV_V: tuple[float, ...] | list[float] = (0.0,) * N_CHANNELS, seed: int = 0) -> None:
        super().__init__(seed)
        self._ep = DeviceEndpoint(fd_or_port)
        self.scale = tuple(float(s) for s in scale_N_per_mV_V)
        self.offset = tuple(float(o) for o in offset_N)
        self.bias = tuple(float(b) for b in bias_mV_V)

    @classmethod
    def from_config(cls, fd_or_port: int | str | Any, cfg: Mapping[str, Any],
                    bias_mV_V: tuple[float, ...] = (0.0,) * N_CHANNELS, seed: int = 0) -> SimLoadCellAmp:
        """Simulated amplifier inverse to the driver's ``load_cells`` config section.

        :raises ConfigError: on an invalid section.
        """
        c = LoadCellConfig.from_mapping(cfg)
        return cls(fd_or_port, c.scale_N_per_mV_V, c.offset_N, bias_mV_V, seed)

    @property
    def dropped_bytes(self) -> int:
        """Bytes discarded because the reader did not keep up."""
        return self._ep.dropped_bytes

    def service(self) -> None:
        """Discard host input (the amplifier takes no commands) and flush; never blocks."""
        self._ep.read_available()
        self._ep.flush()

    def raw_mV_V(self, tensions_N: Any) -> tuple[float, float, float, float]:
        """Bridge signals [mV/V] for tensions [N] (channel order of the frame)."""
        t = [float(x) for x in tensions_N]
        return tuple((t[k] - self.offset[k]) / self.scale[k] + self.bias[k]  # type: ignore[return-value]
                     for k in range(N_CHANNELS))

    def emit(self, tensions_N: Any) -> None:
        """Write one frame for the four tensions [N] (upper in, upper out, lower out, lower in)."""
        frame = build_frame(self.raw_mV_V(tensions_N))
        self._ep.write(self._damage(frame, self._next_fault()))
