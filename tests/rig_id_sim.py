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


def run_excitation(rig: SimulatedRig, exc: Excitation, held: bool) -> dict[str, np.ndarray]:
    """Run ``exc`` on ``rig`` at its dt (from the rig's current state) and return the record columns.

    The command of cycle i is computed from the motor feedback of cycle i - 1 and acts during
    cycle i (the rig has no further delay of its own).
    """
    exc.reset()
    n = exc.n_cycles
    cols = {k: np.empty(n) for k in ("t_s", "q_m_rad", "dq_m_rad_s", "tau_m_cmd_Nm", "T_up_in_N", "T_up_out_N",
                                     "T_lo_out_N", "T_lo_in_N", "q_out_rad", "dq_out_rad_s", "imu_new")}
    q_m, dq_m, _ = rig.motor_feedback()
    t0 = rig.t_s
    for i in range(n):
        tau = exc.torque_Nm(i * exc.dt_s, q_m, dq_m)
        ext = -CLAMP_K_NM_RAD * rig.model.q_out_rad - CLAMP_B_NMS_RAD * rig.model.dq_out_rad_s if held else 0.0
        rig.step(tau, ext, exc.dt_s)
        q_m, dq_m, _ = rig.motor_feedback()
        lc = rig.load_cells_N()
        new, q_o, dq_o = rig.imu_sample()
        cols["t_s"][i] = rig.t_s - t0
        cols["q_m_rad"][i], cols["dq_m_rad_s"][i], cols["tau_m_cmd_Nm"][i] = q_m, dq_m, tau
        cols["T_up_in_N"][i], cols["T_up_out_N"][i], cols["T_lo_out_N"][i], cols["T_lo_in_N"][i] = lc
        cols["q_out_rad"][i], cols["dq_out_rad_s"][i], cols["imu_new"][i] = q_o, dq_o, float(new)
    return cols
