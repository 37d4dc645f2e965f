"""The instrumented link of the interaction use case (paper §4.5): a rigid bar with a
tip mass on the output pulley, gravity acting.

Angle convention shared by the plant and the controller's gravity model:
``q_out_rad = 0`` is the link hanging straight down; positive ``q_out_rad`` is the
same direction as positive output torque. Gravity then acts on the link with
``tau_grav_Nm = -m_g_l_Nm * sin(q_out_rad)``; holding the link still needs
``+m_g_l_Nm * sin(q_out_rad)`` from the transmission (the gravity model tau_g).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from numba import njit

from capstan.models.common.config_tools import get_float, reject_unknown

G_M_S2 = 9.81


@dataclass(frozen=True)
class LinkParams:
    """Link about the joint axis.

    :ivar inertia_kg_m2: moment of inertia about the joint [kg m^2].
    :ivar m_g_l_Nm: mass x g x centre-of-mass distance [Nm] (peak gravity torque).
    :ivar damping_Nms_rad: viscous damping of the joint bearing [Nm s/rad].
    """

    inertia_kg_m2: float = 0.17
    m_g_l_Nm: float = 3.78
    damping_Nms_rad: float = 0.02

    @staticmethod
    def bar_with_tip_mass(length_m: float = 0.5, bar_mass_kg: float = 0.54,
                          tip_mass_kg: float = 0.5, damping_Nms_rad: float = 0.02) -> "LinkParams":
        """Uniform bar pivoted at one end with a point tip mass (paper: 500x20x20 mm Al, 0.5 kg)."""
        inertia = bar_mass_kg * length_m**2 / 3.0 + tip_mass_kg * length_m**2
        mgl = G_M_S2 * (bar_mass_kg * length_m / 2.0 + tip_mass_kg * length_m)
        return LinkParams(inertia, mgl, damping_Nms_rad)

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str = "link") -> "LinkParams":
        """Build from ``{inertia_kg_m2, m_g_l_Nm, damping_Nms_rad}``.

        :raises ConfigError: on unknown keys or invalid values.
        """
        reject_unknown(cfg, {"inertia_kg_m2", "m_g_l_Nm", "damping_Nms_rad"}, prefix)
        d = LinkParams()
        return LinkParams(
            get_float(cfg, "inertia_kg_m2", prefix, d.inertia_kg_m2, min_value=0.0, min_exclusive=True),
            get_float(cfg, "m_g_l_Nm", prefix, d.m_g_l_Nm, min_value=0.0),
            get_float(cfg, "damping_Nms_rad", prefix, d.damping_Nms_rad, min_value=0.0),
        )


@njit(cache=True)
def gravity_torque_Nm(m_g_l_Nm: float, q_out_rad: float) -> float:
    """Torque gravity exerts on the link [Nm] at angle ``q_out_rad`` (0 = hanging down)."""
    return -m_g_l_Nm * math.sin(q_out_rad)


@njit(cache=True)
def gravity_hold_torque_Nm(m_g_l_Nm: float, q_out_rad: float) -> float:
    """Output torque that holds the link still against gravity [Nm] (the model tau_g)."""
    return m_g_l_Nm * math.sin(q_out_rad)
