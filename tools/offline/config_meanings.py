"""One line of meaning per configuration key: the only hand-written part of docs/configuration.md.

Keys are dotted paths as the parsers read them (list entries as ``[]``). Type, unit, range and
default come from the code (:mod:`capstan.tools.commands.config_reference`); no line here
states a default, so the two cannot disagree.
"""

from __future__ import annotations

#: a short paragraph above each top-level section's table
SECTIONS_INTRO: dict[str, str] = {
    "controller": "The 1 kHz control law (`controller/law/`): the nominal plant, the torque loop's gains, "
                  "filters, gravity model, friction feedforward, the safety stage and what the start-up "
                  "stability check assumes. `config/controller.yaml` is a commented example.",
    "motor": "The CiA 402 drive over CANopen (`drivers/canopen/`); `backend: canopen`. "
             "`config/motor.yaml` is a commented example; bring-up: docs/drive-bring-up.md.",
    "imu": "The Xsens MTi on a serial port (`drivers/serial/xsens*.py`); `backend: xsens`. "
           "Bring-up: docs/imu-bring-up.md.",
    "load_cells": "The four-channel load-cell amplifier on a serial port (`drivers/serial/loadcell*.py`); "
                  "`backend: serial`.",
    "logging": "The MCAP log and its writer process (`controller/log/`); see docs/logs.md.",
    "realtime": "Scheduling of the daemon process (`controller/runtime/realtime.py`).",
    "loop": "Pacing, start-up, shutdown and the per-cycle limits of the daemon loop.",
    "lab_override": "Runs a config outside the plausible ranges or the loop margins on purpose; the reason "
                    "is stored with the config in every log.",
    "hil": "Only for `capstan hil`: the simulated rig process (`tools/hil/`, `models/plant/`).",
}

MEANINGS: dict[str, str] = {
    # ---------------------------------------------------------------- controller
    "controller": "the control law",
    "controller.dt_s": "control period of the step",
    "controller.torque_loop": "low-level torque loop: `pid` (PID on the τ_in error) or `ldo` (the paper's "
                              "disturbance observer, eqs 26–28)",
    "controller.plant": "nominal plant K_c / (J_m s² + B_m s + K_c) of the observer and the loop check",
    "controller.plant.stiffness_Nm_rad": "K_c, static torsional stiffness of the transmission",
    "controller.plant.motor_inertia_kg_m2": "J_m, motor-side inertia",
    "controller.plant.motor_damping_Nms_rad": "B_m, motor-side viscous damping",
    "controller.plant.r_in_m": "input pulley radius: τ_in = r_in (T_up_in − T_lo_in)",
    "controller.plant.r_out_m": "output pulley radius",
    "controller.ldo": "the disturbance observer (torque_loop: ldo)",
    "controller.ldo.q_cutoff_hz": "cutoff of the observer's 2nd-order Butterworth Q(s)",
    "controller.feedback": "C(s) on the τ_in error and the terms added to the command",
    "controller.feedback.kp": "proportional gain on the τ_in error",
    "controller.feedback.kd_s": "derivative gain (on the measured τ_in only)",
    "controller.feedback.derivative_cutoff_hz": "first-order filter of the derivative",
    "controller.feedback.ki_1_s": "integral gain, PID loop only",
    "controller.feedback.integral_limit_Nm": "anti-windup clamp of the integral term",
    "controller.feedback.inertia_comp_kg_m2": "J_c: + J_c × acceleration on the command, off at rest (0 = off)",
    "controller.feedback.acceleration_cutoff_hz": "first-order low-pass of the differentiated rate for J_c",
    "controller.feedback.acceleration_source": "where J_c's acceleration comes from: `motor` (drive velocity, "
                                               "every cycle) or `link` (IMU rate, per sample)",
    "controller.feedback.motor_velocity": "the motor velocity the deflection damping and J_c (from the motor) read: "
                                          "`observer` (from the encoder position 0x6064 and the torques on the "
                                          "motor, controller/law/observer/motor_velocity.py) or `drive` (0x606C as the drive "
                                          "forms it)",
    "controller.feedback.motor_velocity_observer_hz": "the velocity observer's error dynamics (double pole)",
    "controller.feedback.motor_velocity_bias_hz": "pole of the observer's unexplained-acceleration state "
                                                  "(friction, load-cell offsets, J_m's error)",
    "controller.feedback.motor_velocity_inertia_factor": "the observer's model inertia as a multiple of "
                                                         "plant.motor_inertia_kg_m2",
    "controller.feedback.deflection_damping_Nms_rad": "b: − b × (motor rate − the rate the link's motion and the "
                                                      "reference imply), damps the cable's deflection (0 = off)",
    "controller.feedback.deflection_link_cutoff_hz": "low-pass of the link's rate inside the deflection damping",
    "controller.feedback.deflection_reference_cutoff_hz": "low-pass of τ_in_des (less gravity) before its rate "
                                                          "is taken in the deflection damping",
    "controller.feedback.deflection_link_lag_compensation": "lead the link's rate in the damping by its "
                                                            "low-pass lag × the link acceleration",
    "controller.feedback.rest_gate_cutoff_hz": "kp, b, the band gain and k_o act only in motion, faded in and "
                                               "out at this cutoff (0 = always on)",
    "controller.feedback.band_gain": "+ gain × band-pass of the τ_in error (faded like kp; 0 = off)",
    "controller.feedback.band_low_hz": "lower edge of the band gain's band-pass",
    "controller.feedback.band_high_hz": "upper edge of the band gain's band-pass",
    "controller.feedback.output_torque_gain": "k_o: + k_o × low-pass of the output-torque error (output load "
                                              "cells), faded like kp (0 = off)",
    "controller.feedback.output_torque_cutoff_hz": "low-pass of the output-torque error",
    "controller.feedback.output_torque_peak_gain": "× (1 + gain × unit band-pass) on the output-torque term "
                                                   "(0 = off)",
    "controller.feedback.output_torque_peak_hz": "centre frequency of that peak",
    "controller.feedback.output_torque_peak_q": "quality factor of that peak",
    "controller.feedback.link_inertia_comp_kg_m2": "J_lc: + J_lc × band-passed link acceleration on the output "
                                                   "torque asked for (0 = off)",
    "controller.feedback.link_inertia_cutoff_hz": "low-pass edge of J_lc's band-pass",
    "controller.feedback.link_inertia_highpass_hz": "high-pass edge of J_lc's band-pass",
    "controller.filters": "measurement filters",
    "controller.filters.tau_in_cutoff_hz": "first-order low-pass on τ_in (load-cell noise; 0 = off)",
    "controller.filters.q_out_blend_hz": "complementary filter of the gravity model's angle: IMU angle below, "
                                         "integrated gyro above (0 = raw angle)",
    "controller.gravity": "gravity compensation of the link",
    "controller.gravity.enabled": "add τ_g = m g l sin(q_out) to the reference",
    "controller.gravity.m_g_l_Nm": "m g l of the link",
    "controller.feedforward": "the reduced model's friction feedforward (eq 21)",
    "controller.feedforward.enabled": "add the friction feedforward",
    "controller.feedforward.placement": "`reference`: into τ_in_des | `motor`: added to τ_m, eq 28 as printed",
    "controller.feedforward.gain": "fraction of the model friction compensated",
    "controller.feedforward.mu": "sheath friction coefficient μ",
    "controller.feedforward.routing": "the sheath's routing: {length_m, theta_rad} (uniform bend), "
                                      "{curvature_profile, length_m} or {points_m, …} (models/transmission/routing.py)",
    "controller.feedforward.routing.length_m": "routing length",
    "controller.feedforward.routing.theta_rad": "total bend angle of a uniform routing",
    "controller.feedforward.pretension": "friction magnitude from the `measured` pretension (mean of the four "
                                         "load cells) or a `fixed` one",
    "controller.feedforward.T0_fixed_N": "pretension used when `pretension: fixed`",
    "controller.feedforward.eq25_reading": "averaged pretension T0_eq of eq 25: `friction_preserving` (twice the "
                                           "bending-weighted mean of the eq 23 field: keeps the distributed model's "
                                           "sliding friction) or `field_minimum` (2 T(s_min), eq 25 as printed)",
    "controller.feedforward.zeta_s": "static (sticky) friction factor ζ_s (≥ zeta_c)",
    "controller.feedforward.zeta_c": "Coulomb friction factor ζ_c",
    "controller.feedforward.eta_s_rad_s": "Stribeck velocity η_s",
    "controller.feedforward.alpha_s_rad": "steepness of the tanh direction term",
    "controller.feedforward.b_vis_Nms_rad": "viscous friction term",
    "controller.feedforward.dead_band_rad_s": "rest gate: feedforward × 0 below 0.8 × band, × 1 above the band "
                                              "(≥ 2 × stability.gyro_noise_rad_s)",
    "controller.feedforward.max_rate_Nm_s": "slew limit of the feedforward (a reversal's flip over several cycles)",
    "controller.feedforward.effects": "learned effects added to the friction torque: the `effects.yaml` fragment "
                                      "`capstan close` writes (format: models/closure/effects_runtime.py); [] = none",
    "controller.feedforward.effects_shape": "s(dq) of the baseline the effects were fitted on, and the rest "
                                            "threshold of their dwell signal",
    "controller.feedforward.effects_shape.alpha_s_rad": "tanh steepness of the effects' baseline (absent: the "
                                                        "feedforward's alpha_s_rad)",
    "controller.feedforward.effects_shape.eta_s_rad_s": "Stribeck velocity of the effects' baseline (absent: the "
                                                        "feedforward's eta_s_rad_s)",
    "controller.feedforward.effects_shape.zeta_s": "static factor of the effects' baseline (absent: the "
                                                   "feedforward's zeta_s; a fitted shape may be below 0)",
    "controller.feedforward.effects_shape.v_rest_rad_s": "below this |rate| the joint counts as resting for the "
                                                         "effects' dwell signal",
    "controller.safety": "the safety stage, applied every cycle",
    "controller.safety.tau_max_Nm": "command clamp (saturation, not a fault)",
    "controller.safety.dtau_max_Nm_s": "command rate clamp",
    "controller.safety.tau_fault_Nm": "raw demand beyond this latches TORQUE_LIMIT",
    "controller.safety.dtau_fault_Nm_s": "raw demand step beyond this × dt latches TORQUE_RATE_LIMIT",
    "controller.safety.imu_timeout_s": "STALE_IMU when the newest IMU sample is older",
    "controller.safety.loadcell_timeout_s": "STALE_LOADCELL when the newest load-cell frame is older",
    "controller.safety.motor_timeout_s": "STALE_MOTOR when the newest drive feedback is older",
    "controller.safety.command_quantum_Nm": "the command is rounded to this grid after its clamps (a power of "
                                            "two; 0 = as computed)",
    "controller.stability": "what the start-up loop check assumes and requires (controller/law/stability.py)",
    "controller.stability.io_delay_cycles": "command → measured effect beyond the zero-order hold",
    "controller.stability.encoder_counts_per_rev": "motor encoder resolution whose quantisation the loop model "
                                                   "carries to the command through the velocity observer",
    "controller.stability.stiffness_range_Nm_rad": "[low, high] K_c range the gains must be robust over",
    "controller.stability.inertia_tolerance": "J_m ± this fraction",
    "controller.stability.link_inertia_kg_m2": "the link's inertia (slip points, output free)",
    "controller.stability.link_damping_Nms_rad": "the link's damping",
    "controller.stability.link_stiffness_Nm_rad": "the link's gravity stiffness m g l at hanging",
    "controller.stability.stick_stiffness_factor": "input-side stiffness in sheath stick / K_c (N + 1 for an "
                                                   "N-node sheath)",
    "controller.stability.min_phase_margin_deg": "required phase margin",
    "controller.stability.min_gain_margin_dB": "required gain margin",
    "controller.stability.tension_noise_N": "load-cell noise per channel (std) for the noise gains",
    "controller.stability.gyro_noise_rad_s": "gyro noise (std)",
    "controller.stability.gravity_model_error": "fraction the gravity model's m g l may be off (slip points keep "
                                                "this residual of the link's gravity stiffness)",
    "controller.stability.grip_stiffness_Nm_rad": "a hand holding the link: extra slip points with these "
                                                  "stiffnesses ([] = not checked)",
    "controller.stability.grip_damping_Nms_rad": "the gripping hand's damping",
    "controller.stability.min_grip_phase_margin_deg": "required phase margin with a gripping hand",
    # ---------------------------------------------------------------- motor
    "motor": "the drive",
    "motor.backend": "`canopen`",
    "motor.interface": "python-can interface: `socketcan` on a rig, `capstan_unix` for the simulated bus",
    "motor.channel": "python-can channel (`can0`; `auto` in HIL)",
    "motor.bitrate": "CAN bit rate (ignored by virtual interfaces)",
    "motor.node_id": "the drive's CANopen node id",
    "motor.master_node_id": "node id of the daemon's own heartbeat (watched by the drive)",
    "motor.eds": "the drive's EDS/DCF: a shipped name (drivers/canopen/data/) or a path",
    "motor.mode": "`cst` (cyclic synchronous torque, mode 10) or `profile_torque` (mode 4)",
    "motor.encoder_counts_per_rev": "increments of 0x6064 per motor revolution",
    "motor.velocity_units_per_rev_s": "units of 0x606C per motor rev/s (counts/s: the encoder counts; rpm: 60)",
    "motor.units": "`check`: the units the drive reports (0x608F/0x6091/0x6092/0x60A8/0x60A9/0x6076) are checked "
                   "against the keys above and a mismatch refused; `write`: the config's units are written "
                   "to 0x60A8/0x60A9 first (docs/drive-bring-up.md)",
    "motor.gear_ratio": "motor revolutions per revolution of the reported shaft",
    "motor.rated_torque_Nm": "rated torque, the unit of 0x6071/0x6077 being 1/1000 of it (absent: read 0x6076)",
    "motor.max_torque_Nm": "commanded torque clamp; also written to 0x6072",
    "motor.cycle_period_s": "SYNC period = interpolation period 0x60C2",
    "motor.heartbeat_period_s": "period of the daemon's own heartbeat",
    "motor.drive_heartbeat_period_s": "drive heartbeat 0x1017; lost after 3 periods",
    "motor.consumer_timeout_s": "drive-side consumer time 0x1016: the drive stops this long after the daemon's "
                                "heartbeat ends",
    "motor.boot_timeout_s": "how long start-up waits for a booting drive",
    "motor.abort_connection_option": "0x6007: 1 fault, 2 disable voltage, 3 quick stop when the daemon's "
                                     "heartbeat stops (0 is refused)",
    "motor.comm_error_behaviour": "0x1029 sub 1 on a communication error: 0 pre-operational, 1 no change, 2 stopped",
    "motor.quick_stop_option": "0x605A, where the drive has it (CiA 402-2 codes 0..8)",
    "motor.shutdown_option": "0x605B, where the drive has it: 0 disable at once, 1 ramp down then disable",
    "motor.fault_reset_at_start": "reset a drive found in any FAULT at start-up (otherwise only the "
                                  "heartbeat-loss fault 0x8130 the daemon itself left)",
    # ---------------------------------------------------------------- imu
    "imu": "the IMU on the link",
    "imu.port": "serial device (`/dev/ttyUSB0`; `auto` in HIL)",
    "imu.baudrate": "running line rate; must carry the configured output",
    "imu.baud_search": "when the MTi does not answer at `baudrate`, search the standard rates and switch it",
    "imu.output_rate_hz": "orientation / rate-of-turn output rate (divides 400)",
    "imu.orientation": "orientation output: quaternion or Euler angles",
    "imu.precision": "number format of orientation and rate of turn",
    "imu.coordinates": "coordinate system of the orientation output",
    "imu.joint_axis": "sensor axis aligned with the joint",
    "imu.sign": "+1 or −1: the joint's direction relative to the sensor axis",
    "imu.offset_rad": "joint angle when the twist about the axis is zero",
    "imu.timeout_s": "wait for each acknowledgement during set-up",
    "imu.retries": "attempts per handshake step (and rounds of the rate search)",
    # ---------------------------------------------------------------- load cells
    "load_cells": "the load-cell amplifier",
    "load_cells.port": "serial device (`/dev/ttyUSB1`; `auto` in HIL)",
    "load_cells.baudrate": "line rate; at least 10 bits × 19 bytes × 1000 frames/s",
    "load_cells.scale_N_per_mV_V": "per-channel sensitivity (one number or four)",
    "load_cells.offset_N": "per-channel offset added after scaling (one number or four)",
    "load_cells.tare_N": "per-channel tare subtracted (replaced when tare_samples > 0)",
    "load_cells.tare_samples": "frames averaged at start-up to set the tare (0 = keep tare_N)",
    "load_cells.timeout_s": "wait for the first frames at start-up",
    # ---------------------------------------------------------------- logging
    "logging": "the MCAP log",
    "logging.dir": "directory of the logs; relative to the config file's folder's parent",
    "logging.ring_records": "capacity of the shared-memory ring between loop and writer",
    "logging.fault_history_cycles": "cycles attached to a fault event (the last N)",
    "logging.on_writer_loss": "a dead writer: `restart` (new writer, new file, the gap as an event) or `stop` "
                              "(ramp the torque to zero, exit 3)",
    "logging.max_writer_restarts": "writer deaths tolerated under `restart`; one more stops the loop",
    "logging.rotate_size_MB": "start a new file at this size (0 = never)",
    "logging.rotate_age_s": "start a new file after this long (0 = never)",
    "logging.keep_newest_GB": "delete the oldest logs beyond this total (0 = keep all)",
    # ---------------------------------------------------------------- realtime
    "realtime": "scheduling",
    "realtime.mode": "`off`, `warn` (use what is permitted, say what is not) or `enforce` (refuse to start "
                     "without it)",
    "realtime.priority": "SCHED_FIFO priority of the loop",
    "realtime.helper_priority": "SCHED_FIFO priority of the process's other threads",
    "realtime.cpus": "CPUs to pin the loop to ([] = leave the affinity alone)",
    "realtime.lock_memory": "mlockall the process",
    "realtime.gil_switch_interval_s": "sys.setswitchinterval (0 = leave as is)",
    # ---------------------------------------------------------------- loop
    "loop": "the daemon loop",
    "loop.period_s": "loop period (the same as controller.dt_s)",
    "loop.busy_tail_s": "busy-wait before each deadline",
    "loop.overrun_streak_fault": "this many late cycles in a row is a fault",
    "loop.sensor_fresh_s": "at start-up every device must have delivered data this recently",
    "loop.startup_timeout_s": "time for all devices to deliver fresh data, and the loop to hold its period, after enable",
    "loop.arm_on_time_cycles": "consecutive on-time cycles with fresh devices before the loop commands torque",
    "loop.ramp_down_s": "torque ramp to zero on SIGTERM/SIGINT",
    "loop.stats_interval_s": "period of the timing statistics record",
    "loop.limits": "limits checked every cycle; a violation is a fault",
    "loop.limits.q_out_min_rad": "lowest allowed joint angle",
    "loop.limits.q_out_max_rad": "highest allowed joint angle",
    "loop.limits.dq_out_max_rad_s": "largest allowed |joint rate|",
    "loop.limits.dq_m_max_rad_s": "largest allowed |motor velocity|",
    "loop.limits.tension_min_N": "lowest allowed cable tension (slack guard)",
    "loop.limits.tension_max_N": "highest allowed cable tension",
    # ---------------------------------------------------------------- lab_override
    "lab_override": "run outside the checks on purpose",
    "lab_override.reason": "why (required with either switch; stored in the log)",
    "lab_override.ranges": "accept values outside the plausible ranges",
    "lab_override.margins": "accept gains that miss the loop margins",
    # ---------------------------------------------------------------- hil
    "hil": "the simulated rig",
    "hil.period_s": "plant step and pacing period",
    "hil.max_catch_up_s": "longest interval integrated in one step after a stall",
    "hil.tau_ext": "an external sine torque on the link (a hand without impedance)",
    "hil.tau_ext.amplitude_Nm": "its amplitude",
    "hil.tau_ext.frequency_hz": "its frequency",
    "hil.drive": "the simulated drive",
    "hil.drive.rated_torque_Nm": "its rated torque (0x6076)",
    "hil.realtime": "scheduling of the plant process",
    "hil.realtime.mode": "`off`, `warn` or `enforce`",
    "hil.realtime.priority": "SCHED_FIFO priority of the plant process",
    "hil.realtime.cpus": "CPUs to pin the plant process to",
    "hil.imu": "the simulated MTi",
    "hil.imu.boot_baudrate": "line rate it boots at (a new unit's, so start-up searches the rate)",
    "hil.hand": "a hand moving the link from stop to stop through an impedance (absent: no hand)",
    "hil.hand.stiffness_Nm_rad": "K_h of the hand's impedance",
    "hil.hand.damping_Nms_rad": "B_h of the hand's impedance",
    "hil.hand.center_rad": "middle of the stroke",
    "hil.hand.amplitude_rad": "half the stroke",
    "hil.hand.targets_rad": "stroke end points, in turn ([] = center ∓ amplitude)",
    "hil.hand.moves_s": "stroke durations, in turn (raised-cosine velocity)",
    "hil.hand.rests_s": "rests before each stroke, in turn",
    "hil.hand.settle_s": "time after grabbing the handle left out of the statistics",
    "hil.hand.breakaway_window_s": "window after each stroke onset for the breakaway peak",
    "hil.plant": "the distributed plant (models/plant/; the scenario file's plant keys)",
    "hil.faults": "faults the simulated rig injects on its own (bring-up and fault tests)",
    "hil.faults.load_cells_silent_after_s": "the load-cell amplifier stops sending this long after the start",
    "hil.plant.sensors": "the simulated devices: `realistic` (default: the drive's 0x606C from 1 ms count "
                         "differences in its unit, load-cell scale/zero errors with drift, gyro bias and axis "
                         "tilt, a jittered lossy command path) or `ideal` (exact signals), or a mapping "
                         "(models/plant/sensors.py; sensor mistakes for bring-up tests under `mistakes`)",
    "hil.plant.seed": "sensor-noise seed",
    "hil.plant.imu_rate_hz": "the simulated IMU's sample rate",
    "hil.plant.effects": "physical effects the controller's model lacks (models/plant/rig_effects.py)",
    "hil.plant.effects[].amp": "dwell stiction: relative friction rise after a long rest",
    "hil.plant.effects[].tau_age_s": "dwell stiction: ageing time of the rise",
    "hil.plant.effects[].slide_rad": "dwell stiction: sliding distance over which the rise decays",
    "hil.plant.transmission": "the distributed model's transmission",
    "hil.plant.transmission.n_nodes": "number of friction nodes N along the sheath",
    "hil.plant.transmission.stiffness_Nm_rad": "K_c, static torsional stiffness",
    "hil.plant.transmission.mu": "sheath friction coefficient",
    "hil.plant.transmission.r_in_m": "input pulley radius",
    "hil.plant.transmission.r_out_m": "output pulley radius",
    "hil.plant.transmission.p": "exponent of the smooth Coulomb law",
    "hil.plant.transmission.b_node_Ns_m": "damping per node",
    "hil.plant.routing": "the sheath's routing (forms as controller.feedforward.routing)",
    "hil.plant.routing.length_m": "routing length",
    "hil.plant.routing.theta_rad": "total bend angle of a uniform routing",
    "hil.plant.pretension": "cable pretension: T0_N, or one per cable end",
    "hil.plant.pretension.T0_N": "pretension of all four cable ends",
    "hil.plant.pretension.upper_in_N": "upper cable, input end",
    "hil.plant.pretension.upper_out_N": "upper cable, output end",
    "hil.plant.pretension.lower_in_N": "lower cable, input end",
    "hil.plant.pretension.lower_out_N": "lower cable, output end",
    "hil.plant.output": "what the output drives: `testbed` (spring–damper) or `link` (a pendulum)",
    "hil.plant.output.mode": "`testbed` or `link`",
    "hil.plant.output.k_out_Nm_rad": "testbed environment stiffness (eq 22)",
    "hil.plant.output.b_out_Nms_rad": "testbed environment damping",
    "hil.plant.output.inertia_kg_m2": "testbed output inertia",
    "hil.plant.output.link": "the link in `link` mode",
    "hil.plant.output.link.inertia_kg_m2": "link inertia",
    "hil.plant.output.link.m_g_l_Nm": "link m g l",
    "hil.plant.output.link.damping_Nms_rad": "link damping",
    "hil.plant.input": "what drives the input: `torque` (ideal) or `motor` (an inertia)",
    "hil.plant.input.mode": "`torque` or `motor`",
    "hil.plant.input.motor_inertia_kg_m2": "the simulated motor's inertia",
    "hil.plant.input.motor_damping_Nms_rad": "the simulated motor's damping",
    "hil.plant.input.b_in_Nms_rad": "input damping of the torque-driven input",
    "hil.plant.noise": "sensor noise of the simulated devices",
    "hil.plant.noise.tension_N": "load-cell noise (std)",
    "hil.plant.noise.torque_Nm": "testbed torque-sensor noise (std)",
    "hil.plant.noise.angle_rad": "IMU orientation noise about the joint axis (std)",
    "hil.plant.noise.rate_rad_s": "IMU rate-of-turn noise (std)",
    "hil.plant.noise.rate_bias_rad_s": "constant gyro bias",
    "hil.plant.noise.encoder_counts_per_rev": "motor encoder resolution (0 = not quantised)",
}

#: units a key's name does not state, or states in a way the suffix rule misreads
UNITS: dict[str, str] = {
    "controller.feedforward.zeta_s": "",
    "controller.feedforward.effects_shape.zeta_s": "",
    "controller.feedforward.alpha_s_rad": "s/rad",
    "controller.feedforward.effects_shape.alpha_s_rad": "s/rad",
    "controller.feedback.kd_s": "N m s/(N m)",
    "controller.feedback.kp": "N m/(N m)",
    "motor.velocity_units_per_rev_s": "1/(rev/s)",
    "motor.bitrate": "bit/s",
    "hil.plant.effects[].amp": "",
}
