"""Test helper: run an identification excitation (capstan.models.rig_id) in lock-step on a
simulated rig and log what the daemon's records would hold (record field names of
controller/law/records.py), with the link held by a stiff clamp or hanging free.

The clamp is a spring-damper on the link (``tau_ext = -k q_out - b dq_out``): what a
clamp or a stop does; the software never reads it.
"""

from __future__ import annotations

import numpy as np

from capstan.models.plant.rig import SimulatedRig
from capstan.models.rig_id import Excitation

#: the clamp of a held run [Nm/rad], [Nm s/rad]
CLAMP_K_NM_RAD = 5000.0
CLAMP_B_NMS_RAD = 50.0


#: the command's nominal delay in the lock-step runs [cycles] (the HIL log's motor torque lags 2)
DELAY_CYCLES = 2


def run_excitation(rig: SimulatedRig, exc: Excitation, held: bool, delay_cycles: int = DELAY_CYCLES) -> dict[str, np.ndarray]:
    """Run ``exc`` on ``rig`` at its dt (from the rig's current state) and return the record columns.

    The command of cycle i is computed from the motor feedback of cycle i - 1 and reaches the
    motor through the rig's command path (``delay_cycles`` late, jittered and now and then lost
    as the rig's ``sensors.command`` says); the log holds the command as sent.
    """
    exc.reset()
    path = rig.command_path(delay_cycles)
    n = exc.n_cycles
    cols = {k: np.empty(n) for k in ("t_s", "q_m_rad", "dq_m_rad_s", "tau_m_cmd_Nm", "T_up_in_N", "T_up_out_N",
                                     "T_lo_out_N", "T_lo_in_N", "q_out_rad", "dq_out_rad_s", "imu_new")}
    q_m, dq_m, _ = rig.motor_feedback()
    t0 = rig.t_s
    for i in range(n):
        tau = exc.torque_Nm(i * exc.dt_s, q_m, dq_m)
        ext = -CLAMP_K_NM_RAD * rig.model.q_out_rad - CLAMP_B_NMS_RAD * rig.model.dq_out_rad_s if held else 0.0
        rig.step(path.push(tau), ext, exc.dt_s)
        q_m, dq_m, _ = rig.motor_feedback()
        lc = rig.load_cells_N()
        new, q_o, dq_o = rig.imu_sample()
        cols["t_s"][i] = rig.t_s - t0
        cols["q_m_rad"][i], cols["dq_m_rad_s"][i], cols["tau_m_cmd_Nm"][i] = q_m, dq_m, tau
        cols["T_up_in_N"][i], cols["T_up_out_N"][i], cols["T_lo_out_N"][i], cols["T_lo_in_N"][i] = lc
        cols["q_out_rad"][i], cols["dq_out_rad_s"][i], cols["imu_new"][i] = q_o, dq_o, float(new)
    return cols


# ---- plant variants the identification is not told about (hil.plant schema) -------------------
NOMINAL: dict = {"output": {"mode": "link", "link": {"inertia_kg_m2": 0.17, "m_g_l_Nm": 3.78, "damping_Nms_rad": 0.02}},
                 "input": {"mode": "motor", "motor_inertia_kg_m2": 0.73, "motor_damping_Nms_rad": 0.1},
                 "transmission": {"stiffness_Nm_rad": 240.0, "mu": 0.052}}


def variant(J_m: float = 1.0, K_c: float = 1.0, mu: float = 1.0, link_mass: float = 1.0, link_inertia: float = 1.0,
            theta: float = 1.0, T0: float = 1.0) -> dict:
    """The nominal plant with each parameter scaled by its factor."""
    return {"output": {"mode": "link", "link": {"inertia_kg_m2": 0.17 * link_inertia, "m_g_l_Nm": 3.78 * link_mass,
                                                "damping_Nms_rad": 0.02}},
            "input": {"mode": "motor", "motor_inertia_kg_m2": 0.73 * J_m, "motor_damping_Nms_rad": 0.1},
            "transmission": {"stiffness_Nm_rad": 240.0 * K_c, "mu": 0.052 * mu},
            "routing": {"length_m": 1.379, "theta_rad": 3.0 * theta}, "pretension": {"T0_N": 150.0 * T0}}


#: 20-40 % from the nominal in J_m, K_c, mu, bending, link mass and inertia, pretension
VARIANTS: dict[str, dict] = {
    "nominal": variant(),
    "heavy_motor_soft": variant(J_m=1.35, K_c=0.75, mu=1.3, link_mass=0.7, link_inertia=0.75),
    "light_motor_stiff": variant(J_m=0.7, K_c=1.35, mu=0.75, link_mass=1.3, link_inertia=1.4),
    "bent_tight": variant(J_m=1.2, K_c=1.25, theta=1.3, T0=1.25, link_mass=0.75, link_inertia=0.7),
}


def truth(plant: dict) -> dict[str, float]:
    """The values the identification should find (read from the plant mapping)."""
    return {"K_c": plant["transmission"]["stiffness_Nm_rad"], "J_m": plant["input"]["motor_inertia_kg_m2"],
            "b_m": plant["input"]["motor_damping_Nms_rad"], "m_g_l": plant["output"]["link"]["m_g_l_Nm"],
            "J_l": plant["output"]["link"]["inertia_kg_m2"], "b_l": plant["output"]["link"]["damping_Nms_rad"],
            "mu": plant["transmission"]["mu"]}


def identify_plant(plant: dict, seed: int, limits=None, geometry_theta_rad: float = 3.0):
    """Held and free runs on the simulated rig of ``plant`` (sensor noise seeded ``seed``), then the fit.

    :returns: (RigIdentification, held columns, free columns)
    """
    from capstan.models.rig_id import ExcitationLimits, RigRun, free_excitation, held_excitation
    from capstan.models.rig_id.identify import RigGeometry, identify_rig

    lim = limits if limits is not None else ExcitationLimits()
    runs = {}
    for kind in ("held", "free"):
        rig = SimulatedRig.from_mapping({**plant, "seed": seed + (0 if kind == "held" else 1000)})
        exc = held_excitation(lim) if kind == "held" else free_excitation(lim)
        runs[kind] = run_excitation(rig, exc, kind == "held")
    r_in = r_out = 0.04
    ident = identify_rig(RigRun.from_arrays(runs["held"], r_in, r_out, f"held seed {seed}"),
                         RigRun.from_arrays(runs["free"], r_in, r_out, f"free seed {seed}"),
                         RigGeometry(r_in, r_out, geometry_theta_rad))
    return ident, runs["held"], runs["free"]


if __name__ == "__main__":      # the study of docs/results/rig-identification.md
    import json
    import sys

    seeds = range(int(sys.argv[1]) if len(sys.argv) > 1 else 5)
    out = {}
    for seed in seeds:
        for name, plant in VARIANTS.items():
            tr = truth(plant)
            ident, _, _ = identify_plant(plant, seed)
            d = ident.to_dict()
            row = {k: {"true": tr[k], "value": d[k]["value"], "stderr": d[k]["stderr"]}
                   for k in ("K_c", "J_m", "b_m", "m_g_l", "J_l", "b_l")}
            row["mu_theta"] = {"true": tr["mu"] * plant["routing"]["theta_rad"], "value": d["friction"]["mu_theta"]["value"],
                               "stderr": d["friction"]["mu_theta"]["stderr"]}
            row["tau_fc"] = {"value": d["friction"]["tau_fc"]["value"], "stderr": d["friction"]["tau_fc"]["stderr"]}
            out.setdefault(name, []).append(row)
            print(name, seed, json.dumps({k: [round(v["value"], 4), round(v["stderr"], 4)] for k, v in row.items()}),
                  flush=True)
            with open(sys.argv[2] if len(sys.argv) > 2 else "rig_id_study.json", "w") as fh:
                json.dump(out, fh, indent=1)
