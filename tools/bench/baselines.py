"""Compare the analytical predictors (reduced eq 20, Wu-type, single-sided) with the distributed plant.

On demand, not a test: ``.venv/bin/python -m capstan.tools.bench.baselines [--nodes 10] [--duration 20]``.
For each routing/pretension case the distributed model (eqs 2-13, errata of design.md)
is driven by a three-sine input torque (10 Nm peak) on the testbed (k_out = 20 Nm/rad,
b_out = 2 Nm s/rad); the Wu-type gain/threshold are least-squares fitted once on the
reference case (uniform theta = 3 rad) and reused, as in the paper's Fig. 11 protocol.
Prints each predictor's friction level and output-torque RMSE [Nm].
"""

from __future__ import annotations

import argparse

import numpy as np

from capstan.models.transmission.baselines import GatedTransmission, fit_parameters, rmse_Nm, single_sided_model
from capstan.models.distributed.model import DistributedModel
from capstan.models.plant.config import plant_from_mapping
from capstan.models.transmission.pretension import pretension_field
from capstan.models.transmission.reduced import ReducedModel, StribeckParams

MU, R_M = 0.052, 0.04
TWO_BENDS = [[0.0, 9.0], [0.3, 9.0], [0.5, 0.0], [1.1, 0.0], [1.2, 3.0], [1.379, 3.0]]
CASES = [  # (label, routing mapping, T_in [N], T_out [N])
    ("uniform theta=3 (fit)", {"length_m": 1.379, "theta_rad": 3.0}, 150.0, 150.0),
    ("uniform theta=0.5", {"length_m": 1.379, "theta_rad": 0.5}, 150.0, 150.0),
    ("uniform theta=6", {"length_m": 1.379, "theta_rad": 6.0}, 150.0, 150.0),
    ("two bends 150/150", {"curvature_profile": TWO_BENDS}, 150.0, 150.0),
    ("two bends 175/150", {"curvature_profile": TWO_BENDS}, 175.0, 150.0),
]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", type=int, default=10, help="N internal nodes of the distributed plant")
    ap.add_argument("--duration", type=float, default=20.0, help="excitation length [s]")
    args = ap.parse_args()
    t = np.arange(0.0, args.duration, 1e-3)
    u = 6 * np.sin(2 * np.pi * 0.1 * t) + 3 * np.sin(2 * np.pi * 0.27 * t + 1) + np.sin(2 * np.pi * 0.61 * t + 0.3)
    wu = None
    print(f"{'case':24s} {'tau_fc':>7s} {'ss_thr':>7s} {'wu_thr':>7s} | RMSE [Nm]: {'reduced':>8s} {'single':>8s} {'wu':>8s}")
    for label, routing_cfg, t_in, t_out in CASES:
        spec = plant_from_mapping({
            "transmission": {"n_nodes": args.nodes, "mu": MU}, "routing": routing_cfg,
            "pretension": {"upper_in_N": t_in, "lower_in_N": t_in, "upper_out_N": t_out, "lower_out_N": t_out},
            "output": {"k_out_Nm_rad": 20.0, "b_out_Nms_rad": 2.0}})
        y = DistributedModel(spec.transmission, spec.boundary).simulate(t, u, record_tensions=False).tau_out_Nm
        if wu is None:
            wu, _ = fit_parameters(GatedTransmission(1.0, 1.0), ["gain", "threshold_Nm"], t, u, y)
        routing = spec.routing
        t0_eq = pretension_field(routing, MU, t_in, t_out).T0_eq_N
        red = ReducedModel.from_pretension(t0_eq, MU, routing.theta_total_rad, R_M,
                                           stribeck=StribeckParams(zeta_s=1.0))
        ss = single_sided_model(routing, MU, t_in, R_M)
        print(f"{label:24s} {red.tau_fc_Nm:7.3f} {ss.threshold_Nm:7.3f} {wu.threshold_Nm:7.3f} |            "
              f"{rmse_Nm(red.predict_tau_out(t, u), y):8.3f} {rmse_Nm(ss.predict_tau_out(t, u), y):8.3f} "
              f"{rmse_Nm(wu.predict_tau_out(t, u), y):8.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
