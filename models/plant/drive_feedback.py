"""What the drive reports of the motor: position actual value (0x6064) and velocity actual
value (0x606C), formed from the encoder as a drive forms them.

The shipped drive is a Nanotec C5-E (EDS ``nanotec_C5-E-2-09.eds``, also ``tests/data/``).
What its documents say, and what they do not:

* **Unit of 0x606C.** The EDS gives ``60A9h SI unit velocity`` the default ``0x00B44700``:
  CiA 402 SI-unit coding, byte 3 = prefix 0x00 (10^0), byte 2 = 0xB4 (revolution),
  byte 1 = 0x47 (minute): **1 rpm** per unit. Nanotec's manuals describe the same default
  ("speed ... in revolutions per minute"; e.g. the PD4-C manual FIR-v1626, object 604Ch
  ``Vl Dimension Factor`` 1/60 giving rpm). So the default 0x606C is an integer in whole rpm:
  one unit is 2π/60 = 0.105 rad/s, i.e. 10 Nm of command through a 100 Nm s/rad damping.
  A finer unit is chosen by writing the prefix (e.g. 0xFD = 10^-3 rpm): ``velocity_unit_rpm``.
* **How the value is formed.** The velocity is derived from the position sensor (CiA 402:
  "derived either from the velocity sensor or the position sensor"; the EDS lists
  ``6090h Velocity encoder resolution`` and ``3203h Feedback selection`` — one encoder
  feeds both). The C5-E EDS (FIR of this file) has **no velocity-actual filter object** in
  0x2000–0x3FFF (its vendor objects near the control loops are 3203h Feedback selection,
  3204h Feedback mapping, 3210h Motor drive parameter set — loop gains and feed-forward
  factors —, 3212h Motor drive flags and 321Ah–321Dh controller parameters) — checked by
  name in the EDS. The Nanotec manual text on
  how 606Ch is sampled was not found in the reference corpus (only the C5-E manual V1.3.1
  table of contents and other Nanotec manuals' object pages). The ``vendor`` model therefore
  takes what is documented plus the plainest reading of the rest, stated here as assumptions:
  the difference of the encoder count over each 1 ms drive cycle (the SYNC period),
  optionally low-passed (``velocity_filter_hz``, default 0 = none, as no filter object
  exists), rounded to the unit of 0x60A9 (whole rpm by default).

Variants (``sensors.drive.velocity``):

* ``vendor`` — the above (the realistic default);
* ``encoder_difference`` — 1 ms differences of the encoder (2^17 counts/rev: one count per ms
  is 0.048 rad/s), no unit rounding (a drive set to increments/s);
* ``whole_rpm`` — the true velocity rounded to whole rpm (a drive with a perfect internal
  estimate, reported in the default unit);
* ``exact`` — the true velocity (the ideal device; what the simulation used to report).

The position is quantised to encoder counts in all variants (``noise.encoder_counts_per_rev``).
Positions and velocities are of the rig's input (motor) shaft [rad, rad/s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import Any, Mapping

from capstan.models.common.config_tools import get_choice, get_float, reject_unknown

RAD_S_PER_RPM = 2.0 * math.pi / 60.0


class VelocitySource(Enum):
    """How the reported velocity (0x606C) is formed."""

    VENDOR = "vendor"
    ENCODER_DIFFERENCE = "encoder_difference"
    WHOLE_RPM = "whole_rpm"
    EXACT = "exact"


@dataclass(frozen=True)
class DriveFeedbackSettings:
    """The drive's feedback model.

    :ivar velocity: how 0x606C is formed.
    :ivar velocity_unit_rpm: the unit of 0x606C per 0x60A9 [rpm] (``vendor`` only; 1.0 = EDS default).
    :ivar velocity_filter_hz: first-order low-pass on the difference [Hz] (``vendor`` only; 0 = none).
    """

    velocity: VelocitySource = VelocitySource.VENDOR
    velocity_unit_rpm: float = 1.0
    velocity_filter_hz: float = 0.0

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str, default: "DriveFeedbackSettings") -> "DriveFeedbackSettings":
        """Parse a ``drive`` section; absent keys keep ``default``'s values.

        :raises ConfigError: on unknown keys or bad values.
        """
        reject_unknown(cfg, {"velocity", "velocity_unit_rpm", "velocity_filter_hz"}, prefix)
        v = get_choice(cfg, "velocity", tuple(s.value for s in VelocitySource), prefix, default.velocity.value)
        return DriveFeedbackSettings(
            VelocitySource(v),
            get_float(cfg, "velocity_unit_rpm", prefix, default.velocity_unit_rpm, min_value=0.0, min_exclusive=True,
                      max_value=100.0),
            get_float(cfg, "velocity_filter_hz", prefix, default.velocity_filter_hz, min_value=0.0, max_value=500.0),
        )


class DriveFeedback:
    """Forms the drive's position and velocity from the true motor state, one drive cycle at a time.

    :param settings: the model.
    :param counts_per_rev: encoder resolution (0: no position quantisation; then the
        ``encoder_difference`` and ``vendor`` velocities difference the exact position).
    """

    def __init__(self, settings: DriveFeedbackSettings, counts_per_rev: int) -> None:
        self.settings = settings
        self.counts_per_rev = int(counts_per_rev)
        self.position_rad = 0.0
        self.velocity_rad_s = 0.0
        self._filtered_rad_s = 0.0

    def quantise_rad(self, q_rad: float) -> float:
        """The position as the encoder reports it [rad] (nearest count)."""
        cpr = self.counts_per_rev
        if cpr <= 0:
            return float(q_rad)
        return round(q_rad * cpr / (2.0 * math.pi)) * 2.0 * math.pi / cpr

    def reset(self, q_rad: float, dq_rad_s: float) -> None:
        """Start at the true state (the drive at rest, or just powered)."""
        self.position_rad = self.quantise_rad(q_rad)
        self._filtered_rad_s = 0.0
        self.velocity_rad_s = self._report(float(dq_rad_s), 0.0, 1e-3)

    def update(self, q_rad: float, dq_rad_s: float, dt_s: float) -> None:
        """One drive cycle of ``dt_s`` ended at the true state ``(q_rad, dq_rad_s)``."""
        q_prev = self.position_rad
        self.position_rad = self.quantise_rad(q_rad)
        diff = (self.position_rad - q_prev) / dt_s if dt_s > 0.0 else 0.0
        self.velocity_rad_s = self._report(float(dq_rad_s), diff, dt_s)

    def _report(self, dq_true: float, diff: float, dt_s: float) -> float:
        s = self.settings
        src = s.velocity
        if src == VelocitySource.EXACT:
            return dq_true
        if src == VelocitySource.WHOLE_RPM:
            return round(dq_true / RAD_S_PER_RPM) * RAD_S_PER_RPM
        if src == VelocitySource.ENCODER_DIFFERENCE:
            return diff
        if s.velocity_filter_hz > 0.0:
            a = math.exp(-2.0 * math.pi * s.velocity_filter_hz * dt_s)
            self._filtered_rad_s = a * self._filtered_rad_s + (1.0 - a) * diff
            v = self._filtered_rad_s
        else:
            v = diff
        unit = s.velocity_unit_rpm * RAD_S_PER_RPM
        return round(v / unit) * unit
