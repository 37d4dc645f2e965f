"""The simulated rig: motor + distributed tendon-sheath transmission + output (testbed
environment or the instrumented link), with the signals the real sensors produce.

Sensors modelled (what the daemon and the offline tools see); the device models
(``sensors``, :mod:`capstan.models.plant.sensors`) are realistic unless ``sensors: ideal``:

* four inline load cells at the cable fixtures, 1 kHz, Gaussian noise
  (order: upper input-side, upper output-side, lower output-side, lower input-side);
  realistic: per-channel scale error, residual zero and slow zero drift;
* the link IMU at ``imu_rate_hz`` (400 Hz): joint angle with Gaussian noise and joint
  rate with Gaussian noise plus a constant gyro bias; realistic: a further bias and the
  sensor axis tilted from the joint axis;
* the drive's motor position (quantized to ``encoder_counts_per_rev``) and velocity
  (realistic: formed as the drive forms 0x606C, :mod:`capstan.models.plant.drive_feedback`);
* for the testbed, input/output torque sensors with Gaussian noise;
* the command path (:attr:`SimulatedRig.command_timing`, used by the lock-step loops;
  realistic: jitter of ±1 cycle and lost commands, :mod:`capstan.models.plant.command_path`);
* bring-up mistakes on request (``sensors.mistakes``: load-cell gain and channel order,
  IMU sign and axis, motor direction).

Ideal devices reproduce the former exact simulation bit for bit (the noise draws are the
same; the device errors draw from their own seeded streams).

Optionally the plant carries physical effects the controller's model lacks
(``effects``, :mod:`capstan.models.plant.rig_effects`), applied between steps.

The rig advances in fixed control steps (``step``); it never sleeps, so the HIL
process paces it in real time and tests run it in lock-step as fast as it computes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from capstan.models.common.config_tools import get_float, get_int, reject_unknown, section
from capstan.models.distributed.model import DistributedModel, InputMode
from capstan.models.plant.command_path import CommandPath, CommandTiming
from capstan.models.plant.config import PlantSpec, plant_from_mapping
from capstan.models.plant.drive_feedback import DriveFeedback
from capstan.models.plant.rig_effects import RigEffects
from capstan.models.plant.sensors import DeviceSettings, ImuModel, LoadCellModel


@dataclass(frozen=True)
class SensorNoise:
    """Sensor noise levels (standard deviations unless noted).

    :ivar tension_N: load-cell noise [N].
    :ivar torque_Nm: testbed torque-sensor noise [Nm].
    :ivar angle_rad: IMU orientation noise about the joint axis [rad].
    :ivar rate_rad_s: IMU rate-of-turn noise [rad/s].
    :ivar rate_bias_rad_s: constant gyro bias [rad/s].
    :ivar encoder_counts_per_rev: motor encoder resolution (quantization), 0 = none.
    """

    tension_N: float = 0.3
    torque_Nm: float = 0.02
    angle_rad: float = 5e-4
    rate_rad_s: float = 2e-3
    rate_bias_rad_s: float = 0.0
    encoder_counts_per_rev: int = 1 << 17

    @staticmethod
    def none() -> "SensorNoise":
        """Noise-free sensors (still quantization-free)."""
        return SensorNoise(0.0, 0.0, 0.0, 0.0, 0.0, 0)

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str = "noise") -> "SensorNoise":
        """Parse a ``noise`` section; absent keys keep the defaults.

        :raises ConfigError: on unknown keys or negative values.
        """
        d = SensorNoise()
        reject_unknown(cfg, {"tension_N", "torque_Nm", "angle_rad", "rate_rad_s", "rate_bias_rad_s",
                             "encoder_counts_per_rev"}, prefix)
        return SensorNoise(
            get_float(cfg, "tension_N", prefix, d.tension_N, min_value=0.0),
            get_float(cfg, "torque_Nm", prefix, d.torque_Nm, min_value=0.0),
            get_float(cfg, "angle_rad", prefix, d.angle_rad, min_value=0.0),
            get_float(cfg, "rate_rad_s", prefix, d.rate_rad_s, min_value=0.0),
            get_float(cfg, "rate_bias_rad_s", prefix, d.rate_bias_rad_s),
            get_int(cfg, "encoder_counts_per_rev", prefix, d.encoder_counts_per_rev, min_value=0),
        )


class SimulatedRig:
    """Distributed plant + sensor models, advanced in fixed control steps.

    :param spec: the plant (transmission, boundary, routing, pretension).
    :param noise: sensor noise levels.
    :param seed: seed of the noise generator (runs are reproducible).
    :param imu_rate_hz: IMU output rate [Hz].
    :param effects: physical effects injected into the plant (none by default).
    :param devices: the device models (None: realistic, :meth:`DeviceSettings.realistic`;
        :meth:`DeviceSettings.ideal` for the exact devices).
    """

    def __init__(self, spec: PlantSpec, noise: SensorNoise | None = None, seed: int = 0,
                 imu_rate_hz: float = 400.0, effects: RigEffects | None = None,
                 devices: DeviceSettings | None = None) -> None:
        self.spec = spec
        self.noise = noise if noise is not None else SensorNoise()
        self.imu_rate_hz = float(imu_rate_hz)
        self.effects = effects if effects is not None else RigEffects(())
        self.devices = devices if devices is not None else DeviceSettings.realistic()
        self.model = DistributedModel(spec.transmission, spec.boundary)
        self._seed = seed
        self.reset()

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str = "plant") -> "SimulatedRig":
        """Build from a ``plant`` section: the keys of :mod:`capstan.models.plant.config` plus
        ``noise`` (see :class:`SensorNoise`), ``seed``, ``imu_rate_hz``, ``effects``
        (see :mod:`capstan.models.plant.rig_effects`) and ``sensors`` (see
        :mod:`capstan.models.plant.sensors`; absent: realistic).

        :raises ConfigError: naming the offending key.
        """
        own = ("noise", "seed", "imu_rate_hz", "effects", "sensors")
        allowed = {"transmission", "routing", "pretension", "output", "input", *own}
        reject_unknown(cfg, allowed, prefix)
        spec = plant_from_mapping({k: v for k, v in cfg.items() if k not in own}, prefix)
        noise = SensorNoise.from_mapping(section(cfg, "noise", prefix, required=False), f"{prefix}.noise")
        return SimulatedRig(spec, noise, get_int(cfg, "seed", prefix, 0),
                            get_float(cfg, "imu_rate_hz", prefix, 400.0, min_value=1.0, max_value=2000.0),
                            RigEffects.from_list(cfg.get("effects"), f"{prefix}.effects"),
                            DeviceSettings.from_config(cfg.get("sensors"), f"{prefix}.sensors"))

    def reset(self) -> None:
        """Back to the initial pretension state at t = 0 and re-seed the noise."""
        self.model.reset()
        self.effects.reset()
        self._rng = np.random.default_rng(self._seed)
        d = self.devices
        self._cells = LoadCellModel(d.load_cells, d.mistakes, self._seed)
        self._imu = ImuModel(d.imu, d.mistakes)
        # the sample at t = 0 is the initial state; the next one is due at 1 / imu_rate_hz
        self._imu_index = 0
        self._imu_q, self._imu_dq = self._imu.report(float(self.model.q_out_rad), float(self.model.dq_out_rad_s))
        self._tau_cmd_Nm = 0.0
        self._drive = DriveFeedback(d.drive, self.noise.encoder_counts_per_rev)
        self._drive.reset(self._motor_sign * float(self.model.q_in_rad), self._motor_sign * float(self.model.dq_in_rad_s))

    @property
    def _motor_sign(self) -> float:
        return float(self.devices.mistakes.motor_direction)

    @property
    def command_timing(self) -> CommandTiming:
        """How irregularly commands reach the motor (``sensors.command``)."""
        return self.devices.command

    def command_path(self, delay_cycles: int) -> CommandPath:
        """A command path with this nominal delay and the rig's timing, seeded from the rig's seed."""
        return CommandPath(self.devices.command, delay_cycles, self._seed)

    @property
    def t_s(self) -> float:
        """Simulated time [s]."""
        return float(self.model.t_s)

    def step(self, tau_m_Nm: float, tau_ext_Nm: float = 0.0, dt_s: float = 1e-3) -> None:
        """Advance by ``dt_s`` with motor (or input) torque ``tau_m_Nm`` held and external
        torque ``tau_ext_Nm`` on the link.

        :raises OperatingRangeError: if a cable goes slack.
        :raises IntegrationError: if the integrator fails.
        """
        self._tau_cmd_Nm = float(tau_m_Nm)
        if self.effects:
            self.effects.before_step(self.model)
        applied = float(tau_m_Nm) if self._motor_sign > 0 else -float(tau_m_Nm)
        self.model.step(dt_s, applied, float(tau_ext_Nm))
        if self.effects:
            self.effects.after_step(self.model, dt_s)
        s = self._motor_sign
        self._drive.counts_per_rev = self.noise.encoder_counts_per_rev    # ``noise`` may be replaced
        self._drive.update(s * float(self.model.q_in_rad), s * float(self.model.dq_in_rad_s), dt_s)

    # ---- sensors -------------------------------------------------------------------
    def load_cells_N(self) -> np.ndarray:
        """Fixture tensions with noise [N]: (upper_in, upper_out, lower_out, lower_in)."""
        f = self._cells.report_N(np.asarray(self.model.fixture_tensions_N, dtype=float), self.t_s)
        if self.noise.tension_N > 0.0:
            f = f + self._rng.normal(0.0, self.noise.tension_N, 4)
        return f

    def imu_sample(self) -> tuple[bool, float, float]:
        """Latest IMU sample: ``(is_new, q_out_rad, dq_out_rad_s)``.

        A new sample is produced whenever the simulated time crosses a multiple of
        ``1 / imu_rate_hz``; between samples the previous values are returned with
        ``is_new = False``.
        """
        index = int(math.floor(self.t_s * self.imu_rate_hz + 1e-9))
        if index == self._imu_index:
            return False, self._imu_q, self._imu_dq
        self._imu_index = index
        n = self.noise
        q, dq = self._imu.report(float(self.model.q_out_rad), float(self.model.dq_out_rad_s))
        self._imu_q = float(q + (self._rng.normal(0.0, n.angle_rad) if n.angle_rad > 0 else 0.0))
        self._imu_dq = float(dq + n.rate_bias_rad_s
                             + (self._rng.normal(0.0, n.rate_rad_s) if n.rate_rad_s > 0 else 0.0))
        return True, self._imu_q, self._imu_dq

    def motor_feedback(self) -> tuple[float, float, float]:
        """What the drive reports: position [rad] (encoder counts), velocity [rad/s] (as
        ``sensors.drive.velocity`` forms it), torque [Nm] (the command it applies, in its
        own sense: with ``motor_direction: -1`` the joint receives the opposite)."""
        return self._drive.position_rad, self._drive.velocity_rad_s, self._tau_cmd_Nm

    def torque_sensors_Nm(self) -> tuple[float, float]:
        """Testbed torque sensors: (tau_in, tau_out) with noise [Nm]."""
        s = self.noise.torque_Nm
        e = self._rng.normal(0.0, s, 2) if s > 0 else (0.0, 0.0)
        return float(self.model.tau_in_Nm + e[0]), float(self.model.tau_out_Nm + e[1])

    @property
    def is_motor_driven(self) -> bool:
        """True when the input is a motor inertia driven by tau_m (else tau_in is commanded)."""
        return self.spec.boundary.input_mode == InputMode.MOTOR
