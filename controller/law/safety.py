"""The fixed safety stage run after every control step (Numba, allocation-free).

Order of checks in one cycle:

1. inputs: every measurement field finite (``NONFINITE_INPUT``); sensor ages
   ``t_s - *_t_s`` within their timeouts (``STALE_IMU``, ``STALE_LOADCELL``,
   ``STALE_MOTOR``); ``ext_fault_bits`` from the loop/drivers are ORed in;
2. output: raw demand finite (``NONFINITE_OUTPUT``), ``|tau_raw| <= tau_fault_Nm``
   (``TORQUE_LIMIT``), ``|tau_raw - tau_raw_prev| <= dtau_fault_Nm_s * dt_s``
   (``TORQUE_RATE_LIMIT``);
3. latch: any bit is ORed into the latched fault word; while it is non-zero the command
   is exactly 0.0 from this very cycle on, until :func:`capstan.controller.law.core.Controller.reset`;
4. otherwise the command is clamped to ``+-tau_max_Nm`` and rate limited to
   ``dtau_max_Nm_s * dt_s`` per cycle (saturation, not a fault).

The fault limits (2) sit above the clamps (4): saturating is normal operation, a demand
beyond the hard limits means the control law or its inputs went wrong.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from capstan.controller.law.records import FaultBits

_NONFINITE_INPUT = int(FaultBits.NONFINITE_INPUT)
_NONFINITE_OUTPUT = int(FaultBits.NONFINITE_OUTPUT)
_TORQUE_LIMIT = int(FaultBits.TORQUE_LIMIT)
_TORQUE_RATE_LIMIT = int(FaultBits.TORQUE_RATE_LIMIT)
_STALE_IMU = int(FaultBits.STALE_IMU)
_STALE_LOADCELL = int(FaultBits.STALE_LOADCELL)
_STALE_MOTOR = int(FaultBits.STALE_MOTOR)


@njit(cache=True)
def input_fault_bits(rec: np.ndarray, imu_timeout_s: float, loadcell_timeout_s: float,
                     motor_timeout_s: float) -> int:
    """Fault bits of this cycle's measurements (finite checks, staleness, external bits)."""
    r = rec[0]
    bits = int(r.ext_fault_bits)
    ok = (math.isfinite(r.t_s) and math.isfinite(r.T_up_in_N) and math.isfinite(r.T_up_out_N)
          and math.isfinite(r.T_lo_out_N) and math.isfinite(r.T_lo_in_N) and math.isfinite(r.lc_t_s)
          and math.isfinite(r.q_out_rad) and math.isfinite(r.dq_out_rad_s) and math.isfinite(r.imu_t_s)
          and math.isfinite(r.q_m_rad) and math.isfinite(r.dq_m_rad_s) and math.isfinite(r.tau_m_meas_Nm)
          and math.isfinite(r.motor_t_s) and math.isfinite(r.tau_out_ref_Nm))
    if not ok:
        bits |= _NONFINITE_INPUT
    # "not (age <= timeout)" also flags a NaN age
    if not (r.t_s - r.imu_t_s <= imu_timeout_s):
        bits |= _STALE_IMU
    if not (r.t_s - r.lc_t_s <= loadcell_timeout_s):
        bits |= _STALE_LOADCELL
    if not (r.t_s - r.motor_t_s <= motor_timeout_s):
        bits |= _STALE_MOTOR
    return bits


@njit(cache=True)
def output_fault_bits(tau_raw_Nm: float, tau_raw_prev_Nm: float, tau_fault_Nm: float,
                      dtau_fault_step_Nm: float) -> int:
    """Fault bits of the raw demand (finite, hard torque limit, hard per-cycle jump)."""
    if not math.isfinite(tau_raw_Nm):
        return _NONFINITE_OUTPUT
    bits = 0
    if abs(tau_raw_Nm) > tau_fault_Nm:
        bits |= _TORQUE_LIMIT
    if math.isfinite(tau_raw_prev_Nm) and abs(tau_raw_Nm - tau_raw_prev_Nm) > dtau_fault_step_Nm:
        bits |= _TORQUE_RATE_LIMIT
    return bits


@njit(cache=True)
def limit_command_Nm(tau_raw_Nm: float, tau_prev_cmd_Nm: float, tau_max_Nm: float,
                     dtau_max_step_Nm: float) -> float:
    """Clamp to ``+-tau_max_Nm``, then limit the change from the previous command [Nm]."""
    tau = min(max(tau_raw_Nm, -tau_max_Nm), tau_max_Nm)
    lo = tau_prev_cmd_Nm - dtau_max_step_Nm
    hi = tau_prev_cmd_Nm + dtau_max_step_Nm
    return min(max(tau, lo), hi)
