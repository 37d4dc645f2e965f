"""Parameters, boundary modes, run result and input validation of the distributed
tendon-sheath model (:mod:`capstan.models.distributed.model`, which re-exports all of them).

Units are in the names: ``_rad``, ``_N``, ``_Nm_rad``, ``_m``, ``_Ns_m``, ``_kg_m2``, ...
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from capstan.models.common.errors import ConfigError
from capstan.models.transmission.link import LinkParams


class InputMode(IntEnum):
    """How the input pulley is driven."""

    TORQUE = 0   #: commanded cable torque, ``b_in dq_in = tau_in - tau_in,cable``
    MOTOR = 1    #: motor inertia, ``J_m ddq_in + B_m dq_in = tau_m - tau_in,cable``


class OutputMode(IntEnum):
    """What the output pulley drives."""

    TESTBED = 0  #: passive environment ``J_out ddq + b_out dq + k_out q = tau_out``
    LINK = 1     #: link with gravity ``J ddq + B dq = tau_out + tau_grav(q) + tau_ext``


def _vec(name: str, value: object, length: int | None, positive: bool) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1:
        raise ConfigError(name, f"must be a 1-D array, got shape {arr.shape}")
    if length is not None and arr.shape[0] != length:
        raise ConfigError(name, f"must have length {length}, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(name, "must be finite")
    if positive and np.any(arr <= 0.0):
        raise ConfigError(name, f"must be > 0, got min {arr.min()}")
    if not positive and np.any(arr < 0.0):
        raise ConfigError(name, f"must be >= 0, got min {arr.min()}")
    return arr


def _pos(name: str, x: float, strict: bool = True) -> None:
    if not math.isfinite(x) or (x <= 0.0 if strict else x < 0.0):
        raise ConfigError(name, f"must be {'>' if strict else '>='} 0 and finite, got {x}")


@dataclass(frozen=True)
class TransmissionParams:
    """Transmission geometry, pretension field and material.

    :ivar theta_upper_rad: (N,) accumulated bending angle of each internal node's
        segment, routing order input -> output.
    :ivar theta_lower_rad: (N,) same for the lower cable, routing order input -> output.
    :ivar tension_upper_N: (N+1,) initial segment tensions, routing order input -> output.
    :ivar tension_lower_N: (N+1,) initial segment tensions, routing order input -> output.
    :ivar stiffness_Nm_rad: K_c, static torsional stiffness with mu = 0 [Nm/rad].
    :ivar mu: friction coefficient [-]. :ivar p: smoothness exponent of eq (13).
    :ivar r_in_m, r_out_m: pulley radii [m]. :ivar b_node_Ns_m: damping of each internal
        node [N s/m], the paper's b_l = 1e-3 N s/mm (Table 3), per node, not per cable. It
        is not negligible: with the smooth law (13) a node creeps at ``g / b`` below the
        Coulomb limit, and a sliding cable drags ``N b v``. On the testbed multisine
        (theta = 3 rad, T0 = 150 N) tau_out moves by 0.04-0.08 Nm RMSE for b = 0.1 and by
        0.14-0.6 Nm for b = 10 (N = 10-50); an implementation must use the same value.
    :raises ConfigError: on wrong shapes or non-positive / non-finite values.
    """

    theta_upper_rad: np.ndarray
    theta_lower_rad: np.ndarray
    tension_upper_N: np.ndarray
    tension_lower_N: np.ndarray
    stiffness_Nm_rad: float = 240.0
    mu: float = 0.052
    p: float = 100.0
    r_in_m: float = 0.04
    r_out_m: float = 0.04
    b_node_Ns_m: float = 1.0

    def __post_init__(self) -> None:
        tu = _vec("transmission.theta_upper_rad", self.theta_upper_rad, None, False)
        n = tu.shape[0]
        if n < 1:
            raise ConfigError("transmission.theta_upper_rad", "needs at least one node (N >= 1)")
        object.__setattr__(self, "theta_upper_rad", tu)
        object.__setattr__(self, "theta_lower_rad",
                           _vec("transmission.theta_lower_rad", self.theta_lower_rad, n, False))
        object.__setattr__(self, "tension_upper_N",
                           _vec("transmission.tension_upper_N", self.tension_upper_N, n + 1, True))
        object.__setattr__(self, "tension_lower_N",
                           _vec("transmission.tension_lower_N", self.tension_lower_N, n + 1, True))
        _pos("transmission.stiffness_Nm_rad", self.stiffness_Nm_rad)
        _pos("transmission.mu", self.mu, strict=False)
        _pos("transmission.p", self.p)
        _pos("transmission.r_in_m", self.r_in_m)
        _pos("transmission.r_out_m", self.r_out_m)
        _pos("transmission.b_node_Ns_m", self.b_node_Ns_m)

    @property
    def n_nodes(self) -> int:
        """Number of internal nodes per cable N."""
        return int(self.theta_upper_rad.shape[0])

    @property
    def cable_stiffness_N_m(self) -> float:
        """Axial stiffness of one whole cable ``K_c / (2 r_in r_out)`` [N/m]."""
        return self.stiffness_Nm_rad / (2.0 * self.r_in_m * self.r_out_m)

    @property
    def segment_stiffness_N_m(self) -> float:
        """Stiffness of one of the N+1 segments ``(N+1) K_c / (2 r_in r_out)`` [N/m]."""
        return (self.n_nodes + 1) * self.cable_stiffness_N_m

    @staticmethod
    def uniform(n_nodes: int, theta_rad: float, pretension_N: float, **kw: float) -> "TransmissionParams":
        """Uniform curvature (theta_i = theta/N) with the limiting capstan pretension
        field of eq (23): boundary pretension ``pretension_N`` at both fixtures, decaying by
        ``exp(-mu theta_i)`` per node from each end, the larger of the two profiles.

        :raises ConfigError: on invalid arguments.
        """
        if n_nodes < 1:
            raise ConfigError("transmission.n_nodes", f"must be >= 1, got {n_nodes}")
        mu = float(kw.get("mu", 0.052))
        th = np.full(n_nodes, theta_rad / n_nodes)
        cum = np.concatenate(([0.0], np.cumsum(th)))          # bending passed before seg j
        tens = pretension_N * np.maximum(np.exp(-mu * cum), np.exp(-mu * (cum[-1] - cum)))
        return TransmissionParams(th, th.copy(), tens, tens.copy(), **kw)


@dataclass(frozen=True)
class BoundaryParams:
    """Boundary conditions of the input and output pulleys.

    :ivar b_in_Nms_rad: TORQUE mode regularising damping [Nm s/rad]; default 1e-3 gives
        a time constant ``b_in / K_c`` of about 4 us, so q_in follows the torque well
        within a control period (torque lag ``b_in dq_in`` ~ 1 mNm at 1 rad/s).
    :ivar motor_inertia_kg_m2: J_m (MOTOR mode) [kg m^2] (design.md: 0.73).
    :ivar motor_damping_Nms_rad: B_m (MOTOR mode) [Nm s/rad]; default 0.1 is a
        placeholder for a lightly damped servo until identified (damping ratio ~0.004 on K_c).
    :ivar k_out_Nm_rad, b_out_Nms_rad, out_inertia_kg_m2: TESTBED environment; with zero
        inertia (default, massless as in the paper) ``b_out`` must be > 0.
    :ivar link: LINK mode parameters (:class:`capstan.models.transmission.link.LinkParams`).
    :raises ConfigError: on invalid values.
    """

    input_mode: InputMode = InputMode.TORQUE
    b_in_Nms_rad: float = 1e-3
    motor_inertia_kg_m2: float = 0.73
    motor_damping_Nms_rad: float = 0.1
    output_mode: OutputMode = OutputMode.TESTBED
    k_out_Nm_rad: float = 20.0
    b_out_Nms_rad: float = 2.0
    out_inertia_kg_m2: float = 0.0
    link: LinkParams = field(default_factory=LinkParams)

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "input_mode", InputMode(self.input_mode))
        except ValueError as exc:
            raise ConfigError("boundary.input_mode", f"unknown mode {self.input_mode!r}") from exc
        try:
            object.__setattr__(self, "output_mode", OutputMode(self.output_mode))
        except ValueError as exc:
            raise ConfigError("boundary.output_mode", f"unknown mode {self.output_mode!r}") from exc
        _pos("boundary.b_in_Nms_rad", self.b_in_Nms_rad, strict=self.input_mode == InputMode.TORQUE)
        _pos("boundary.motor_inertia_kg_m2", self.motor_inertia_kg_m2,
             strict=self.input_mode == InputMode.MOTOR)
        _pos("boundary.motor_damping_Nms_rad", self.motor_damping_Nms_rad, strict=False)
        _pos("boundary.k_out_Nm_rad", self.k_out_Nm_rad, strict=False)
        _pos("boundary.out_inertia_kg_m2", self.out_inertia_kg_m2, strict=False)
        massless = self.output_mode == OutputMode.TESTBED and self.out_inertia_kg_m2 == 0.0
        _pos("boundary.b_out_Nms_rad", self.b_out_Nms_rad, strict=massless)
        if self.output_mode == OutputMode.LINK:
            _pos("boundary.link.inertia_kg_m2", self.link.inertia_kg_m2)
            _pos("boundary.link.damping_Nms_rad", self.link.damping_Nms_rad, strict=False)


@dataclass
class SimResult:
    """Offline run sampled at the input times (row 0 = the state at ``t_s[0]``).

    Tension arrays are in routing order input -> output; fixture tensions are
    (upper input-side, upper output-side, lower output-side, lower input-side) [N].
    """

    t_s: np.ndarray
    q_in_rad: np.ndarray
    q_out_rad: np.ndarray
    dq_in_rad_s: np.ndarray
    dq_out_rad_s: np.ndarray
    tau_in_Nm: np.ndarray
    tau_out_Nm: np.ndarray
    fixture_tensions_N: np.ndarray
    tensions_upper_N: np.ndarray
    tensions_lower_N: np.ndarray
    n_steps: int = 0
    n_rhs: int = 0
    n_rejected: int = 0
    n_newton_failures: int = 0


def input_series(t_s: np.ndarray, u_Nm: np.ndarray,
                 tau_ext_Nm: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated contiguous float arrays (time [s], input torque [Nm], external torque [Nm],
    zero if ``None``) for a simulation run.

    :raises ConfigError: unless t_s is strictly increasing with >= 2 samples and both torque
        series have its shape and are finite.
    """
    t = np.ascontiguousarray(t_s, dtype=float)
    u = np.ascontiguousarray(u_Nm, dtype=float)
    if t.ndim != 1 or t.shape[0] < 2 or not np.all(np.diff(t) > 0):
        raise ConfigError("t_s", "must be a strictly increasing 1-D array of >= 2 samples")
    if u.shape != t.shape:
        raise ConfigError("u_Nm", f"must have the shape of t_s {t.shape}, got {u.shape}")
    te = np.zeros_like(t) if tau_ext_Nm is None else np.ascontiguousarray(tau_ext_Nm, dtype=float)
    if te.shape != t.shape:
        raise ConfigError("tau_ext_Nm", f"must have the shape of t_s {t.shape}, got {te.shape}")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(te))):
        raise ConfigError("u_Nm/tau_ext_Nm", "must be finite")
    return t, u, te
