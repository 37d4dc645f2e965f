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
   ``dtau_max_Nm_s * dt_s`` per cycle (saturation, not a fault), then rounded to a
   multiple of ``safety.command_quantum_Nm`` (default :data:`COMMAND_QUANTUM_NM`,
   2**-16 Nm = 15 uNm) inside those limits.

Why the command is quantised: the drive takes its target torque (0x6071) in per mille of
the rated torque, 20 mNm on a 20 Nm motor, 1300 quanta; below that the float64 command
only carried rounding noise of the filters, which is what the live log spent 8 bytes per
cycle on (the command is stored exactly, as float64, because replay compares it bit for
bit). A power of two leaves the low mantissa bits zero, so the stored command
compresses, and division and multiplication by it are exact, so the rounding is the
same in the daemon and in a replay. The observer's ``tau_m[k-1]`` is the rounded
command, as the drive gets it.

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

#: the command's resolution [Nm]: 2**-16 Nm, 1/1300 of the drive's torque step (1 per mille
#: of a 20 Nm rated torque); a power of two (see the module docstring)
COMMAND_QUANTUM_NM = 2.0 ** -16


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
                     dtau_max_step_Nm: float, quantum_Nm: float = COMMAND_QUANTUM_NM) -> float:
    """Clamp to ``+-tau_max_Nm``, limit the change from the previous command, then round
    to the nearest multiple of ``quantum_Nm`` (a power of two; 0: no rounding) that keeps
    both limits [Nm].

    The rounding moves the command by at most half a quantum (7.6 uNm), or by less than
    one quantum where the nearest multiple would cross a limit that is not itself a
    multiple (limits narrower than a quantum are not supported: the command then keeps
    the nearest multiple).
    """
    rate_lo, rate_hi = tau_prev_cmd_Nm - dtau_max_step_Nm, tau_prev_cmd_Nm + dtau_max_step_Nm
    tau = min(max(min(max(tau_raw_Nm, -tau_max_Nm), tau_max_Nm), rate_lo), rate_hi)
    lo, hi = max(rate_lo, -tau_max_Nm), min(rate_hi, tau_max_Nm)    # both limits, for the rounding
    q = quantum_Nm
    if q <= 0.0:
        return tau
    g = math.floor(tau / q + 0.5) * q
    if g > hi and g - q >= lo:
        g -= q
    elif g < lo and g + q <= hi:
        g += q
    return g
