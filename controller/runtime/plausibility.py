"""Plausible ranges of the safety-relevant configuration keys, and the explicit lab override.

Type and hard validity (a number, finite, positive, clamp below its fault limit) are
checked where each section is parsed. This module adds what a typo must not switch off:
a timeout of ``1e9`` s disables stale-sensor detection, a ramp of ``1e9`` s makes SIGTERM
never finish, ``kp: 1e9`` or ``max_torque_Nm: 1e9`` start a loop nobody analysed. Each
key has a range a rig engineer would call plausible for this joint (motor rated 20 Nm,
1 kHz loop, sensors at 1 kHz / 400 Hz); a value outside is refused with the key, the
value and the range, unless the config says otherwise explicitly::

    lab_override:
      reason: "bench test of the staleness logic with a slowed IMU"   # required
      ranges: true       # accept values outside the plausible ranges below
      margins: true      # start gains that miss the loop's stability margins

The section is part of the config every log stores (the ``capstan.config`` metadata
record), and the daemon logs a warning naming each overridden key at start-up.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from capstan.models.common.config_tools import get_bool, reject_unknown
from capstan.models.common.errors import ConfigError

#: dotted key -> (low, high, why); both bounds inclusive, SI units as in the key name
PLAUSIBLE_RANGES: dict[str, tuple[float, float, str]] = {
    "controller.safety.imu_timeout_s": (0.003, 0.1, "the IMU sends at 400 Hz; beyond 0.1 s a lost IMU goes unnoticed"),
    "controller.safety.loadcell_timeout_s": (0.002, 0.1, "load cells send at 1 kHz"),
    "controller.safety.motor_timeout_s": (0.002, 0.1, "the drive answers every SYNC"),
    "controller.safety.tau_max_Nm": (0.1, 40.0, "command clamp; the drive is rated 20 Nm"),
    "controller.safety.dtau_max_Nm_s": (10.0, 20000.0, "command rate clamp"),
    "controller.safety.tau_fault_Nm": (0.1, 200.0, "hard torque fault limit"),
    "controller.safety.dtau_fault_Nm_s": (10.0, 500000.0, "hard torque-step fault limit"),
    "controller.feedback.kp": (0.0, 50.0, "proportional gain [Nm/Nm]"),
    "controller.feedback.kd_s": (0.0, 1.0, "derivative gain [s]"),
    "controller.feedback.ki_1_s": (0.0, 1000.0, "integral gain [1/s]"),
    "controller.feedback.integral_limit_Nm": (0.0, 40.0, "anti-windup clamp"),
    "controller.feedforward.gain": (0.0, 1.5, "fraction of the model friction"),
    "motor.max_torque_Nm": (0.1, 40.0, "driver-side clamp; the drive is rated 20 Nm"),
    "motor.consumer_timeout_s": (0.005, 1.0, "the drive stops this long after the daemon's heartbeat ends"),
    "motor.heartbeat_period_s": (0.001, 0.5, "daemon heartbeat"),
    "motor.drive_heartbeat_period_s": (0.001, 0.5, "drive heartbeat"),
    "loop.ramp_down_s": (0.0, 5.0, "torque ramp to zero on SIGTERM; a stop must finish"),
    "loop.startup_timeout_s": (0.1, 60.0, "time for the devices to deliver after enable"),
    "loop.sensor_fresh_s": (0.001, 0.5, "freshness required before READY"),
    "loop.overrun_streak_fault": (1.0, 1000.0, "consecutive late cycles before a fault"),
    "loop.limits.dq_out_max_rad_s": (0.01, 50.0, "joint rate limit"),
    "loop.limits.dq_m_max_rad_s": (0.01, 200.0, "motor velocity limit"),
    "loop.limits.tension_max_N": (1.0, 3000.0, "cable tension limit"),
}


@dataclass(frozen=True)
class LabOverride:
    """The explicit ``lab_override`` section (absent: nothing overridden)."""

    reason: str = ""
    ranges: bool = False
    margins: bool = False

    @property
    def active(self) -> bool:
        return self.ranges or self.margins


def lab_override_from_mapping(c: Mapping[str, Any]) -> LabOverride:
    """Parse ``lab_override``.

    :raises ConfigError: on unknown keys, non-boolean flags, or a flag without a reason.
    """
    p = "lab_override"
    reject_unknown(c, {"reason", "ranges", "margins"}, p)
    ov = LabOverride(str(c.get("reason") or "").strip(), get_bool(c, "ranges", p, False),
                     get_bool(c, "margins", p, False))
    if ov.active and not ov.reason:
        raise ConfigError(f"{p}.reason", "required when anything is overridden: say why, it is stored in the log")
    return ov


def _lookup(cfg: Mapping[str, Any], dotted: str) -> Any:
    node: Any = cfg
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return None
        node = node[part]
    return node


def check_plausible(cfg: Mapping[str, Any], override: LabOverride = LabOverride()) -> list[str]:
    """Check every key of :data:`PLAUSIBLE_RANGES` present in ``cfg`` (absent keys take
    their defaults, which are inside).

    :returns: one line per overridden key (empty when all are plausible).
    :raises ConfigError: naming the first implausible key, unless ``override.ranges``.
    """
    out = []
    for key, (lo, hi, why) in PLAUSIBLE_RANGES.items():
        v = _lookup(cfg, key)
        if v is None or isinstance(v, bool) or not isinstance(v, (int, float)):
            continue    # absent, or a type error the section's parser reports
        if not lo <= float(v) <= hi:
            text = f"{v!r} is outside the plausible range [{lo:g}, {hi:g}] ({why})"
            if not override.ranges:
                raise ConfigError(key, text + "; set lab_override: {ranges: true, reason: ...} to run it anyway")
            out.append(f"{key}: {text}")
    return out
