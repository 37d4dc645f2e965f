"""The motor's velocity for the deflection damping and the inertia compensation, formed from the motor's
position (the drive's encoder counts) instead of the drive's velocity object.

A drive's velocity (0x606C) is a 1 ms difference of encoder counts or a value in whole rpm: quantised to
4.8e-5 rad / 1 ms = 0.048 rad/s (2^17 counts/rev) or 0.105 rad/s (1 rpm), which the damping's 100 Nm s/rad
turns into 5-10 Nm steps of the command. Here an observer on the position with the motor's known torque as
its input (a steady-state Kalman filter of the motor's rigid-body model, an alpha-beta filter with an
acceleration input)::

    a      = (u_applied - tau_in) / J_m              the motor's acceleration from the torques on it
                                                     (u_applied: the command io_delay_cycles before the
                                                     previous one; tau_in: the input load cells, raw)
    q-     = q^ + T v^ + T^2/2 (a + d^),   v- = v^ + T (a + d^)      predict
    e      = q_m - q-                                the position's innovation (counts, quantised)
    q^     = q- + k0 e,   v^ = v- + k1 e,   d^ = d^ + k2 e

With the torques known the estimate follows the motion without the lag of a differentiator's low-pass; the
innovation only corrects what the model misses (J_m off by its tolerance, the delay's jitter, friction at the
motor, a load-cell offset), at ``feedback.motor_velocity_observer_hz``: the error dynamics have a double pole at
``r = exp(-2 pi f T)``, and one at ``feedback.motor_velocity_bias_hz`` for the third state. The third state ``d^`` takes up a steady acceleration the torques do not explain, so such
an error leaves no steady velocity error (without it a 0.1 Nm offset of tau_in would bias the estimate by
~2 mrad/s, 0.2 Nm of damping). The encoder's quantisation (uniform,
``2 pi / counts / sqrt(12)`` rad std) reaches the estimate through :func:`observer_responses`'s ``H_q``;
:mod:`capstan.controller.law.loop_model` closes the loop through both paths and
:mod:`capstan.controller.law.stability` states the noise on the command.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np
from numba import njit


class MotorVelocitySource(IntEnum):
    """Where the damping and the inertia compensation take the motor's velocity from."""

    OBSERVER = 0    # the motor's position through the observer of this module (the encoder counts)
    DRIVE = 1       # the drive's velocity object (0x606C) as reported: exact only in an ideal simulation


#: the command history the step keeps for the observer's input: u[k-1] ... u[k-4] (io_delay_cycles <= 3)
HISTORY = 4


def observer_gains(cutoff_hz: float, bias_hz: float, dt_s: float) -> np.ndarray:
    """The observer's gains ``K`` (3) whose error dynamics ``(I - K c) A`` have a double pole at
    ``exp(-2 pi cutoff_hz dt_s)`` and one at ``exp(-2 pi bias_hz dt_s)`` (the unexplained acceleration's)
    (Ackermann's formula on ``(A, c A)``, ``A`` of :func:`observer_model`).

    :raises ValueError: if a cutoff is not in (0, Nyquist).
    """
    for f in (cutoff_hz, bias_hz):
        if not 0.0 < f < 0.5 / dt_s:
            raise ValueError(f"observer cutoff must be in (0, {0.5 / dt_s:g}) Hz, got {f}")
    r = math.exp(-2.0 * math.pi * cutoff_hz * dt_s)
    r_d = math.exp(-2.0 * math.pi * bias_hz * dt_s)
    A, _ = observer_model(dt_s)
    c = np.array([1.0, 0.0, 0.0]) @ A
    obs = np.vstack((c, c @ A, c @ A @ A))
    phi = np.linalg.matrix_power(A - r * np.eye(3), 2) @ (A - r_d * np.eye(3))
    return phi @ np.linalg.solve(obs, np.array([0.0, 0.0, 1.0]))


def observer_model(dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of the model ``x[k] = A x[k-1] + B a``: ``x = (q, v, d)``, ``d`` a slowly varying acceleration
    the torques do not explain (the motor's friction, a load-cell offset, J_m's error x the acceleration)."""
    T = dt_s
    A = np.array([[1.0, T, 0.5 * T * T], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    return A, np.array([0.5 * T * T, T, 0.0])


def observer_matrices(K: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(F, G, K)`` of ``x[k] = F x[k-1] + G a[k] + K q[k]``: the step's arithmetic (predict, correct)."""
    A, B = observer_model(dt_s)
    ikc = np.eye(3) - np.outer(K, [1.0, 0.0, 0.0])
    return ikc @ A, ikc @ B, np.asarray(K, dtype=float)


def observer_responses(K: np.ndarray, dt_s: float, f_hz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(H_q, H_a)`` at ``f_hz``: the velocity estimate per unit position [1/s] and per unit acceleration
    input [s] (``v^ = H_q q + H_a a``), from :func:`observer_matrices`."""
    F, G, Kq = observer_matrices(K, dt_s)
    zi = np.exp(-2j * math.pi * np.atleast_1d(np.asarray(f_hz, dtype=float)) * dt_s)
    m = np.eye(3)[None, :, :] - F[None, :, :] * zi[:, None, None]       # I - F z^-1, per frequency
    rhs = np.stack((np.broadcast_to(Kq, (len(zi), 3)), np.broadcast_to(G, (len(zi), 3))), axis=2).astype(complex)
    x = np.linalg.solve(m, rhs)
    return x[:, 1, 0], x[:, 1, 1]


@njit(cache=True)
def observer_step(st: np.ndarray, i: int, q_m: float, acc: float, dt: float, k0: float, k1: float,
                  k2: float) -> float:
    """One cycle of the observer on ``st[i:i + 3]`` (q^, v^, d^) with gains ``k0 k1 k2``; returns v^ [rad/s]."""
    a = acc + st[i + 2]
    qp = st[i] + dt * st[i + 1] + 0.5 * dt * dt * a
    vp = st[i + 1] + dt * a
    e = q_m - qp
    st[i] = qp + k0 * e
    st[i + 1] = vp + k1 * e
    st[i + 2] += k2 * e
    return st[i + 1]


def encoder_noise_rad(counts_per_rev: int) -> float:
    """The quantisation noise of an encoder [rad std]: uniform over one count (0 counts: none)."""
    return 0.0 if counts_per_rev <= 0 else 2.0 * math.pi / counts_per_rev / math.sqrt(12.0)
