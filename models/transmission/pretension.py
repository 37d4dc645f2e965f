"""Pretension field along a cable and the averaged pretension of the reduced model (paper eqs 23-25).

Each cable is tensioned at both fixtures: ``T_a`` at the input side (s = 0) and ``T_b`` at
the output side (s = L). Friction in the curved sheath lets each boundary tension decay
into the sheath by the capstan law, so at rest the field is the larger of the two
decaying branches::

    T(s) = max( T_a exp(-mu C(s)),  T_b exp(-mu (theta - C(s))) ),   C(s) = int_0^s kappa ds

**Eq (24), corrected bounds.** The paper prints the output-side branch with
``int_1^{1-s} L kappa(L sigma) d sigma``, which is negative for s < 1 (a growing
exponential) and does not vanish at the output end. The physically consistent form,
used here, is the attenuation accumulated from the output fixture back to s::

    T_b exp(-mu int_s^1 L kappa(L sigma) d sigma) = T_b exp(-mu (theta - C(s))).

(For a routing symmetric about its midpoint ``int_{1-s}^1 = int_0^s``, which is probably
what the printed bounds meant.) The minimum-pretension point ``s_min`` is where both
branches are equal (eq 24 generalised to ``T_a != T_b``)::

    C(s_min) = ( theta + ln(T_a / T_b) / mu ) / 2,

and the averaged pretension (eq 25, generalised) is the sum of both branches there::

    T0_eq = T_a exp(-mu C(s_min)) + T_b exp(-mu (theta - C(s_min)))   ( = 2 T(s_min) ).

For ``T_a = T_b = T0`` this is eq 25; on a uniform routing ``T0_eq = 2 T0 exp(-mu theta / 2)``.
``T0_eq`` is a per-cable *sum of two tensions*: at rest the two springs of the N = 1
reduced cable carry ``T0_eq / 2`` each (see :mod:`capstan.models.transmission.reduced`).

**Two readings of eq (25)** (:class:`Eq25Reading`). The printed formula is the sum of both
branches at ``s_min``, i.e. ``2 T(s_min)``: read literally, every spring of the averaged
model sits at the field's *minimum* (``FIELD_MINIMUM``, ``T0_eq_N``). The text says instead
that the averaged pretension preserves the total friction of the distributed model under
steady sliding. Node i of the distributed model carries a Coulomb friction
``mu theta_i`` x (its mean spring tension) (eq 11/13), so the total is
``mu int kappa(s) T(s) ds`` per cable, and a uniform field preserves it when it equals the
*bending-weighted* mean of the field (``FRICTION_PRESERVING``, ``T0_eq_friction_N``)::

    T0_eq = (2 / theta) int_0^theta T dC
          = (2 / (mu theta)) [ T_a (1 - e^{-mu C*}) + T_b (1 - e^{-mu (theta - C*)}) ],  C* = C(s_min).

With ``dC = kappa ds`` the integral does not depend on where the bends are, only on theta and
the end values (as for the minimum). Symmetric ends: ``T0_eq = 4 T0 (1 - e^{-mu theta/2}) /
(mu theta)``, between the minimum ``2 T0 e^{-mu theta/2}`` and ``2 T0``; both readings tend to
``T_a + T_b`` as ``mu theta -> 0``. (The arc-length mean of the field is a third number; it
depends on the profile and does not preserve the friction.)

**Inconsistent ends.** If ``|ln(T_a / T_b)| > mu theta`` one branch dominates the whole
cable; no static capstan field can have those two end values. ``C(s_min)`` is then clipped
to the weaker end (``s_min_norm`` = 0 or 1, ``clipped = True``, a warning is logged) and the
formula above still gives a value that is continuous in the inputs (``T_a + T_b`` at mu = 0).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import ArrayLike

from capstan.models.common.errors import ModelError
from capstan.models.transmission.routing import Routing

log = logging.getLogger(__name__)


class Eq25Reading(IntEnum):
    """Which uniform pretension eq (25) stands for (see the module docstring)."""

    FIELD_MINIMUM = 1        #: ``2 T(s_min)`` as printed: every spring at the field's minimum
    FRICTION_PRESERVING = 2  #: twice the bending-weighted field mean: same total Coulomb friction

    @staticmethod
    def parse(text: str) -> "Eq25Reading":
        """``"field_minimum"`` or ``"friction_preserving"`` (case-insensitive).

        :raises ModelError: on any other text.
        """
        key = str(text).strip().upper()
        if key not in Eq25Reading.__members__:
            raise ModelError(f"eq 25 reading must be one of {[m.name.lower() for m in Eq25Reading]}, got {text!r}")
        return Eq25Reading[key]


@dataclass(frozen=True)
class PretensionField:
    """Summary of the pretension field of one cable.

    :ivar s_min_norm: normalised arc length [0, 1] of the minimum-pretension point (eq 24).
    :ivar T0_eq_N: averaged (equivalent) pretension of eq 25 as printed [N] (sum of both branches
        at s_min: :attr:`Eq25Reading.FIELD_MINIMUM`).
    :ivar T_min_N: field value at ``s_min`` [N] (= T0_eq / 2 unless clipped).
    :ivar bending_at_min_rad: ``int_0^{s_min} kappa ds`` [rad].
    :ivar T_a_N: boundary pretension at the input-side fixture [N].
    :ivar T_b_N: boundary pretension at the output-side fixture [N].
    :ivar mu: sheath friction coefficient [-].
    :ivar theta_total_rad: total bending of the routing [rad].
    :ivar clipped: True if the end values exceed the capstan ratio (see module docstring).
    :ivar T0_eq_friction_N: averaged pretension that preserves the field's total friction [N]
        (twice its bending-weighted mean: :attr:`Eq25Reading.FRICTION_PRESERVING`).
    """

    s_min_norm: float
    T0_eq_N: float
    T_min_N: float
    bending_at_min_rad: float
    T_a_N: float
    T_b_N: float
    mu: float
    theta_total_rad: float
    clipped: bool
    T0_eq_friction_N: float = math.nan

    def T0_eq(self, reading: Eq25Reading) -> float:
        """Averaged pretension of eq 25 [N] in the given reading (per-cable sum of two tensions)."""
        return self.T0_eq_N if Eq25Reading(reading) == Eq25Reading.FIELD_MINIMUM else self.T0_eq_friction_N


def _check(mu: float, T_a_N: float, T_b_N: float) -> None:
    """:raises ModelError: on negative/non-finite mu or non-positive boundary tensions."""
    if not (math.isfinite(mu) and mu >= 0.0):
        raise ModelError(f"friction coefficient mu must be finite and >= 0, got {mu}")
    for name, t in (("T_a_N", T_a_N), ("T_b_N", T_b_N)):
        if not (math.isfinite(t) and t > 0.0):
            raise ModelError(f"boundary pretension {name} must be finite and > 0, got {t}")


def pretension_field(routing: Routing, mu: float, T_a_N: float, T_b_N: float) -> PretensionField:
    """Minimum-pretension point (eq 24) and averaged pretension (eq 25) of one cable.

    :param routing: the sheath routing (s = 0 at the input fixture).
    :param mu: sheath friction coefficient [-], >= 0.
    :param T_a_N: pretension at the input-side fixture [N], > 0.
    :param T_b_N: pretension at the output-side fixture [N], > 0.
    :raises ModelError: on invalid mu or tensions.
    """
    mu, T_a_N, T_b_N = float(mu), float(T_a_N), float(T_b_N)
    _check(mu, T_a_N, T_b_N)
    theta = routing.theta_total_rad
    mu_theta = mu * theta
    log_ratio = math.log(T_a_N / T_b_N)
    at_end = T_a_N != T_b_N and abs(log_ratio) >= mu_theta
    clipped = T_a_N != T_b_N and abs(log_ratio) > mu_theta
    if T_a_N == T_b_N:
        c_star = 0.5 * theta
    elif at_end:
        c_star = theta if log_ratio > 0.0 else 0.0
    else:
        c_star = min(max(0.5 * (theta + log_ratio / mu), 0.0), theta)
    if at_end:
        s_norm = 1.0 if log_ratio > 0.0 else 0.0
    else:
        s_lo, s_hi = routing.arc_length_at_bending_m(c_star)
        s_norm = 0.5 * (s_lo + s_hi) / routing.length_m
    branch_a = T_a_N * math.exp(-mu * c_star)
    branch_b = T_b_N * math.exp(-mu * (theta - c_star))
    if theta > 0.0:
        # int_0^theta max(branches) dC, each piece T (1 - e^{-mu c}) / mu written as T c phi(mu c)
        t_eq_fric = 2.0 / theta * (T_a_N * c_star * _decay_mean(mu * c_star)
                                   + T_b_N * (theta - c_star) * _decay_mean(mu * (theta - c_star)))
    else:
        t_eq_fric = T_a_N + T_b_N
    if clipped:
        log.warning("boundary pretensions T_a=%.1f N, T_b=%.1f N exceed the capstan ratio exp(mu theta)=%.3f; "
                    "minimum point clipped to the weaker end", T_a_N, T_b_N, math.exp(mu_theta))
    return PretensionField(
        s_min_norm=float(s_norm), T0_eq_N=branch_a + branch_b, T_min_N=max(branch_a, branch_b),
        bending_at_min_rad=float(c_star), T_a_N=T_a_N, T_b_N=T_b_N, mu=mu,
        theta_total_rad=theta, clipped=clipped, T0_eq_friction_N=float(t_eq_fric),
    )


def _decay_mean(x: float) -> float:
    """Mean of ``e^{-u}`` over ``u in [0, x]``: ``(1 - e^{-x}) / x`` (1 at x = 0, no cancellation)."""
    return -math.expm1(-x) / x if x > 0.0 else 1.0


def tension_at(routing: Routing, mu: float, T_a_N: float, T_b_N: float, s_m: ArrayLike) -> np.ndarray:
    """Pretension field ``T(s)`` [N] at arc length(s) ``s_m`` [m] (eq 23, corrected bounds).

    :raises ModelError: on invalid mu or tensions.
    """
    mu, T_a_N, T_b_N = float(mu), float(T_a_N), float(T_b_N)
    _check(mu, T_a_N, T_b_N)
    c = routing.cumulative_bending_rad(s_m)
    return np.maximum(T_a_N * np.exp(-mu * c), T_b_N * np.exp(-mu * (routing.theta_total_rad - c)))


def segment_tensions_N(routing: Routing, mu: float, T_a_N: float, T_b_N: float, n_nodes: int) -> np.ndarray:
    """(N+1,) initial tension [N] of each spring of an N-node cable, in routing order.

    Convention (consistent with ``routing.segment_bending_rad(N)``): internal node i
    (1-based) represents arc-length segment ``[(i-1) L/N, i L/N]`` with bending
    ``theta_i``; spring j (0-based, between node j and j+1; node 0 is the input fixture,
    node N+1 the output fixture) is evaluated at ``s_j = j L / N``. So spring 0 carries
    ``T_a``, spring N carries ``T_b`` and each internal node sits between the field values
    at its segment ends. That field holds each node inside its static friction cone of
    eq (13): ``|f_{i-1,i} - f_{i,i+1}| <= mu theta_i (f_{i-1,i} + f_{i,i+1}) / 2``
    (the trapezoid bound of the convex exponential).

    :param n_nodes: N, number of internal nodes (>= 1).
    :raises ModelError: on invalid mu, tensions or ``n_nodes < 1``.
    """
    if int(n_nodes) < 1:
        raise ModelError(f"n_nodes must be >= 1, got {n_nodes}")
    s = np.linspace(0.0, routing.length_m, int(n_nodes) + 1)
    return tension_at(routing, mu, T_a_N, T_b_N, s)


def uniform_segment_tensions_N(T0_eq_N: float, n_nodes: int) -> np.ndarray:
    """(N+1,) springs all at ``T0_eq / 2`` [N]: the averaged-pretension initial state (paper §4.4.2).

    :raises ModelError: on non-positive ``T0_eq_N`` or ``n_nodes < 1``.
    """
    if int(n_nodes) < 1:
        raise ModelError(f"n_nodes must be >= 1, got {n_nodes}")
    if not (math.isfinite(T0_eq_N) and T0_eq_N > 0.0):
        raise ModelError(f"T0_eq_N must be finite and > 0, got {T0_eq_N}")
    return np.full(int(n_nodes) + 1, 0.5 * float(T0_eq_N))


def boundary_pretension_from_load_cells(T_lc_in_N: float, T_lc_out_N: float) -> float:
    """Symmetric nominal boundary pretension ``T0`` [N] of paper §4.4.1 from load-cell readings.

    Convention of ``formats.md``: ``T_lc_in_N`` / ``T_lc_out_N`` are the MEAN cable tension at
    the input-side / output-side fixtures (mean of the two cables). The result is the mean
    of all four fixture tensions, ``(T_lc_in + T_lc_out) / 2``. The paper writes
    ``(T_lc,in + T_lc,out) / 4`` because there each reading is the SUM over both cables;
    see :func:`boundary_pretension_from_load_cell_sums`. Under load the cable difference
    (torque) cancels in the mean.

    :raises ModelError: on non-finite or non-positive readings.
    """
    for name, t in (("T_lc_in_N", T_lc_in_N), ("T_lc_out_N", T_lc_out_N)):
        if not (math.isfinite(t) and t > 0.0):
            raise ModelError(f"load-cell tension {name} must be finite and > 0, got {t}")
    return 0.5 * (float(T_lc_in_N) + float(T_lc_out_N))


def boundary_pretension_from_load_cell_sums(T_lc_in_sum_N: float, T_lc_out_sum_N: float) -> float:
    """Paper §4.4.1 verbatim: ``T0 = (T_lc,in + T_lc,out) / 4`` with per-side SUMS over both cables [N].

    :raises ModelError: on non-finite or non-positive readings.
    """
    return boundary_pretension_from_load_cells(0.5 * T_lc_in_sum_N, 0.5 * T_lc_out_sum_N)
