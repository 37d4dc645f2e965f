"""Build the distributed plant (transmission + boundary conditions) from a YAML mapping.

Used by testbed scenarios (``capstan simulate``), the simulated rig of the HIL mode and
the experiments, so every place describes a plant with the same keys::

    transmission:            # all optional, defaults = the reference rig of design.md
      n_nodes: 10            # N internal nodes per cable (>= 1)
      stiffness_Nm_rad: 240  # static torsional stiffness K_c with mu = 0
      mu: 0.052
      p: 100                 # steepness of the smooth Coulomb law (13)
      r_in_m: 0.04
      r_out_m: 0.04
      b_node_Ns_m: 1.0       # node damping (paper 1e-3 Ns/mm)
    routing:                 # one of: {length_m, theta_rad} | {curvature_profile: [[s_m, kappa_1_per_m], ...]} | {points_m: [[x, y], ...]}
      length_m: 1.379
      theta_rad: 3.0
    pretension:              # boundary pretensions at the fixtures [N]
      T0_N: 150              # all four ends, or any of upper_in_N, upper_out_N, lower_in_N, lower_out_N
    output:
      mode: testbed          # testbed | link
      k_out_Nm_rad: 20.0     # testbed environment (eq 22)
      b_out_Nms_rad: 2.0
      inertia_kg_m2: 0.0     # optional small output inertia (testbed)
      link: {inertia_kg_m2: 0.17, m_g_l_Nm: 3.78, damping_Nms_rad: 0.02}   # link mode
    input:
      mode: torque           # torque (testbed: tau_in commanded) | motor (J_m, B_m driven by tau_m)
      motor_inertia_kg_m2: 0.73
      motor_damping_Nms_rad: 0.5
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from capstan.models.common.config_tools import get_choice, get_float, get_int, reject_unknown, section
from capstan.models.distributed.model import BoundaryParams, InputMode, OutputMode, TransmissionParams
from capstan.models.transmission.link import LinkParams
from capstan.models.transmission.pretension import pretension_field, segment_tensions_N
from capstan.models.transmission.routing import Routing

REFERENCE_LENGTH_M = 1.379


@dataclass(frozen=True)
class Pretension:
    """Boundary pretensions at the four fixtures [N]."""

    upper_in_N: float
    upper_out_N: float
    lower_in_N: float
    lower_out_N: float

    @property
    def T_lc_in_N(self) -> float:
        """Mean tension at the input-side fixtures [N]."""
        return 0.5 * (self.upper_in_N + self.lower_in_N)

    @property
    def T_lc_out_N(self) -> float:
        """Mean tension at the output-side fixtures [N]."""
        return 0.5 * (self.upper_out_N + self.lower_out_N)


@dataclass(frozen=True)
class PlantSpec:
    """Everything needed to build a :class:`capstan.models.distributed.model.DistributedModel`."""

    transmission: TransmissionParams
    boundary: BoundaryParams
    routing: Routing
    pretension: Pretension

    @property
    def T0_eq_N(self) -> float:
        """Averaged pretension (eq 25) from the mean boundary pretensions [N]."""
        p = self.pretension
        return pretension_field(self.routing, self.transmission.mu, p.T_lc_in_N, p.T_lc_out_N).T0_eq_N


def pretension_from_mapping(cfg: Mapping[str, Any], prefix: str = "pretension") -> Pretension:
    """Parse the ``pretension`` section (``T0_N`` and/or per-end values).

    :raises ConfigError: on unknown keys or non-positive tensions.
    """
    keys = ("upper_in_N", "upper_out_N", "lower_in_N", "lower_out_N")
    reject_unknown(cfg, {"T0_N", *keys}, prefix)
    t0 = get_float(cfg, "T0_N", prefix, 150.0, min_value=0.0, min_exclusive=True)
    vals = [get_float(cfg, k, prefix, t0, min_value=0.0, min_exclusive=True) for k in keys]
    return Pretension(*vals)


def plant_from_mapping(cfg: Mapping[str, Any], prefix: str = "") -> PlantSpec:
    """Build a :class:`PlantSpec` from a mapping with the sections documented above.

    :raises ConfigError: naming the offending key.
    """
    def sub(key: str) -> Mapping[str, Any]:
        return section(cfg, key, prefix, required=False)

    def p(key: str) -> str:
        return f"{prefix}.{key}" if prefix else key

    tr = sub("transmission")
    reject_unknown(tr, {"n_nodes", "stiffness_Nm_rad", "mu", "p", "r_in_m", "r_out_m", "b_node_Ns_m"}, p("transmission"))
    n = get_int(tr, "n_nodes", p("transmission"), 10, min_value=1, max_value=400)
    mu = get_float(tr, "mu", p("transmission"), 0.052, min_value=0.0)
    routing_cfg = sub("routing") or {"length_m": REFERENCE_LENGTH_M, "theta_rad": 3.0}
    routing = Routing.from_mapping(routing_cfg, p("routing"))
    pre = pretension_from_mapping(sub("pretension"), p("pretension"))
    theta = np.asarray(routing.segment_bending_rad(n), dtype=float)
    t_up = segment_tensions_N(routing, mu, pre.upper_in_N, pre.upper_out_N, n)
    t_lo = segment_tensions_N(routing, mu, pre.lower_in_N, pre.lower_out_N, n)
    trans = TransmissionParams(
        theta_upper_rad=theta, theta_lower_rad=theta.copy(),
        tension_upper_N=np.asarray(t_up, dtype=float), tension_lower_N=np.asarray(t_lo, dtype=float),
        stiffness_Nm_rad=get_float(tr, "stiffness_Nm_rad", p("transmission"), 240.0, min_value=0.0, min_exclusive=True),
        mu=mu,
        p=get_float(tr, "p", p("transmission"), 100.0, min_value=1.0),
        r_in_m=get_float(tr, "r_in_m", p("transmission"), 0.04, min_value=0.0, min_exclusive=True),
        r_out_m=get_float(tr, "r_out_m", p("transmission"), 0.04, min_value=0.0, min_exclusive=True),
        b_node_Ns_m=get_float(tr, "b_node_Ns_m", p("transmission"), 1.0, min_value=0.0, min_exclusive=True),
    )
    out = sub("output")
    reject_unknown(out, {"mode", "k_out_Nm_rad", "b_out_Nms_rad", "inertia_kg_m2", "link"}, p("output"))
    out_mode = get_choice(out, "mode", ("testbed", "link"), p("output"), "testbed")
    inp = sub("input")
    reject_unknown(inp, {"mode", "motor_inertia_kg_m2", "motor_damping_Nms_rad", "b_in_Nms_rad"}, p("input"))
    in_mode = get_choice(inp, "mode", ("torque", "motor"), p("input"), "torque")
    defaults = BoundaryParams()
    link_cfg = section(out, "link", p("output"), required=False)
    bnd = BoundaryParams(
        input_mode=InputMode.TORQUE if in_mode == "torque" else InputMode.MOTOR,
        b_in_Nms_rad=get_float(inp, "b_in_Nms_rad", p("input"), defaults.b_in_Nms_rad, min_value=0.0, min_exclusive=True),
        motor_inertia_kg_m2=get_float(inp, "motor_inertia_kg_m2", p("input"), 0.73, min_value=0.0, min_exclusive=True),
        motor_damping_Nms_rad=get_float(inp, "motor_damping_Nms_rad", p("input"), defaults.motor_damping_Nms_rad, min_value=0.0),
        output_mode=OutputMode.TESTBED if out_mode == "testbed" else OutputMode.LINK,
        k_out_Nm_rad=get_float(out, "k_out_Nm_rad", p("output"), 20.0, min_value=0.0),
        b_out_Nms_rad=get_float(out, "b_out_Nms_rad", p("output"), 2.0, min_value=0.0),
        out_inertia_kg_m2=get_float(out, "inertia_kg_m2", p("output"), 0.0, min_value=0.0),
        link=LinkParams.from_mapping(link_cfg, p("output.link")) if link_cfg else LinkParams.bar_with_tip_mass(),
    )
    if bnd.output_mode == OutputMode.TESTBED and bnd.k_out_Nm_rad == 0.0 and bnd.b_out_Nms_rad == 0.0:
        from capstan.models.common.errors import ConfigError

        raise ConfigError(p("output"), "testbed environment needs k_out_Nm_rad > 0 or b_out_Nms_rad > 0")
    return PlantSpec(trans, bnd, routing, pre)
