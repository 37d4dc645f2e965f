"""The one cycle-record layout of the 1 kHz loop and the fault bits.

A cycle record is State + Measurements + Command of one control cycle, declared once
here as a flat numpy structured dtype (scalars only) so that the Numba step, the MCAP
schema, the CSV export and the replay all derive from the same list.

Who writes what, in cycle order:

1. the loop, before the step: ``cycle``, ``t_s`` and the measurement group
   (load cells, IMU, motor feedback, ``ext_fault_bits``, and ``tau_out_ref_Nm``, an
   optional output-torque reference on top of the gravity model, 0 in the interaction
   use case, a test signal on the testbed);
2. the step (:mod:`capstan.controller.law.step`): the controller group, ``tau_m_cmd_Nm`` and
   ``fault_bits``;
3. the loop, after the step: the timing group, and the loop gating (``phase``: whether
   the step ran at all; ``cmd_scale``: the ramp-down factor it applied to the command).

Replay contract: the step reads only the measurement group, ``t_s`` and its own
config/state, so feeding logged measurements (stepping only where ``phase`` says the
loop did, and applying :func:`loop_command`) reproduces ``tau_m_cmd_Nm`` bit for bit.
"""

from __future__ import annotations

import math
from enum import IntFlag

import numpy as np


class FaultBits(IntFlag):
    """Latched fault causes (``fault_bits`` / ``ext_fault_bits`` of a record).

    Bits 0..7 are detected inside the step, bits 8..15 outside it (by the loop and the
    drivers, passed in through ``ext_fault_bits``).
    """

    NONE = 0
    NONFINITE_INPUT = 1 << 0      #: a measurement field is NaN/inf
    NONFINITE_OUTPUT = 1 << 1     #: the control law produced NaN/inf
    TORQUE_LIMIT = 1 << 2         #: raw demand beyond the hard torque limit
    TORQUE_RATE_LIMIT = 1 << 3    #: raw demand jumped faster than the hard rate limit
    STALE_IMU = 1 << 4            #: newest IMU sample older than the IMU timeout
    STALE_LOADCELL = 1 << 5       #: newest load-cell frame older than its timeout
    STALE_MOTOR = 1 << 6          #: newest drive feedback older than its timeout
    DRIVE_FAULT = 1 << 8          #: drive statusword fault bit or EMCY
    HEARTBEAT_LOST = 1 << 9       #: drive heartbeat missing
    OVERRUN_STREAK = 1 << 10      #: too many consecutive late cycles
    EXTERNAL_STOP = 1 << 11       #: operator / supervisor requested a stop
    LIMIT_VIOLATION = 1 << 12     #: joint angle/rate, motor speed or tension outside its limit
    DEVICE_LOST = 1 << 13         #: a device is gone (drive without heartbeat, rig process dead)


#: fields, in order: (name, numpy type, unit / meaning)
RECORD_FIELDS: tuple[tuple[str, str, str], ...] = (
    # ---- cycle (loop, before the step) ------------------------------------------
    ("cycle", "u8", "cycle index since start [-]"),
    ("t_s", "f8", "loop time of this cycle, monotonic [s]"),
    # ---- measurements (loop, before the step) -----------------------------------
    ("T_up_in_N", "f8", "upper cable tension at the input-side fixture [N]"),
    ("T_up_out_N", "f8", "upper cable tension at the output-side fixture [N]"),
    ("T_lo_out_N", "f8", "lower cable tension at the output-side fixture [N]"),
    ("T_lo_in_N", "f8", "lower cable tension at the input-side fixture [N]"),
    ("lc_t_s", "f8", "receive time of the newest load-cell frame [s]"),
    ("q_out_rad", "f8", "joint (link) angle from the IMU, 0 = hanging down [rad]"),
    ("dq_out_rad_s", "f8", "joint rate from the IMU rate of turn [rad/s]"),
    ("imu_t_s", "f8", "receive time of the newest IMU sample [s]"),
    ("imu_new", "u1", "1 if a new IMU sample arrived this cycle, else 0 [-]"),
    ("q_m_rad", "f8", "motor position [rad]"),
    ("dq_m_rad_s", "f8", "motor velocity [rad/s]"),
    ("tau_m_meas_Nm", "f8", "motor torque reported by the drive [Nm]"),
    ("motor_t_s", "f8", "receive time of the newest drive feedback [s]"),
    ("ext_fault_bits", "u4", "faults detected outside the step (FaultBits) [-]"),
    ("tau_out_ref_Nm", "f8", "extra output-torque reference added to the gravity model (0 = pure gravity compensation) [Nm]"),
    # ---- controller state / intermediates (step) --------------------------------
    ("tau_in_Nm", "f8", "measured input torque r_in (T_up_in - T_lo_in), filtered [Nm]"),
    ("T0_meas_N", "f8", "pretension estimate, mean of the four tensions [N]"),
    ("tau_g_Nm", "f8", "gravity model tau_g(q_out) (output side) [Nm]"),
    ("tau_fc_Nm", "f8", "friction feedforward tau_fc(dq_out), held between IMU samples [Nm]"),
    ("tau_in_des_Nm", "f8", "desired input torque [Nm]"),
    ("err_Nm", "f8", "torque error tau_in_des - tau_in [Nm]"),
    ("pd_Nm", "f8", "feedback term C(s) e (PD, or PID in the PID loop) [Nm]"),
    ("d_hat_Nm", "f8", "disturbance estimate of the LDO (0 in the PID loop) [Nm]"),
    ("tau_m_raw_Nm", "f8", "motor torque demand before the safety stage [Nm]"),
    # ---- command (step) ----------------------------------------------------------
    ("tau_m_cmd_Nm", "f8", "safe motor torque command sent to the drive [Nm]"),
    ("fault_bits", "u4", "latched fault bits (FaultBits); non-zero => command 0 [-]"),
    # ---- timing (loop, after the step) ------------------------------------------
    ("period_s", "f8", "measured period since the previous cycle [s]"),
    ("compute_s", "f8", "time spent from read to write in this cycle [s]"),
    ("late", "u1", "1 if this cycle missed its deadline [-]"),
    # ---- loop gating (loop, around the step) ------------------------------------
    ("phase", "u1", "loop phase at the step: 0 arming (no step, command 0), 1 running, 2 ramping down [-]"),
    ("cmd_scale", "f8", "factor the loop applied to the step's command (1 running, ramp fraction ramping, 0 arming) [-]"),
    # ---- wire values (loop, with the measurements): what the devices sent --------
    ("t_ns", "i8", "loop wake-up time, monotonic clock; t_s = t_ns * 1e-9 [ns]"),
    ("lc_up_in_mV_V", "f4", "upper input-side bridge signal as the amplifier sends it [mV/V]"),
    ("lc_up_out_mV_V", "f4", "upper output-side bridge signal [mV/V]"),
    ("lc_lo_out_mV_V", "f4", "lower output-side bridge signal [mV/V]"),
    ("lc_lo_in_mV_V", "f4", "lower input-side bridge signal [mV/V]"),
    ("lc_t_ns", "i8", "receive time of the newest load-cell frame [ns]"),
    ("imu_rate_rad_s", "f8", "IMU rate of turn about the joint axis as the sensor sends it (before the sign) [rad/s]"),
    ("imu_t_ns", "i8", "receive time of the newest IMU sample [ns]"),
    ("q_m_counts", "i4", "drive position feedback 0x6064 [counts]"),
    ("dq_m_units", "i4", "drive velocity feedback 0x606C [drive units]"),
    ("tau_m_meas_permille", "i2", "drive torque feedback 0x6077 [per mille of the rated torque]"),
    ("motor_t_ns", "i8", "receive time of the newest drive feedback [ns]"),
)

#: the flat structured dtype of one cycle record
RECORD_DTYPE = np.dtype([(name, typ) for name, typ, _ in RECORD_FIELDS])

#: field name -> unit / meaning (for MCAP schema descriptions and CSV headers)
RECORD_UNITS: dict[str, str] = {name: doc for name, _, doc in RECORD_FIELDS}

#: the measurement fields the loop writes before the step (the replay inputs)
MEASUREMENT_FIELDS: tuple[str, ...] = (
    "t_s", "T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N", "lc_t_s",
    "q_out_rad", "dq_out_rad_s", "imu_t_s", "imu_new",
    "q_m_rad", "dq_m_rad_s", "tau_m_meas_Nm", "motor_t_s", "ext_fault_bits", "tau_out_ref_Nm",
)

#: the fields the step writes
STEP_OUTPUT_FIELDS: tuple[str, ...] = (
    "tau_in_Nm", "T0_meas_N", "tau_g_Nm", "tau_fc_Nm", "tau_in_des_Nm", "err_Nm", "pd_Nm",
    "d_hat_Nm", "tau_m_raw_Nm", "tau_m_cmd_Nm", "fault_bits",
)


#: the loop gating fields (written around the step; replay inputs as well)
LOOP_GATING_FIELDS: tuple[str, ...] = ("phase", "cmd_scale")

#: float64 fields the daemon's log stores as float32 (protobuf ``float``, read back as
#: float64). Nothing the step or the replay reads is among them, nor the command:
#:
#: * the step's intermediates and state (``tau_in_Nm`` ... ``tau_m_raw_Nm``): a replay
#:   recomputes them bit for bit from the logged inputs and config, so the log keeps a
#:   copy for plotting (rounded to :data:`LOG_FLOAT32_QUANTA`) and loses no information;
#: * ``period_s`` and ``compute_s``: the loop's own timing (differences of integer
#:   nanosecond clock readings), not read by the step or the replay; stored rounded to
#:   :data:`LOG_FLOAT32_QUANTA` (2**-20 s = 0.95 us): the nanoseconds below it are the
#:   clock read's own cost and scheduling noise (the loop is judged on microsecond
#:   jitter), and cost 3.2 B per cycle of a 69 B cycle.
#:
#: Together they save about 27 bytes per cycle after compression, 148 -> 121 B
#: (``tools/bench/logs.py`` with and without ``--all-float64``); ``tau_m_cmd_Nm``
#: stays float64, the replay compares it.
LOG_FLOAT32_FIELDS: tuple[str, ...] = (
    "tau_in_Nm", "T0_meas_N", "tau_g_Nm", "tau_fc_Nm", "tau_in_des_Nm", "err_Nm", "pd_Nm",
    "d_hat_Nm", "tau_m_raw_Nm", "period_s", "compute_s",
)

#: quantum (a power of two, in the field's unit) each step intermediate is rounded to in
#: the live log before its float32 cast, so its low mantissa bits are zero and it
#: compresses. The step's intermediates are display copies: a replay recomputes them bit
#: for bit (and ``capstan archive`` checks the recomputed values against these stored
#: ones); the loop's timing fields are stored as rounded (0.95 us). Torques:
#: 2**-12 Nm = 0.24 mNm, 1/80 of the drive's torque step (1 per mille of a 20 Nm rated
#: torque) and about 1/70 of the torque noise of the tension measurement (0.3 N on
#: 40 mm pulleys, both cables); the pretension ``T0_meas_N``: 2**-8 N = 3.9 mN, 1/77 of
#: the load-cell noise. The rounding adds at most half a quantum (rms quantum/sqrt(12)).
#: Measured values and the command are never rounded by the log (the command is on the
#: law's own grid, ``controller.safety.command_quantum_Nm``, and stored as float64).
LOG_FLOAT32_QUANTA: dict[str, float] = {
    **{f: 2.0 ** -12 for f in ("tau_in_Nm", "tau_g_Nm", "tau_fc_Nm", "tau_in_des_Nm", "err_Nm", "pd_Nm",
                                "d_hat_Nm", "tau_m_raw_Nm")},
    "T0_meas_N": 2.0 ** -8,
    "period_s": 2.0 ** -20, "compute_s": 2.0 ** -20,
}

#: SI measurement field -> the wire field the driver computes it from (with the
#: driver's conversion, :mod:`capstan.models.common.wire_units`). The live log stores
#: the wire field only; a reader rebuilds the SI field bit for bit.
DERIVED_FROM_WIRE: dict[str, str] = {
    "t_s": "t_ns",
    "T_up_in_N": "lc_up_in_mV_V", "T_up_out_N": "lc_up_out_mV_V",
    "T_lo_out_N": "lc_lo_out_mV_V", "T_lo_in_N": "lc_lo_in_mV_V", "lc_t_s": "lc_t_ns",
    "dq_out_rad_s": "imu_rate_rad_s", "imu_t_s": "imu_t_ns",
    "q_m_rad": "q_m_counts", "dq_m_rad_s": "dq_m_units", "tau_m_meas_Nm": "tau_m_meas_permille",
    "motor_t_s": "motor_t_ns",
}

#: ``phase`` of a cycle in which the loop did not step the controller (arming)
PHASE_ARMING = 0


def loop_command(tau_step_Nm: float, cmd_scale: float, fault_bits: int) -> float:
    """The command the loop sends, from the step's command: scaled by the loop's gating
    factor, zero on any fault bit (step or loop) or a non-finite value.

    The daemon and the replay both use this, so a replay reproduces the sent command
    bit for bit.
    """
    tau = tau_step_Nm * cmd_scale
    if fault_bits or not math.isfinite(tau):
        return 0.0
    return tau


def new_record() -> np.ndarray:
    """A zeroed record array of shape (1,) and dtype :data:`RECORD_DTYPE`."""
    return np.zeros(1, dtype=RECORD_DTYPE)


def fault_names(bits: int) -> str:
    """Readable ``"STALE_IMU|TORQUE_LIMIT"`` form of fault bits (``"NONE"`` if 0)."""
    if int(bits) == 0:
        return "NONE"
    names = [f.name for f in FaultBits if f.value and (int(bits) & f.value) and f.name]
    rest = int(bits) & ~sum(f.value for f in FaultBits)
    if rest:
        names.append(hex(rest))
    return "|".join(names)
