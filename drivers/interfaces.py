"""Narrow per-role device interfaces used by the daemon.

Each role (motor, IMU, load cells) has one interface; a real backend speaks the wire
protocol to hardware, a simulated backend speaks the same protocol to a simulated
device. Backends are chosen by configuration (see ``drivers.registry`` if present).

Real-time contract: ``start()``/``stop()`` may block (SDO, configuration handshakes);
everything called per cycle (``poll``, ``write_torque``, ``send_cycle``) must not block,
allocate little and never sleep.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable


@dataclass
class LinkStats:
    """Health counters of one device link.

    :ivar good_frames: frames/messages decoded successfully.
    :ivar bad_frames: frames rejected (checksum, length, malformed).
    :ivar counter_gaps: missing samples detected from a sample counter.
    :ivar resyncs: times the parser had to hunt for a frame start.
    :ivar bytes_skipped: bytes that belonged to no accepted frame (garbage, rejected
        candidates, bytes dropped by a parser reset).
    """

    good_frames: int = 0
    bad_frames: int = 0
    counter_gaps: int = 0
    resyncs: int = 0
    bytes_skipped: int = 0


@dataclass
class MotorReading:
    """Latest drive feedback (from TPDOs), SI units at the motor shaft.

    :ivar t_s: host monotonic time the reading arrived [s].
    :ivar position_rad: motor position (after encoder/gear scaling) [rad].
    :ivar velocity_rad_s: motor velocity [rad/s].
    :ivar torque_Nm: actual torque (0x6077 scaled by rated torque) [Nm].
    :ivar statusword: raw CiA 402 statusword (0x6041).
    :ivar mode: mode of operation display (0x6061).
    :ivar t_ns: ``t_s`` as integer monotonic-clock nanoseconds (``t_s = t_ns * 1e-9``) [ns].
    :ivar position_counts: position as the drive sent it (0x6064) [counts].
    :ivar velocity_units: velocity as the drive sent it (0x606C) [drive units].
    :ivar torque_permille: torque as the drive sent it (0x6077) [per mille of rated].
    """

    t_s: float = 0.0
    position_rad: float = 0.0
    velocity_rad_s: float = 0.0
    torque_Nm: float = 0.0
    statusword: int = 0
    mode: int = 0
    t_ns: int = 0
    position_counts: int = 0
    velocity_units: int = 0
    torque_permille: int = 0


@dataclass
class ImuSample:
    """One IMU sample mapped onto the joint.

    :ivar t_s: host monotonic receive time [s].
    :ivar q_out_rad: joint angle from orientation about the configured axis [rad].
    :ivar dq_out_rad_s: joint rate from the rate of turn [rad/s].
    :ivar counter: device packet counter (wraps at 65536), -1 if absent.
    :ivar t_ns: ``t_s`` as integer monotonic-clock nanoseconds [ns].
    :ivar rate_rad_s: rate of turn about the joint axis as the sensor sent it, before
        the sign (``dq_out_rad_s = sign * rate_rad_s``) [rad/s].
    """

    t_s: float = 0.0
    q_out_rad: float = 0.0
    dq_out_rad_s: float = 0.0
    counter: int = -1
    t_ns: int = 0
    rate_rad_s: float = 0.0


@dataclass
class LoadCellSample:
    """One load-cell frame, four tensions after scale/offset/tare.

    :ivar t_s: host monotonic receive time [s].
    :ivar tensions_N: (upper input-side, upper output-side, lower output-side,
        lower input-side) cable tensions [N].
    :ivar t_ns: ``t_s`` as integer monotonic-clock nanoseconds [ns].
    :ivar raw_mV_V: the four bridge signals as the amplifier sent them (float32 values) [mV/V].
    """

    t_s: float = 0.0
    tensions_N: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    t_ns: int = 0
    raw_mV_V: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


@runtime_checkable
class Motor(Protocol):
    """A torque-controlled motor behind a CiA 402 drive."""

    def start(self) -> None:
        """Configure (SDO), start NMT, bring the drive to OPERATION ENABLED in torque mode.

        :raises DriverError: (or a subclass) if any step fails or times out.
        """

    def write_torque(self, torque_Nm: float) -> None:
        """Stage the target torque for the next cycle (no bus traffic)."""

    def send_cycle(self) -> None:
        """Send the staged RPDO, then SYNC. Called once per control cycle."""

    def poll(self) -> MotorReading | None:
        """Drain received frames without blocking; the newest reading, or None if none new.

        :raises DriveFaultError: on EMCY or a fault in the statusword.
        :raises HeartbeatLostError: when the drive heartbeat is missing for 3 periods.
        """

    def disable(self) -> None:
        """Zero torque and leave OPERATION ENABLED (best effort, bounded time)."""

    def quick_stop(self) -> None:
        """Command QUICK STOP ACTIVE."""

    def fault_reset(self) -> None:
        """Reset a drive fault with a rising edge of controlword bit 7."""

    def close(self) -> None:
        """Release the bus."""


@runtime_checkable
class Imu(Protocol):
    """A joint IMU (Xsens MTi over serial)."""

    stats: LinkStats

    def start(self) -> None:
        """Configure the device (output configuration, measurement mode).

        :raises DriverError: if the device does not acknowledge in time.
        """

    def poll(self) -> ImuSample | None:
        """Read available bytes without blocking; the newest sample, or None."""

    def close(self) -> None:
        """Close the port."""


@runtime_checkable
class LoadCells(Protocol):
    """The four-channel load-cell amplifier."""

    stats: LinkStats

    def start(self) -> None:
        """Open the stream (and tare if configured)."""

    def poll(self) -> LoadCellSample | None:
        """Read available bytes without blocking; the newest sample, or None."""

    def close(self) -> None:
        """Close the port."""


@dataclass
class DeviceSet:
    """The three device roles the daemon drives."""

    motor: Motor
    imu: Imu
    load_cells: LoadCells
    extra: dict[str, object] = field(default_factory=dict)
