"""What the torque loop's stability check assumes and requires: the ``controller.stability``
section (documented in ``config/controller.yaml``; used by :mod:`capstan.controller.law.stability`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from capstan.models.common.config_tools import get_float, reject_unknown
from capstan.models.common.errors import ConfigError


@dataclass(frozen=True)
class StabilitySettings:
    """What the loop check assumes and requires (``controller.stability``, SI)."""

    io_delay_cycles: int = 2
    stiffness_range_Nm_rad: tuple[float, float] = (200.0, 300.0)
    inertia_tolerance: float = 0.3
    link_inertia_kg_m2: float = 0.17
    link_damping_Nms_rad: float = 0.02
    link_stiffness_Nm_rad: float = 3.78
    stick_stiffness_factor: float = 11.0
    min_phase_margin_deg: float = 45.0
    min_gain_margin_dB: float = 6.0
    tension_noise_N: float = 0.3
    gyro_noise_rad_s: float = 0.002
    #: how far the gravity model's m g l may be off the link's [fraction]: in slip the daemon's
    #: gravity model (a positive feedback of the link angle) cancels the link's gravity stiffness
    #: ``link_stiffness_Nm_rad`` up to this residual, which is what the slip points keep
    gravity_model_error: float = 0.25
    #: a hand holding the link (slip points with its stiffness [Nm/rad] and damping [Nm s/rad] on the link):
    #: the output torque gain feeds the hand's torque back, so a firm grip closes a loop through it that the
    #: free link does not have; checked at the K_c / J_m corners against ``min_grip_phase_margin_deg``
    #: (the grip's own damping is light, so less than the free loop's requirement). Empty: not checked
    grip_stiffness_Nm_rad: tuple[float, ...] = (60.0, 300.0, 1000.0)
    grip_damping_Nms_rad: float = 3.0
    min_grip_phase_margin_deg: float = 30.0
    #: the motor encoder's counts per revolution: its quantisation (uniform over a count) is the position noise the
    #: motor velocity observer turns into command noise (``encoder_to_cmd_std_Nm``); 0 = not counted
    encoder_counts_per_rev: int = 1 << 17


def stability_from_mapping(c: Mapping[str, Any], p: str) -> StabilitySettings:
    """Parse ``controller.stability``.

    :raises ConfigError: naming the key.
    """
    d = StabilitySettings()
    reject_unknown(c, set(StabilitySettings.__dataclass_fields__), p)
    delay = c.get("io_delay_cycles", d.io_delay_cycles)
    if isinstance(delay, bool) or not isinstance(delay, int) or not 0 <= delay <= 20:
        raise ConfigError(f"{p}.io_delay_cycles", f"must be an integer in [0, 20], got {delay!r}")
    rng = c.get("stiffness_range_Nm_rad", list(d.stiffness_range_Nm_rad))
    if (not isinstance(rng, (list, tuple)) or len(rng) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in rng)
            or not 0.0 < rng[0] <= rng[1]):
        raise ConfigError(f"{p}.stiffness_range_Nm_rad", f"must be [low, high] with 0 < low <= high, got {rng!r}")

    grip = c.get("grip_stiffness_Nm_rad", list(d.grip_stiffness_Nm_rad))
    if (not isinstance(grip, (list, tuple)) or len(grip) > 10
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and 0.0 < x <= 1e5
                       for x in grip)):
        raise ConfigError(f"{p}.grip_stiffness_Nm_rad", f"must be a list of up to 10 stiffnesses in (0, 1e5] Nm/rad "
                          f"(empty: no grip check), got {grip!r}")
    grip = tuple(float(x) for x in grip)
    counts = c.get("encoder_counts_per_rev", d.encoder_counts_per_rev)
    if isinstance(counts, bool) or not isinstance(counts, int) or not 0 <= counts <= 1 << 31:
        raise ConfigError(f"{p}.encoder_counts_per_rev", f"must be an integer in [0, 2^31], got {counts!r}")

    def pos(key: str, hi: float) -> float:
        return get_float(c, key, p, getattr(d, key), min_value=0.0, max_value=hi)

    return StabilitySettings(
        delay, (float(rng[0]), float(rng[1])),
        get_float(c, "inertia_tolerance", p, d.inertia_tolerance, min_value=0.0, max_value=0.9),
        get_float(c, "link_inertia_kg_m2", p, d.link_inertia_kg_m2, min_value=0.0, min_exclusive=True),
        pos("link_damping_Nms_rad", 1e3), pos("link_stiffness_Nm_rad", 1e4),
        get_float(c, "stick_stiffness_factor", p, d.stick_stiffness_factor, min_value=1.0, max_value=1000.0),
        get_float(c, "min_phase_margin_deg", p, d.min_phase_margin_deg, min_value=0.0, max_value=90.0),
        get_float(c, "min_gain_margin_dB", p, d.min_gain_margin_dB, min_value=0.0, max_value=40.0),
        pos("tension_noise_N", 100.0), pos("gyro_noise_rad_s", 1.0), pos("gravity_model_error", 1.0),
        grip, pos("grip_damping_Nms_rad", 1e3),
        get_float(c, "min_grip_phase_margin_deg", p, d.min_grip_phase_margin_deg, min_value=0.0, max_value=90.0),
        counts)
