"""The torsional unit of :mod:`capstan.models.transmission.stick_slip` with strain-hardening
elastic paths: the cable stiffening with strain, at the one-node level.

Each elastic path ``j`` of the unit (the input half of the cable, and in the two-angle form
the output half) pulls the node ``x`` with

    ``tau_j = K_j e_j (1 + c_node e_j^2)``,   ``e_j = A_j(t) - x``  [rad]

where ``A_j`` is the path's anchor (``q_in``; ``rho q_out``) and ``c_node >= 0`` [1/rad^2]
(``c_node = 0``: the linear unit, the same arithmetic as :func:`stick_slip.simulate_unit`).

What the distributed model's hardening maps to (derivation). Each cable of the pull-pull
pair follows ``f = k_c D (1 + c D^2)`` (``D`` the cable-equivalent elongation, ``k_c`` the
cable's stiffness, ``c`` [1/m^2], :class:`capstan.models.distributed.model.DistributedModel`).
Both cables start at the pretension elongation ``D0`` (``k_c D0 (1 + c D0^2) = T0``); a
torsional deflection ``theta`` stretches one by ``d = r theta`` and relaxes the other by
``d`` (``r = sqrt(r_in r_out)``), so the pair's torque is exactly

    ``tau = r k_c [(D0 + d)(1 + c (D0 + d)^2) - (D0 - d)(1 + c (D0 - d)^2)]
          = 2 r^2 k_c (1 + 3 c D0^2) theta + 2 r^4 k_c c theta^3``

-- odd in ``theta`` (the quadratic terms of the two cables cancel), a *linear* stiffness
raised by ``1 + 3 c D0^2`` and a cubic relative to it ``c r^2 / (1 + 3 c D0^2)``. The node
sits half way along the cable (each half ``K_h = 2 K_c``, stretch ``e = theta / 2``), so

    ``c_node = 4 c r^2 / (1 + 3 c D0^2)``.

The pretension linearises the pair: the tangent stiffness of the pair rises by
``3 c_node e^2 = x (d_lin / D0)^2 / (1 + x)^3`` at the deflection ``d_lin = tau / (2 r k_c)``
of the linear cable, ``x = 3 c D0^2``; at most ``0.148 (d_lin / D0)^2`` (at ``x = 1/2``), while
one cable alone stiffens by ``3 c ((D0 + d)^2 - D0^2) / (1 + 3 c D0^2)``. A hardening cable
is therefore visible in the pair's deflection only where the torque takes a cable's tension
change near its pretension (``d_lin / D0 -> 1``); below that it reads as a stiffer linear
cable. (With the eq-23 field ``D0`` varies along the sheath; ``c_node`` is an average.)

Time stepping: backward Euler on ``x`` as in :mod:`stick_slip`, the springs' cubic force
implicit too (:func:`stick_slip.step_velocity`, ``P(v)``): unconditionally stable for
``c_node >= 0`` (the cubic part only adds stiffness).
"""

from __future__ import annotations


import numpy as np
from numba import njit

from capstan.models.transmission.stick_slip import simulate_paths


@njit(cache=True)
def hardening_torque_Nm(K_Nm_rad: float, c_node_1_rad2: float, e_rad: float) -> float:
    """Torque of one hardening elastic path ``K e (1 + c_node e^2)`` [Nm] at the stretch ``e`` [rad]."""
    return K_Nm_rad * e_rad * (1.0 + c_node_1_rad2 * e_rad * e_rad)


@njit(cache=True, nogil=True)
def simulate_unit_hardening(t_s: np.ndarray, a_Nm: np.ndarray, starts: np.ndarray, x0_rad: np.ndarray,
                            c0_Nms_rad: np.ndarray, kx_Nm_rad: np.ndarray, k_pre_Nm_rad: float, tau_fc_Nm: float,
                            zeta_s: float, eta_s_rad_s: float, b_vis_Nms_rad: float, out_x_rad: np.ndarray,
                            out_v_rad_s: np.ndarray, out_f_Nm: np.ndarray, cap_scale: np.ndarray,
                            c2_Nms2_rad2: float, dahl_exp: float, c_node_1_rad2: float, K1_Nm_rad: float,
                            anchor1_rad: np.ndarray, K2_Nm_rad: float, anchor2_rad: np.ndarray) -> int:
    """:func:`stick_slip.simulate_unit` with the cubic part of hardening elastic paths.

    The linear part of every path stays in ``a_Nm - kx x`` as there; this adds
    ``c_node K_j (A_j - x)^3`` for path 1 (``K1``, anchor ``anchor1_rad`` per sample) and path 2
    (``K2``; ``K2 = 0`` and an empty ``anchor2_rad``: one path).

    :param c_node_1_rad2: hardening coefficient at the node ``>= 0`` [1/rad^2] (module docstring).
    :returns: the number of samples integrated (``len(t_s)`` unless a step failed: NaN
        velocity, non-increasing time, or a negative ``c_node``).
    """
    if not c_node_1_rad2 >= 0.0:
        return 0
    h1 = c_node_1_rad2 * K1_Nm_rad
    h2 = c_node_1_rad2 * K2_Nm_rad if anchor2_rad.shape[0] == t_s.shape[0] else 0.0
    return simulate_paths(t_s, a_Nm, starts, x0_rad, c0_Nms_rad, kx_Nm_rad, k_pre_Nm_rad, tau_fc_Nm, zeta_s,
                          eta_s_rad_s, b_vis_Nms_rad, out_x_rad, out_v_rad_s, out_f_Nm, cap_scale, c2_Nms2_rad2,
                          dahl_exp, h1, anchor1_rad, h2, anchor2_rad)
