"""The composed 1 kHz control step: measurements -> LDO/PID + gravity + friction
feedforward -> safety stage -> motor torque command.

``control_step(cfg, st, rec)`` is a pure function of the flat config array ``cfg``
(coefficients computed once in Python, :func:`capstan.controller.law.core.pack_config`), the flat
state array ``st`` and the measurement fields of the record ``rec`` (shape (1,),
:data:`capstan.controller.law.records.RECORD_DTYPE`); it writes the state, the record's controller
fields and returns the safe command [Nm]. Allocation-free, ``@njit(cache=True)``.

Control law (per cycle, ``k``)::

    tau_in   = F[ r_in (T_up_in - T_lo_in) ]             F: 1st-order low-pass (load-cell noise)
    T0       = mean of the four tensions                 pretension estimate (§4.4.1)
    tau_g    = m_g_l sin(q_g)                            models.link.gravity_hold_torque_Nm, q_g: q_out
                                                         blended with the integrated gyro rate above
                                                         filters.q_out_blend_hz (AHRS angle noise 5e-4 rad
                                                         made the command's only high-frequency content at rest)
    tau_fc   = gain * (g(dq_out) eq21(dq_out; c_fc T0) + tau_e)   only when imu_new, held otherwise;
                                                         g: rest gate (feedforward.dead_band_rad_s)
                                                         tau_e: learned effects (controller.learned_effects)
    tau_out_des = tau_g + tau_out_ref + g_fb J_lc (r_in/r_out) A_l[g a]   link inertia compensation
                                   (feedback.link_inertia_comp_kg_m2; a the link's acceleration at the
                                   motor side, g as J_c's below, A_l a 1st-order low-pass at
                                   feedback.link_inertia_cutoff_hz times a 1st-order high-pass at
                                   feedback.link_inertia_highpass_hz: the strokes' band; the grip modes
                                   (4-8 Hz) pass less, and the lag that would undamp the free link's
                                   slow mode (0.2-0.5 Hz) is turned into a lead)
    tau_in_des = (r_in/r_out) (tau_out_des [+ tau_fc if placement = reference])
    e        = tau_in_des - tau_in
    C e      = kp e - D tau_in     derivative on the measurement only: the reference jumps
                                   at 400 Hz (feedforward) and a derivative on it would kick
               + k_b BP[e]         band gain (feedback.band_gain, faded like kp): BP a 4th-order
                                   band-pass over the strokes' band (feedback.band_low_hz-band_high_hz,
                                   shipped 0.3-2 Hz), 0 at DC
    tau_out_des += g_fb k_o LP[e_out]   output torque gain (feedback.output_torque_gain, faded like kp):
                                   e_out = tau_out_des - r_out (T_up_out - T_lo_out), the hand's
                                   torque less the link's uncompensated inertia torque, LP feedback.output_torque_cutoff_hz;
                                   x (1 + g BP[.]), a peak at feedback.output_torque_peak_hz (g output_torque_peak_gain);
                                   at rest (g_fb = 0) nothing, so load-cell noise stays off the command
    LDO:  tau_m = C e + tau_in_des + d_hat [+ tau_fc if placement = motor]      eq (28)
          d_hat = -Q F P^-1 tau_in + Q F tau_m[k-1]                              eq (27)
    PID:  tau_m = tau_in_des + kp e + ki int(e) - D tau_in [+ tau_fc if placement = motor]
    both: tau_m += J_c A[g a]      inertia compensation (feedback.inertia_comp_kg_m2): a the
                                   link's (IMU rate, per sample) or the motor's velocity v_m's backward
                                   difference / dt (the motor's: x g_fb, faded with kp and b, below),
                                   A a 1st-order low-pass
                                   (feedback.acceleration_cutoff_hz); the loop then
                                   sees J_m - J_c (controller/law/loop_model.py checks it);
                                   g the feedforward's rest gate on dq_out (opening on the second IMU
                                   sample in a row outside it), on the filter's input so that the
                                   gate does not step the command: the differentiated gyro noise
                                   (0.14 rad/s^2 std after 5 Hz) stays off the command at rest
    both: tau_m -= g_fb b (v_m - LP[g' (r_out/r_in) dq_out] - D[tau_in_des - (r_in/r_out) tau_g] / K_c)
                                   deflection-rate damping
                                   (feedback.deflection_damping_Nms_rad): v_m the motor's velocity
                                   (every cycle; feedback.motor_velocity: observer, from the encoder's
                                   position and the torques on the motor, controller.law.motor_velocity;
                                   or the drive's 0x606C), the link's velocity per IMU sample, held,
                                   low-passed (feedback.deflection_link_cutoff_hz) plus its lag x the
                                   link's acceleration (deflection_link_lag_compensation); g' = 1 with the
                                   rest gate g_fb below, else g (at rest the link's rate is gyro
                                   noise: 0); D the rate of the
                                   reference low-passed (feedback.deflection_reference_cutoff_hz),
                                   K_c plant.stiffness_Nm_rad. It damps the motor
                                   against the cable (stick / sheath-stick modes, which a delayed kp
                                   drives), is 0 in a steady motion and does not brake the deflection
                                   the reference asks for (a load change along a stroke)
    g_fb: 1, or with feedback.rest_gate_cutoff_hz > 0 the debounced rest gate low-passed at
          that cutoff, on kp e and on the damping: at rest neither load-cell noise x kp nor the
          encoder velocity's quantisation x b reaches the command

``tau_m[k-1]`` is the command actually applied in the previous cycle (after safety), so
clamping and rate limiting do not wind the observer up.

Signal conditioning, and why:

* ``tau_in``: a first-order low-pass (default 150 Hz) on the load-cell difference. Q P^-1
  has a high-frequency gain of ``w_c^2 J_m / K_c`` (12 at 10 Hz), so white load-cell noise
  would reach the command amplified; the observer's ``tau_m`` input passes the same filter
  so the two observer paths stay consistent.
* ``q_out``: used as sampled (AHRS orientation, ~5e-4 rad noise: 2 mNm of gravity torque).
* ``dq_out``: the gyro's rate of turn, not a differentiated angle, so no derivative filter;
  its noise (~2e-3 rad/s) is far below the Stribeck velocity but not below the tanh width
  (1/alpha = 0.02 rad/s): at rest tanh(alpha dq) followed the noise and flipped the
  friction torque's sign at 400 Hz, which the delayed loop amplified into a buzz. The
  feedforward is therefore multiplied by a rest gate: 0 below 0.8 x dead_band (default
  10 mrad/s, 5 sigma of the gyro noise: a sample of noise reaches 4 sigma once in ~16000),
  1 above the band, linear in between, so eq (21) is unchanged once the joint moves and
  motion onset gets the full friction as soon as the rate leaves the noise.
  Evaluated only on a new IMU sample (400 Hz) and held, as in the paper, then slew-limited to
  ``feedforward.max_rate_Nm_s`` (200 Nm/s: a 3.4 Nm flip at a fast reversal takes 17 ms
  instead of one cycle, which hit the command's 2 Nm/cycle clamp in HIL with a hand).
* pretension ``T0``: the plain mean of the four tensions (noise / 2); it enters the
  friction magnitude linearly (0.3 N noise -> < 0.1 % of tau_fc).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from capstan.controller.law.feedforward import friction_feedforward_Nm, rest_gate
from capstan.controller.law.learned_effects import N_FX_STATE, learned_effects_Nm
from capstan.controller.law.ldo import biquad_init, biquad_init_steady, biquad_step, lowpass_step
from capstan.controller.law.observer.motor_velocity import HISTORY, observer_step
from capstan.controller.law.safety import input_fault_bits, limit_command_Nm, output_fault_bits
from capstan.models.transmission.link import gravity_hold_torque_Nm

# ---------------------------------------------------------------- config array layout
C_DT = 0
C_LOOP_LDO = 1          # 1.0 = LDO, 0.0 = PID
C_Q = 2                 # 5 coefficients b0 b1 b2 a1 a2 of Q(z)
C_QP = 7                # 5 coefficients of Q P^-1 (z)
C_F_ALPHA = 12          # tau_in low-pass pole (0 = off)
C_KP = 13
C_KD_B0 = 14
C_KD_A1 = 15
C_KI_DT = 16            # ki * dt
C_I_LIM = 17
C_G_ON = 18
C_MGL = 19
C_FF_ON = 20
C_FF_MOTOR = 21         # 1.0 = placement motor, 0.0 = reference
C_FF_GAIN = 22
C_FF_NM_PER_N = 23      # nominal friction torque per N of pretension
C_FF_FIXED = 24         # 1.0 = fixed pretension
C_FF_T0_FIXED = 25
C_ZETA_S = 26
C_ZETA_C = 27
C_ETA_S = 28
C_ALPHA_S = 29
C_B_VIS = 30
C_R_IN = 31
C_R_RATIO = 32          # r_in / r_out
C_TAU_MAX = 33
C_DTAU_MAX_STEP = 34    # dtau_max * dt
C_TAU_FAULT = 35
C_DTAU_FAULT_STEP = 36  # dtau_fault * dt
C_IMU_TIMEOUT = 37
C_LC_TIMEOUT = 38
C_MOTOR_TIMEOUT = 39
C_FF_DEAD_BAND = 40     # rest band of the feedforward's velocity [rad/s]
C_QB_ALPHA = 41         # pole of the complementary filter of q_out (0 = off)
C_JC = 42               # inertia compensation J_c [kg m^2] (0 = off)
C_ACC_ALPHA = 43        # pole of the acceleration low-pass
C_ACC_LINK = 44         # 1.0 = link acceleration from the IMU rate, 0.0 = motor from dq_m
C_FF_SLEW_STEP = 45     # largest change of the feedforward per cycle [Nm] (feedforward.max_rate_Nm_s x dt)
C_DEFL_B = 46           # damping of the deflection rate [Nm s/rad] (feedback.deflection_damping_Nms_rad; 0 = off)
C_DEFL_ALPHA = 47       # pole of the low-pass on the link's velocity in it (feedback.deflection_link_cutoff_hz)
C_DEFL_REF_ALPHA = 48   # pole of the low-pass on tau_in_des whose rate it subtracts (deflection_reference_cutoff_hz)
C_DEFL_K_INV = 49       # 1 / plant.stiffness_Nm_rad [rad/Nm]: the deflection rate the reference asks for
C_FBG_ON = 50           # 1.0 = kp and the deflection damping act only in motion (feedback.rest_gate_cutoff_hz > 0)
C_FBG_ALPHA = 51        # pole of the low-pass that fades them in and out
C_DEFL_LEAD = 52        # lead on the link's velocity in the damping [s] (0 = off): + lead x the link acceleration
C_CMD_QUANTUM = 53      # the command's resolution [Nm] (safety.command_quantum_Nm; 0 = float64 as computed)
C_BAND_GAIN = 54        # extra gain on the error in a band [Nm/Nm] (feedback.band_gain; 0 = off)
C_BAND_SOS = 55         # 2 x 5 coefficients of its band-pass (two biquads, ldo.band_pass_sos)
C_OUT_GAIN = 65         # gain on the output torque's error [Nm/Nm] (feedback.output_torque_gain; 0 = off)
C_OUT_ALPHA = 66        # pole of its low-pass (feedback.output_torque_cutoff_hz)
C_R_OUT = 67            # output pulley radius [m]: tau_out = r_out (T_up_out - T_lo_out)
C_OUT_PEAK_ON = 68      # 1.0 = its peak filter is on (feedback.output_torque_peak_gain > 0)
C_OUT_PEAK = 69         # 5 coefficients b0 b1 b2 a1 a2 of its peak filter 1 + g BP (ldo.output_peak_biquad)
C_JLC = 74              # link inertia compensation J_lc [kg m^2] (feedback.link_inertia_comp_kg_m2; 0 = off)
C_JLC_ALPHA = 75        # pole of its low-pass on the link's acceleration (feedback.link_inertia_cutoff_hz)
C_JLC_HP_ALPHA = 76     # pole of its high-pass (feedback.link_inertia_highpass_hz)
C_VOBS_ON = 77          # 1.0 = the motor's velocity from its position (feedback.motor_velocity observer), 0.0 = drive's
C_VOBS_K = 78           # the observer's 3 gains (controller.law.motor_velocity.observer_gains)
C_VOBS_DELAY = 81       # which past command acts on the motor now: u[k-1-d], d = stability.io_delay_cycles (<= 3)
C_VOBS_J_INV = 82       # 1 / the observer's motor inertia [1/(kg m^2)] (feedback_config.observer_inertia_kg_m2)
N_CFG = 83              # fixed part; the learned-effects block follows (controller.learned_effects)

# ---------------------------------------------------------------- state array layout
S_STARTED = 0           # 0 until the first cycle initialised the filters
S_Q = 1                 # 2 biquad states: Q on F tau_m[k-1]
S_QP = 3                # 2 biquad states: Q P^-1 on F tau_in
S_F_TIN = 5             # low-pass state of tau_in
S_F_TM = 6              # low-pass state of tau_m[k-1] (observer path)
S_TIN_PREV = 7          # previous filtered tau_in (derivative on measurement)
S_D = 8                 # filtered derivative output
S_INT = 9               # integral term (PID) [Nm]
S_CMD_PREV = 10         # command applied in the previous cycle [Nm]
S_RAW_PREV = 11         # previous raw demand [Nm]
S_FC_HELD = 12          # friction feedforward held between IMU samples [Nm]
S_FAULT = 13            # latched fault bits (as float64, exact)
S_FX = 14               # N_FX_STATE states of the learned effects (controller.learned_effects)
S_QF = S_FX + N_FX_STATE  # blended joint angle for the gravity model [rad]
S_FF_OUT = S_QF + 1       # 1.0 if the previous IMU rate was outside the rest gate's lower edge
                          # (one debounce for the feedforward and the inertia compensation)
S_V_PREV = S_FF_OUT + 1    # previous velocity sample [rad/s] (acceleration estimate)
S_ACC = S_V_PREV + 1       # filtered acceleration [rad/s^2]
S_ACC_RAW = S_ACC + 1      # last raw difference quotient, held between IMU samples [rad/s^2]
S_ACC_N = S_ACC_RAW + 1    # cycles since the previous IMU sample
S_GATE = S_ACC_N + 1       # the debounced rest gate, held between IMU samples (read by the inertia
                           # compensation and by the fade of kp and the damping)
S_FC_OUT = S_GATE + 1  # the feedforward after its slew limit [Nm]
S_DEFL_IN = S_FC_OUT + 1   # gated link velocity at the motor [rad/s], held between IMU samples
S_DEFL_LINK = S_DEFL_IN + 1  # ... low-passed: the motor velocity the link's motion implies [rad/s]
S_DEFL_REF = S_DEFL_LINK + 1  # low-passed tau_in_des [Nm] (NaN until the first cycle set it)
S_FBG = S_DEFL_REF + 1     # the held rest gate low-passed: the factor on kp and b
S_VM_PREV = S_FBG + 1      # previous motor velocity [rad/s] (J_c from the motor's acceleration)
S_ACC_M = S_VM_PREV + 1    # the motor's filtered acceleration [rad/s^2] (J_c's, acceleration_source motor)
S_BAND = S_ACC_M + 1       # 2 x 2 biquad states of the band-pass on the error (NaN until the first cycle set them)
S_OUT_E = S_BAND + 4       # low-passed output torque error [Nm] (NaN until the first cycle set it)
S_OUT_PEAK = S_OUT_E + 1   # 2 biquad states of its peak filter (NaN until the first cycle set them)
S_ACC_JLC = S_OUT_PEAK + 2  # the link's acceleration low-passed for the link inertia compensation [rad/s^2]
S_ACC_JLC_HP = S_ACC_JLC + 1  # ... and its low-pass at the high-pass's corner (high-pass = x - that) [rad/s^2]
S_VOBS = S_ACC_JLC_HP + 1  # the motor velocity observer's position, velocity and acceleration estimates
S_U_HIST = S_VOBS + 3      # the commands u[k-1] ... u[k-HISTORY] [Nm] (the observer's input)
N_STATE = S_U_HIST + HISTORY


@njit(cache=True)
def control_step(cfg: np.ndarray, st: np.ndarray, rec: np.ndarray) -> float:
    """One control cycle; returns the safe motor torque command [Nm] (0.0 when faulted)."""
    r = rec[0]
    bits = input_fault_bits(rec, cfg[C_IMU_TIMEOUT], cfg[C_LC_TIMEOUT], cfg[C_MOTOR_TIMEOUT])

    # ---- measurements -> signals
    tau_in_raw = cfg[C_R_IN] * (r.T_up_in_N - r.T_lo_in_N)
    t0_meas = 0.25 * (r.T_up_in_N + r.T_up_out_N + r.T_lo_out_N + r.T_lo_in_N)
    alpha = cfg[C_F_ALPHA]
    if st[S_STARTED] == 0.0:
        st[S_F_TIN] = tau_in_raw
        st[S_F_TM] = st[S_CMD_PREV]
        biquad_init(cfg, C_QP, st, S_QP, tau_in_raw)
        biquad_init(cfg, C_Q, st, S_Q, st[S_CMD_PREV])
        st[S_D] = 0.0
        st[S_TIN_PREV] = tau_in_raw
        st[S_INT] = 0.0
        st[S_RAW_PREV] = math.nan
        st[S_QF] = r.q_out_rad
        st[S_FF_OUT] = 1.0 if rest_gate(r.dq_out_rad_s, cfg[C_FF_DEAD_BAND]) > 0.0 else 0.0
        st[S_V_PREV] = r.dq_out_rad_s
        st[S_VOBS] = r.q_m_rad
        st[S_VOBS + 1] = 0.0 if cfg[C_VOBS_ON] != 0.0 else r.dq_m_rad_s
        st[S_VOBS + 2] = 0.0
        for j in range(HISTORY):
            st[S_U_HIST + j] = st[S_CMD_PREV]
        st[S_VM_PREV] = st[S_VOBS + 1]
        st[S_ACC_M] = 0.0
        st[S_ACC] = 0.0
        st[S_ACC_RAW] = 0.0
        st[S_ACC_N] = 0.0
        st[S_ACC_JLC] = 0.0
        st[S_ACC_JLC_HP] = 0.0
        st[S_GATE] = 0.0
        st[S_FC_OUT] = 0.0
        # a start in motion: the link-implied velocity starts where the link is (gated as below), so
        # the damping does not kick by -b dq_m on the first cycle
        g0 = 1.0 if cfg[C_FBG_ON] != 0.0 else rest_gate(r.dq_out_rad_s, cfg[C_FF_DEAD_BAND])
        st[S_DEFL_IN] = g0 * r.dq_out_rad_s / cfg[C_R_RATIO]
        st[S_DEFL_LINK] = st[S_DEFL_IN]
        st[S_DEFL_REF] = math.nan
        st[S_FBG] = 0.0
        st[S_BAND] = math.nan
        st[S_OUT_E] = math.nan
        st[S_OUT_PEAK] = math.nan
        st[S_STARTED] = 1.0
    tau_in = lowpass_step(alpha, st, S_F_TIN, tau_in_raw)
    # the motor's velocity (damping, J_c from the motor): from its position and the torques on it, or the drive's
    v_m = r.dq_m_rad_s
    if cfg[C_VOBS_ON] != 0.0:
        acc_in = (st[S_U_HIST + int(cfg[C_VOBS_DELAY])] - tau_in_raw) * cfg[C_VOBS_J_INV]
        v_m = observer_step(st, S_VOBS, r.q_m_rad, acc_in, cfg[C_DT], cfg[C_VOBS_K], cfg[C_VOBS_K + 1],
                            cfg[C_VOBS_K + 2])

    # ---- references
    qb = cfg[C_QB_ALPHA]        # complementary filter: angle below the blend frequency, gyro above
    q_g = qb * (st[S_QF] + r.dq_out_rad_s * cfg[C_DT]) + (1.0 - qb) * r.q_out_rad
    st[S_QF] = q_g
    tau_g = gravity_hold_torque_Nm(cfg[C_MGL], q_g) if cfg[C_G_ON] != 0.0 else 0.0
    # the rest gate on dq_out (feedforward, inertia compensation, fade of kp and b), on each new IMU
    # sample: it opens only on the second sample in a row outside its lower edge, so one noise
    # sample beyond 4 sigma (once in ~16000) cannot kick the command; onset waits 2.5 ms
    gate = 0.0
    if r.imu_new != 0 and (cfg[C_FF_ON] != 0.0 or cfg[C_JC] != 0.0 or cfg[C_JLC] != 0.0 or cfg[C_DEFL_B] != 0.0
                           or cfg[C_FBG_ON] != 0.0):
        g_now = rest_gate(r.dq_out_rad_s, cfg[C_FF_DEAD_BAND])
        gate = g_now if st[S_FF_OUT] != 0.0 else 0.0
        st[S_FF_OUT] = 1.0 if g_now > 0.0 else 0.0
        st[S_GATE] = gate
    if cfg[C_FF_ON] != 0.0 and r.imu_new != 0:
        t0 = cfg[C_FF_T0_FIXED] if cfg[C_FF_FIXED] != 0.0 else t0_meas
        fc = gate * friction_feedforward_Nm(
            r.dq_out_rad_s, cfg[C_FF_NM_PER_N] * t0, cfg[C_ZETA_S], cfg[C_ZETA_C], cfg[C_ETA_S], cfg[C_ALPHA_S],
            cfg[C_B_VIS])
        if cfg[N_CFG] != 0.0:   # load: the input torque asked for without the effects (no algebraic loop)
            load = cfg[C_R_RATIO] * (tau_g + r.tau_out_ref_Nm + fc)
            fc += learned_effects_Nm(cfg, N_CFG, st, S_FX, r.t_s, r.q_out_rad, r.dq_out_rad_s, load, t0_meas)
        st[S_FC_HELD] = cfg[C_FF_GAIN] * fc
    # slew limit: at a fast reversal eq (21) flips 2 x 1.7 Nm within one IMU sample (tanh width
    # 1/alpha = 20 mrad/s), a step past the command's rate clamp; spread over max_rate_Nm_s instead
    fc_target = st[S_FC_HELD] if cfg[C_FF_ON] != 0.0 else 0.0
    tau_fc = st[S_FC_OUT] + min(max(fc_target - st[S_FC_OUT], -cfg[C_FF_SLEW_STEP]), cfg[C_FF_SLEW_STEP])
    st[S_FC_OUT] = tau_fc
    g_fb = 1.0          # the factor on kp, the band gain, the damping and the output torque's gain:
    if cfg[C_FBG_ON] != 0.0:    # 1, or the faded rest gate
        g_fb = lowpass_step(cfg[C_FBG_ALPHA], st, S_FBG, st[S_GATE])
    # the accelerations: a low-passed difference quotient, gated on the filter's input by the feedforward's
    # debounced rest gate on the joint rate, held (0 at rest: one gyro-noise sample beyond 4 sigma would otherwise
    # pass J_c x the differentiated noise for a sample); opening and closing (a reversal passes the rest band in
    # 1-3 IMU samples) reach the command through the low-pass, not as a step of J_c x a
    acc = 0.0       # (r_out / r_in) x the link's, from the IMU rate: J_c's with the link source, the lead's
    acc_lp = (cfg[C_JC] != 0.0 and cfg[C_ACC_LINK] != 0.0) or cfg[C_DEFL_LEAD] != 0.0   # J_lc filters the raw one
    if acc_lp or cfg[C_JLC] != 0.0:
        st[S_ACC_N] += 1.0
        if r.imu_new != 0:
            st[S_ACC_RAW] = (r.dq_out_rad_s - st[S_V_PREV]) / (st[S_ACC_N] * cfg[C_DT] * cfg[C_R_RATIO])
            st[S_V_PREV] = r.dq_out_rad_s
            st[S_ACC_N] = 0.0
        if acc_lp:
            acc = lowpass_step(cfg[C_ACC_ALPHA], st, S_ACC, st[S_GATE] * st[S_ACC_RAW])
    acc_m = 0.0     # the motor's, every cycle (acceleration_source motor): the loop then sees J_m - J_c, which
    if cfg[C_JC] != 0.0 and cfg[C_ACC_LINK] == 0.0:     # without the deflection damping rings the stick mode: faded
        acc_m = lowpass_step(cfg[C_ACC_ALPHA], st, S_ACC_M, st[S_GATE] * (v_m - st[S_VM_PREV]) / cfg[C_DT])
        st[S_VM_PREV] = v_m
    ff_motor = cfg[C_FF_MOTOR] != 0.0
    # + g_fb J_lc (r_in / r_out) a: a share of the link's own inertia torque asked of the cable, from the link's
    # acceleration whatever J_c's source (held by a firm grip, the link does not accelerate; the motor does)
    tau_link = 0.0
    if cfg[C_JLC] != 0.0:
        a_l = lowpass_step(cfg[C_JLC_ALPHA], st, S_ACC_JLC, st[S_GATE] * st[S_ACC_RAW])
        a_l -= lowpass_step(cfg[C_JLC_HP_ALPHA], st, S_ACC_JLC_HP, a_l)
        tau_link = g_fb * cfg[C_JLC] * cfg[C_R_RATIO] * a_l
    tau_out_des = tau_g + r.tau_out_ref_Nm + tau_link
    if cfg[C_OUT_GAIN] != 0.0:  # + g_fb k_o LP[e_out]: the output torque asked for less the measured one,
        # the hand's torque less the link's inertia torque; raised in the reference, it divides what the
        # transmission and the motor add to the link's own impedance by (1 + k_o)
        e_out = tau_out_des - cfg[C_R_OUT] * (r.T_up_out_N - r.T_lo_out_N)
        if math.isnan(st[S_OUT_E]):
            st[S_OUT_E] = e_out
        e_lp = lowpass_step(cfg[C_OUT_ALPHA], st, S_OUT_E, e_out)
        if cfg[C_OUT_PEAK_ON] != 0.0:   # x (1 + g BP): more gain where the strokes swing the link on the hand
            if math.isnan(st[S_OUT_PEAK]):  # (~2 Hz), ~x1 at the grip and two-mass modes (4-13 Hz)
                biquad_init_steady(cfg, C_OUT_PEAK, st, S_OUT_PEAK, e_lp)
            e_lp = biquad_step(cfg, C_OUT_PEAK, st, S_OUT_PEAK, e_lp)
        tau_out_des += g_fb * cfg[C_OUT_GAIN] * e_lp
    if not ff_motor:
        tau_out_des += tau_fc
    tau_in_des = cfg[C_R_RATIO] * tau_out_des

    # ---- feedback
    e = tau_in_des - tau_in
    deriv = -cfg[C_KD_A1] * st[S_D] - cfg[C_KD_B0] * (tau_in - st[S_TIN_PREV])
    st[S_D] = deriv
    st[S_TIN_PREV] = tau_in
    fb = g_fb * cfg[C_KP] * e + deriv
    if cfg[C_BAND_GAIN] != 0.0:     # + g_fb k_b BP[e]: loop gain in the strokes' band (0 at DC)
        if math.isnan(st[S_BAND]):
            biquad_init_steady(cfg, C_BAND_SOS + 5, st, S_BAND + 2,
                               biquad_init_steady(cfg, C_BAND_SOS, st, S_BAND, e))
        y = biquad_step(cfg, C_BAND_SOS + 5, st, S_BAND + 2, biquad_step(cfg, C_BAND_SOS, st, S_BAND, e))
        fb += g_fb * cfg[C_BAND_GAIN] * y

    # ---- torque loop
    d_hat = 0.0
    if cfg[C_LOOP_LDO] != 0.0:
        tm_f = lowpass_step(alpha, st, S_F_TM, st[S_CMD_PREV])
        d_hat = -biquad_step(cfg, C_QP, st, S_QP, tau_in) + biquad_step(cfg, C_Q, st, S_Q, tm_f)
        tau_raw = fb + tau_in_des + d_hat
    else:
        if st[S_FAULT] == 0.0:
            lim = cfg[C_I_LIM]
            st[S_INT] = min(max(st[S_INT] + cfg[C_KI_DT] * e, -lim), lim)
        fb += st[S_INT]
        tau_raw = fb + tau_in_des
    if ff_motor:
        tau_raw += tau_fc
    # inertia compensation: g J_c a (a, acc_m above)
    if cfg[C_JC] != 0.0:
        tau_raw += cfg[C_JC] * acc if cfg[C_ACC_LINK] != 0.0 else g_fb * cfg[C_JC] * acc_m
    if cfg[C_DEFL_B] != 0.0:    # damping of the deflection rate: the motor's velocity less the one the
        if r.imu_new != 0:      # link's implies ((r_out / r_in) dq_out, low-passed). At rest the gyro's noise
            # is kept off by g_fb; without it (rest_gate_cutoff_hz 0), by gating the link's rate like J_c. Not
            # both: at a reversal the link passes the rest band while the motor still moves, and the gated
            # link rate would step the term by b x dq_out (1.2 Nm in a slow HIL stroke)
            st[S_DEFL_IN] = (1.0 if cfg[C_FBG_ON] != 0.0 else gate) * r.dq_out_rad_s / cfg[C_R_RATIO]
        # low-passed, and led by the low-pass's and the hold's lag times the link's acceleration (its S_ACC,
        # gated at rest; feedback.deflection_link_lag_compensation)
        v_link = lowpass_step(cfg[C_DEFL_ALPHA], st, S_DEFL_LINK, st[S_DEFL_IN]) + cfg[C_DEFL_LEAD] * st[S_ACC]
        # the deflection rate the reference asks for, d/dt LP[tau_in_des - gravity] / K: the gravity
        # model's rate is m_g_l dq_out, positive feedback of the link's velocity that would undamp the
        # free link (loop_model.deflection_reference_filter)
        ref_in = tau_in_des - cfg[C_R_RATIO] * tau_g
        if math.isnan(st[S_DEFL_REF]):
            st[S_DEFL_REF] = ref_in
        ref_prev = st[S_DEFL_REF]
        v_ref = (lowpass_step(cfg[C_DEFL_REF_ALPHA], st, S_DEFL_REF, ref_in) - ref_prev) * cfg[C_DEFL_K_INV] / cfg[C_DT]
        tau_raw -= g_fb * cfg[C_DEFL_B] * (v_m - v_link - v_ref)

    # ---- safety stage
    bits |= output_fault_bits(tau_raw, st[S_RAW_PREV], cfg[C_TAU_FAULT], cfg[C_DTAU_FAULT_STEP])
    st[S_RAW_PREV] = tau_raw
    latched = int(st[S_FAULT]) | bits
    st[S_FAULT] = float(latched)
    if latched != 0:
        cmd = 0.0
    else:
        cmd = limit_command_Nm(tau_raw, st[S_CMD_PREV], cfg[C_TAU_MAX], cfg[C_DTAU_MAX_STEP], cfg[C_CMD_QUANTUM])
    st[S_CMD_PREV] = cmd
    for j in range(HISTORY - 1, 0, -1):
        st[S_U_HIST + j] = st[S_U_HIST + j - 1]
    st[S_U_HIST] = cmd

    # ---- record
    r.tau_in_Nm = tau_in
    r.T0_meas_N = t0_meas
    r.tau_g_Nm = tau_g
    r.tau_fc_Nm = tau_fc
    r.tau_in_des_Nm = tau_in_des
    r.err_Nm = e
    r.pd_Nm = fb
    r.d_hat_Nm = d_hat
    r.tau_m_raw_Nm = tau_raw
    r.tau_m_cmd_Nm = cmd
    r.fault_bits = latched
    return cmd


@njit(cache=True)
def reset_state(st: np.ndarray) -> None:
    """Zero the state: filters re-initialise on the next cycle, fault latch cleared."""
    for i in range(st.shape[0]):
        st[i] = 0.0
