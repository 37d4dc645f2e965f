"""The Python-facing controller object used by the 1 kHz loop, replay and experiments.

Usage in a loop (nothing here allocates per cycle)::

    ctl = Controller(ControllerConfig.from_mapping(cfg["controller"]))
    ctl.warmup()                      # compile + exercise the Numba step before the loop
    rec = ctl.record[0]               # a view; write the measurement fields
    rec["t_s"] = now; rec["T_up_in_N"] = ...; rec["imu_new"] = 1; ...
    tau_m = ctl.step()                # safe motor torque command [Nm], 0.0 when faulted
    if ctl.faulted: ...               # ctl.fault_bits says why; ctl.reset() re-arms

The step is a pure function of (config array, state array, measurement fields of the
record): replaying logged measurements through a fresh ``Controller`` with the logged
config reproduces ``tau_m_cmd_Nm`` bit for bit.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from capstan.controller.law.config import AccelerationSource, ControllerConfig, Placement, PretensionSource, TorqueLoop
from capstan.controller.law.feedforward import friction_torque_per_N
from capstan.controller.law.learned_effects import pack_block
from capstan.controller.law.ldo import (band_pass_sos, derivative_filter_coefficients, lowpass_alpha,
                                        output_peak_biquad, q_filter_coefficients, qpinv_filter_coefficients)
from capstan.controller.law.feedback_config import deflection_link_lead_s, observer_inertia_kg_m2
from capstan.controller.law.observer.motor_velocity import HISTORY, MotorVelocitySource, observer_gains
from capstan.controller.law.records import FaultBits, new_record
from capstan.controller.law import step as _s


def pack_config(cfg: ControllerConfig) -> np.ndarray:
    """The flat float64 config array of :mod:`capstan.controller.law.step` (all coefficients), with
    the learned effects of the feedforward packed after ``N_CFG``
    (:func:`capstan.controller.law.learned_effects.pack_block`).

    :raises ModelError: if the friction magnitude cannot be computed from the routing.
    :raises ConfigError: if a learned effect entry is malformed.
    """
    c = np.zeros(_s.N_CFG)
    dt = cfg.dt_s
    p = cfg.plant
    c[_s.C_DT] = dt
    c[_s.C_LOOP_LDO] = 1.0 if cfg.torque_loop == TorqueLoop.LDO else 0.0
    bq, aq = q_filter_coefficients(cfg.q_cutoff_hz, dt)
    bp, ap = qpinv_filter_coefficients(cfg.q_cutoff_hz, dt, p.stiffness_Nm_rad, p.motor_inertia_kg_m2,
                                       p.motor_damping_Nms_rad)
    c[_s.C_Q:_s.C_Q + 5] = (bq[0], bq[1], bq[2], aq[1], aq[2])
    c[_s.C_QP:_s.C_QP + 5] = (bp[0], bp[1], bp[2], ap[1], ap[2])
    c[_s.C_F_ALPHA] = lowpass_alpha(cfg.tau_in_cutoff_hz, dt)
    fb = cfg.feedback
    c[_s.C_KP] = fb.kp
    c[_s.C_KD_B0], c[_s.C_KD_A1] = derivative_filter_coefficients(fb.kd_s, fb.derivative_cutoff_hz, dt)
    c[_s.C_KI_DT] = fb.ki_1_s * dt
    c[_s.C_BAND_GAIN] = fb.band_gain
    c[_s.C_BAND_SOS:_s.C_BAND_SOS + 10] = band_pass_sos(fb.band_low_hz, fb.band_high_hz, dt).ravel()
    c[_s.C_OUT_GAIN] = fb.output_torque_gain
    c[_s.C_OUT_ALPHA] = lowpass_alpha(fb.output_torque_cutoff_hz, dt)
    c[_s.C_R_OUT] = p.r_out_m
    c[_s.C_OUT_PEAK_ON] = 1.0 if fb.output_torque_peak_gain > 0.0 else 0.0
    c[_s.C_OUT_PEAK:_s.C_OUT_PEAK + 5] = output_peak_biquad(fb.output_torque_peak_gain, fb.output_torque_peak_hz,
                                                            fb.output_torque_peak_q, dt)
    c[_s.C_JLC] = fb.link_inertia_comp_kg_m2
    c[_s.C_JLC_ALPHA] = lowpass_alpha(fb.link_inertia_cutoff_hz, dt)
    c[_s.C_JLC_HP_ALPHA] = lowpass_alpha(fb.link_inertia_highpass_hz, dt)
    c[_s.C_JC] = fb.inertia_comp_kg_m2
    c[_s.C_ACC_ALPHA] = lowpass_alpha(fb.acceleration_cutoff_hz, dt)
    c[_s.C_ACC_LINK] = 1.0 if fb.acceleration_source == AccelerationSource.LINK else 0.0
    c[_s.C_VOBS_ON] = 1.0 if fb.motor_velocity == MotorVelocitySource.OBSERVER else 0.0
    c[_s.C_VOBS_K:_s.C_VOBS_K + 3] = observer_gains(fb.motor_velocity_observer_hz, fb.motor_velocity_bias_hz, dt)
    c[_s.C_VOBS_DELAY] = min(cfg.stability.io_delay_cycles, HISTORY - 1)
    c[_s.C_VOBS_J_INV] = 1.0 / observer_inertia_kg_m2(cfg)
    c[_s.C_DEFL_B] = fb.deflection_damping_Nms_rad
    c[_s.C_DEFL_ALPHA] = lowpass_alpha(fb.deflection_link_cutoff_hz, dt)
    c[_s.C_DEFL_REF_ALPHA] = lowpass_alpha(fb.deflection_reference_cutoff_hz, dt)
    c[_s.C_DEFL_K_INV] = 1.0 / p.stiffness_Nm_rad
    c[_s.C_FBG_ON] = 1.0 if fb.rest_gate_cutoff_hz > 0.0 else 0.0
    c[_s.C_FBG_ALPHA] = lowpass_alpha(fb.rest_gate_cutoff_hz, dt)
    c[_s.C_DEFL_LEAD] = deflection_link_lead_s(cfg)
    c[_s.C_I_LIM] = fb.integral_limit_Nm
    c[_s.C_G_ON] = 1.0 if cfg.gravity_enabled else 0.0
    c[_s.C_MGL] = cfg.m_g_l_Nm
    ff = cfg.feedforward
    c[_s.C_FF_ON] = 1.0 if ff.enabled else 0.0
    c[_s.C_FF_MOTOR] = 1.0 if ff.placement == Placement.MOTOR else 0.0
    c[_s.C_FF_GAIN] = ff.gain
    c[_s.C_FF_NM_PER_N] = friction_torque_per_N(ff, p.r_out_m)
    c[_s.C_FF_FIXED] = 1.0 if ff.pretension == PretensionSource.FIXED else 0.0
    c[_s.C_FF_T0_FIXED] = ff.T0_fixed_N
    c[_s.C_ZETA_S] = ff.zeta_s
    c[_s.C_ZETA_C] = ff.zeta_c
    c[_s.C_ETA_S] = ff.eta_s_rad_s
    c[_s.C_ALPHA_S] = ff.alpha_s_rad
    c[_s.C_B_VIS] = ff.b_vis_Nms_rad
    c[_s.C_R_IN] = p.r_in_m
    c[_s.C_R_RATIO] = p.r_in_m / p.r_out_m
    sf = cfg.safety
    c[_s.C_TAU_MAX] = sf.tau_max_Nm
    c[_s.C_DTAU_MAX_STEP] = sf.dtau_max_Nm_s * dt
    c[_s.C_CMD_QUANTUM] = sf.command_quantum_Nm
    c[_s.C_TAU_FAULT] = sf.tau_fault_Nm
    c[_s.C_DTAU_FAULT_STEP] = sf.dtau_fault_Nm_s * dt
    c[_s.C_IMU_TIMEOUT] = sf.imu_timeout_s
    c[_s.C_LC_TIMEOUT] = sf.loadcell_timeout_s
    c[_s.C_MOTOR_TIMEOUT] = sf.motor_timeout_s
    c[_s.C_FF_DEAD_BAND] = ff.dead_band_rad_s
    c[_s.C_FF_SLEW_STEP] = ff.max_rate_Nm_s * dt
    c[_s.C_QB_ALPHA] = lowpass_alpha(cfg.q_out_blend_hz, dt)
    return np.concatenate((c, pack_block(ff.effects, *ff.effects_shape)))


@njit(cache=True)
def _step_many(cfg: np.ndarray, st: np.ndarray, records: np.ndarray, indices: np.ndarray) -> None:
    for k in range(indices.shape[0]):
        i = indices[k]
        _s.control_step(cfg, st, records[i:i + 1])


class Controller:
    """Config + state + one preallocated cycle record around the Numba step.

    :param cfg: the frozen controller configuration.
    :raises ModelError: if the feedforward's friction magnitude cannot be computed.
    """

    def __init__(self, cfg: ControllerConfig) -> None:
        self.cfg = cfg
        self.cfg_array = pack_config(cfg)
        self.state = np.zeros(_s.N_STATE)
        self.record = new_record()

    @property
    def friction_torque_per_N(self) -> float:
        """Nominal friction torque per Newton of pretension used by the feedforward [Nm/N]."""
        return float(self.cfg_array[_s.C_FF_NM_PER_N])

    def step(self) -> float:
        """Run one cycle on the measurement fields of :attr:`record`.

        :returns: the safe motor torque command [Nm] (exactly 0.0 while faulted).
        """
        return _s.control_step(self.cfg_array, self.state, self.record)

    def step_many(self, records: np.ndarray, indices: np.ndarray) -> None:
        """Run the step on ``records[i]`` for each ``i`` of ``indices`` in order, in one
        compiled loop (offline replay): the same step, state and arithmetic as
        :meth:`step` per record, each record's controller fields written in place.

        :param records: structured array of :attr:`record`'s dtype.
        :param indices: int64 record indices, increasing.
        """
        _step_many(self.cfg_array, self.state, records, np.ascontiguousarray(indices, dtype=np.int64))

    def reset(self) -> None:
        """Clear the state and the fault latch; filters re-initialise on the next step."""
        _s.reset_state(self.state)

    @property
    def fault_bits(self) -> FaultBits:
        """The latched fault bits."""
        return FaultBits(int(self.state[_s.S_FAULT]))

    @property
    def faulted(self) -> bool:
        """True while a fault is latched (the command is 0)."""
        return self.state[_s.S_FAULT] != 0.0

    def warmup(self, cycles: int = 50) -> None:
        """Compile (or load from cache) and exercise the step on synthetic healthy
        measurements, then reset state and record. Call before the real-time loop."""
        rec = self.record[0]
        for k in range(cycles):
            t = 1.0 + k * self.cfg.dt_s
            rec["cycle"] = k
            rec["t_s"] = t
            for name in ("T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N"):
                rec[name] = 150.0
            rec["lc_t_s"] = t
            rec["imu_t_s"] = t
            rec["motor_t_s"] = t
            rec["imu_new"] = 1 if k % 2 == 0 else 0
            rec["q_out_rad"] = 0.1
            rec["dq_out_rad_s"] = 0.01
            self.step()
        self.reset()
        self.record[:] = np.zeros(1, dtype=self.record.dtype)
