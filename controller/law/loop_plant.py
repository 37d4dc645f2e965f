"""The linearised plant of the torque loop's analysis (:mod:`capstan.controller.law.loop_model`): the
grid points and their transfer functions and state space (SI, torques at the motor side, ``r_in = r_out``).

* ``stick`` — the transmission friction holds the output: ``P = K/(J s^2 + B s + K)``;
* ``slip``  — friction constant (no incremental effect), the link free (or held by a hand: its stiffness and
  damping on the link): ``P = K M_l / (M_m M_l + K (M_m + M_l))`` with ``M_m = J_m s^2 + B_m s`` and
  ``M_l = J_l s^2 + b_l s + k_g``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import signal

TF = tuple[np.ndarray, np.ndarray]


@dataclass(frozen=True)
class PlantPoint:
    """One linearisation of the plant (SI): motor side and, for slip, the link.

    :ivar stiffness_Nm_rad: transmission stiffness K_c [Nm/rad].
    :ivar motor_inertia_kg_m2: J_m [kg m^2]; ``motor_damping_Nms_rad``: B_m [Nm s/rad].
    :ivar slip: False = stick (output held by friction), True = slip (link free).
    :ivar link_inertia_kg_m2, link_damping_Nms_rad, link_stiffness_Nm_rad: the link in slip.
    """

    stiffness_Nm_rad: float
    motor_inertia_kg_m2: float
    motor_damping_Nms_rad: float
    slip: bool = False
    link_inertia_kg_m2: float = 0.17
    link_damping_Nms_rad: float = 0.02
    link_stiffness_Nm_rad: float = 3.78


def plant_continuous(p: PlantPoint) -> TF:
    """``P(s)`` (descending powers of s): applied motor torque -> tau_in."""
    K, mm = p.stiffness_Nm_rad, np.array([p.motor_inertia_kg_m2, p.motor_damping_Nms_rad, 0.0])
    if not p.slip:
        return np.array([K]), np.polyadd(mm, [K])
    ml = np.array([p.link_inertia_kg_m2, p.link_damping_Nms_rad, p.link_stiffness_Nm_rad])
    return K * ml, np.polyadd(np.polymul(mm, ml), K * np.polyadd(mm, ml))


def plant_velocity_continuous(p: PlantPoint) -> TF:
    """``P_v(s)`` (descending powers of s): applied motor torque -> motor velocity dq_m."""
    K, mm = p.stiffness_Nm_rad, np.array([p.motor_inertia_kg_m2, p.motor_damping_Nms_rad, 0.0])
    if not p.slip:
        return np.array([1.0, 0.0]), np.polyadd(mm, [K])
    ml = np.array([p.link_inertia_kg_m2, p.link_damping_Nms_rad, p.link_stiffness_Nm_rad])
    return np.polymul([1.0, 0.0], np.polyadd(ml, [K])), np.polyadd(np.polymul(mm, ml), K * np.polyadd(mm, ml))


def plant_position_continuous(p: PlantPoint) -> TF:
    """``P_q(s)``: applied motor torque -> motor position q_m (:func:`plant_velocity_continuous` / s)."""
    num, den = plant_velocity_continuous(p)
    return num[:-1], den       # the velocity's numerator ends in the factor s


def plant_link_velocity_continuous(p: PlantPoint) -> TF:
    """``P_o(s)``: applied motor torque -> link velocity dq_out (0 when the output sticks)."""
    if not p.slip:
        return np.array([0.0]), np.array([1.0])
    K, mm = p.stiffness_Nm_rad, np.array([p.motor_inertia_kg_m2, p.motor_damping_Nms_rad, 0.0])
    ml = np.array([p.link_inertia_kg_m2, p.link_damping_Nms_rad, p.link_stiffness_Nm_rad])
    return np.array([K, 0.0]), np.polyadd(np.polymul(mm, ml), K * np.polyadd(mm, ml))


def plant_discrete(p: PlantPoint, dt_s: float, delay_cycles: int, plant: TF | None = None) -> TF:
    """``z^-d Pd(z)`` in ascending powers of z^-1 (zero-order hold, scipy ``cont2discrete``)
    of ``plant`` (descending powers of s; default :func:`plant_continuous`)."""
    with warnings.catch_warnings():     # ZOH of a velocity leaves a ~1e-20 leading numerator term
        warnings.simplefilter("ignore", signal.BadCoefficients)
        num, den, _ = signal.cont2discrete(plant_continuous(p) if plant is None else plant, dt_s, method="zoh")
    num = np.trim_zeros(np.atleast_2d(num)[0], "f") if np.any(num) else np.zeros(1)
    den = np.atleast_1d(den)
    # descending powers of z -> ascending z^-1 with the relative degree as leading zeros
    rel = len(den) - len(num)
    num = np.concatenate((np.zeros(rel + delay_cycles), num))
    return num, den


def plant_state_space(p: PlantPoint, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Physical states (q_m, dq_m[, q_o, dq_o]) discretised with a zero-order hold:
    ``(A, B, C)`` with ``x' = A x + B u``, ``tau_in = C x``."""
    K, J, B = p.stiffness_Nm_rad, p.motor_inertia_kg_m2, p.motor_damping_Nms_rad
    if not p.slip:
        a = np.array([[0.0, 1.0], [-K / J, -B / J]])
        b = np.array([[0.0], [1.0 / J]])
        c = np.array([[K, 0.0]])
    else:
        Jl, bl, kg = p.link_inertia_kg_m2, p.link_damping_Nms_rad, p.link_stiffness_Nm_rad
        a = np.array([[0.0, 1.0, 0.0, 0.0], [-K / J, -B / J, K / J, 0.0],
                      [0.0, 0.0, 0.0, 1.0], [K / Jl, 0.0, -(K + kg) / Jl, -bl / Jl]])
        b = np.array([[0.0], [1.0 / J], [0.0], [0.0]])
        c = np.array([[K, 0.0, -K, 0.0]])
    ad, bd, cd, _, _ = signal.cont2discrete((a, b, c, np.zeros((1, 1))), dt_s, method="zoh")
    return ad, bd[:, 0], cd[0]
