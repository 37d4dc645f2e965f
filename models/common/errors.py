"""The one exception hierarchy of capstan.

Every error raised on purpose by capstan code derives from :class:`CapstanError`::

    CapstanError
     +-- ConfigError            a configuration key is missing or invalid (key + reason)
     |    +-- ConfigFileError       a configuration file is missing, unreadable or not YAML
     +-- DataFormatError        a measurement table, import description or log is unreadable
     +-- ModelError             a model cannot be built or evaluated
     |    +-- OperatingRangeError   a scenario leaves the model's range (e.g. cable slack)
     |    +-- IntegrationError      the integrator failed to converge
     +-- DriverError            a device driver failed
     |    +-- ProtocolError         malformed bytes / unexpected reply on a wire protocol
     |    +-- DeviceTimeoutError    a device did not answer or went stale in time
     |    |    +-- DeviceLostError  a device is gone (no heartbeat, process dead)
     |    +-- DriveFaultError       the CiA 402 drive reports a fault (EMCY, statusword)
     |    +-- HeartbeatLostError    a CANopen heartbeat was not seen for too long
     |    +-- StateTransitionError  a DS402 transition did not complete in its timeout
     +-- ControlFaultError      the control loop latched a fault (carries the last N cycles)
     +-- RealtimeError          real-time scheduling was required but is not available
     +-- UsageError             a command-line argument is invalid (the parser cannot tell)

Library code raises these; only the command line turns them into exit codes.
"""

from __future__ import annotations

from typing import Any


class CapstanError(Exception):
    """Base class of every error capstan raises on purpose."""


class ConfigError(CapstanError):
    """A configuration value is missing or invalid.

    :param key: dotted path of the offending key, e.g. ``"controller.ldo.cutoff_hz"``.
    :param reason: human-readable reason, e.g. ``"must be > 0, got -3"``.
    """

    def __init__(self, key: str, reason: str) -> None:
        self.key = key
        self.reason = reason
        super().__init__(f"config key '{key}': {reason}")


class ConfigFileError(ConfigError):
    """A configuration file cannot be used as a whole (missing, unreadable, not a YAML mapping,
    not shipped).

    :param path: the file as the user named it.
    :param reason: human-readable reason.
    """

    def __init__(self, path: str, reason: str) -> None:
        self.key = path
        self.reason = reason
        CapstanError.__init__(self, f"config file '{path}': {reason}")


class DataFormatError(CapstanError):
    """Input data (measurement table, sidecar, import description, log) is malformed."""


class ModelError(CapstanError):
    """A model cannot be built or evaluated with the given parameters."""


class OperatingRangeError(ModelError):
    """The simulated scenario left the model's valid operating range (e.g. cable slack)."""


class IntegrationError(ModelError):
    """The numerical integrator failed (no Newton convergence, step size underflow)."""


class DriverError(CapstanError):
    """A device driver failed."""


class ProtocolError(DriverError):
    """Unexpected or malformed bytes on a wire protocol (CANopen, Xsens MT, load cells)."""


class DeviceTimeoutError(DriverError):
    """A device did not answer, or its data went stale, within the allowed time."""


class DeviceLostError(DeviceTimeoutError):
    """A device is gone: no heartbeat and no answer for longer than its timeout (killed, unplugged)."""


class DriveFaultError(DriverError):
    """The CiA 402 drive reports a fault (statusword fault bit or EMCY)."""


class HeartbeatLostError(DriverError):
    """A CANopen heartbeat was not received within its allowed period."""


class StateTransitionError(DriverError):
    """A DS402 state-machine transition did not complete within its timeout."""


class ControlFaultError(CapstanError):
    """The control loop latched a fault; ``last_cycles`` holds the last N records.

    :param reason: readable description of the fault.
    :param last_cycles: structured numpy array of the last N cycle records, or None.
    :param bits: the latched fault bits (``FaultBits`` of the controller records; 0 if unknown).
    """

    def __init__(self, reason: str, last_cycles: Any = None, bits: int = 0) -> None:
        self.reason = reason
        self.last_cycles = last_cycles
        self.bits = int(bits)
        super().__init__(reason)


class RealtimeError(CapstanError):
    """Real-time scheduling (SCHED_FIFO, mlockall, affinity) was enforced but is unavailable."""


class UsageError(CapstanError):
    """A command-line argument is invalid in a way the argument parser cannot check
    (``--duration-s 0``); the command line reports it like a config error, exit code 2."""
