"""The simulated rig's devices: what each sensor reports of the true plant state, and the
command path — realistic by default, ideal on request, with bring-up mistakes on request.

Config (the ``sensors`` key of a rig ``plant`` section; absent = ``realistic``)::

    sensors: ideal                 # the exact devices the simulation used to have (labelled "ideal")
    sensors: realistic             # the defaults below
    sensors:                       # a preset with some keys changed
      preset: realistic            # realistic | ideal (what absent keys take)
      drive: {velocity: vendor, velocity_unit_rpm: 1.0, velocity_filter_hz: 0.0}
      load_cells: {scale_error: 0.003, offset_N: 2.0, drift_N: 1.0, drift_period_s: 600.0}
      imu: {gyro_bias_rad_s: 0.001, misalignment_deg: 1.0}
      command: {jitter_cycles: 1, jitter_probability: 0.05, loss_probability: 0.001}
      mistakes:                    # gross set-up errors, for bring-up checks (none by default)
        load_cell_gain: [1.0, 1.0, 2.0, 1.0]  # reported / true tension per channel (wrong sensitivity)
        load_cell_order: [0, 1, 3, 2]         # reported channel k carries true channel order[k] (swapped wires)
        imu_sign: -1                          # joint angle and rate reported negated
        imu_axis: other                       # joint | other: the joint turns about an axis the driver does not read
        motor_direction: -1                   # the motor turns against the positive joint direction

The noise levels stay in ``noise`` (:class:`capstan.models.plant.rig.SensorNoise`); the
drive's velocity model is :mod:`capstan.models.plant.drive_feedback`, the command path
:mod:`capstan.models.plant.command_path`.

Realistic magnitudes and why:

* **Load cells** (inline S-beam cells, a few hundred N range, bridge amplifier):
  ``scale_error`` 0.3 % — each channel's sensitivity drawn once, uniform in ±0.3 % (rated
  output tolerance and amplifier gain tolerance are 0.1–0.5 % for such cells; a shunt or
  dead-weight calibration leaves a few tenths of a percent). ``offset_N`` 2 N — the residual
  zero after a tare, drawn uniform in ±2 N per channel (cable pretension cannot be removed
  for the tare, so the zero is set with the cells loaded and carries the fixture's hysteresis).
  ``drift_N`` 1 N over ``drift_period_s`` 600 s — zero drift with temperature (about
  0.02 % FS/K on a 500 N cell: 0.1 N/K, several K while the motor and amplifier warm up),
  a slow sinusoid per channel with a seeded phase and a period between 1× and 2× the
  configured one: bounded by ``drift_N`` by construction.
* **IMU** (Xsens MTi, rate about the joint axis): ``gyro_bias_rad_s`` 1 mrad/s (0.06 °/s —
  MEMS gyros of this class specify a bias repeatability of 0.1–0.2 °/s and an in-run
  stability of ~10 °/h; the on-board filter estimates part of it); ``misalignment_deg`` 1° —
  the sensor's axis tilted from the joint axis by a hand-mounted bracket's tolerance.
  Misalignment is a rotation of the sensor about an axis normal to the joint: the rate about
  the sensor's joint axis is ω cos α and ω sin α leaks onto the sensor's normal axis; the
  angle (the twist of the orientation about the joint axis) is unchanged.
* **Drive velocity and command path**: see their modules.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np

from capstan.models.common.config_tools import get_choice, get_float, reject_unknown, section
from capstan.models.common.errors import ConfigError
from capstan.models.plant.command_path import REALISTIC_TIMING, CommandTiming
from capstan.models.plant.drive_feedback import DriveFeedbackSettings, VelocitySource

N_CELLS = 4


@dataclass(frozen=True)
class LoadCellErrors:
    """Per-channel calibration errors of the load cells (drawn once per seed).

    :ivar scale_error: largest relative sensitivity error (uniform in ±) [-].
    :ivar offset_N: largest residual zero (uniform in ±) [N].
    :ivar drift_N: amplitude of the slow zero drift [N].
    :ivar drift_period_s: shortest drift period (each channel's is 1–2× this) [s].
    """

    scale_error: float = 0.003
    offset_N: float = 2.0
    drift_N: float = 1.0
    drift_period_s: float = 600.0

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str, d: "LoadCellErrors") -> "LoadCellErrors":
        """:raises ConfigError: on unknown keys or bad values."""
        reject_unknown(cfg, {"scale_error", "offset_N", "drift_N", "drift_period_s"}, prefix)
        return LoadCellErrors(get_float(cfg, "scale_error", prefix, d.scale_error, min_value=0.0, max_value=0.2),
                              get_float(cfg, "offset_N", prefix, d.offset_N, min_value=0.0),
                              get_float(cfg, "drift_N", prefix, d.drift_N, min_value=0.0),
                              get_float(cfg, "drift_period_s", prefix, d.drift_period_s, min_value=1.0))


@dataclass(frozen=True)
class ImuErrors:
    """Errors of the IMU about the joint axis.

    :ivar gyro_bias_rad_s: constant rate bias [rad/s] (added to ``noise.rate_bias_rad_s``).
    :ivar misalignment_deg: tilt of the sensor's axis from the joint axis [deg].
    """

    gyro_bias_rad_s: float = 1e-3
    misalignment_deg: float = 1.0

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str, d: "ImuErrors") -> "ImuErrors":
        """:raises ConfigError: on unknown keys or bad values."""
        reject_unknown(cfg, {"gyro_bias_rad_s", "misalignment_deg"}, prefix)
        return ImuErrors(get_float(cfg, "gyro_bias_rad_s", prefix, d.gyro_bias_rad_s),
                         get_float(cfg, "misalignment_deg", prefix, d.misalignment_deg, min_value=-45.0,
                                   max_value=45.0))


@dataclass(frozen=True)
class Mistakes:
    """Gross set-up errors a bring-up must catch (none by default).

    :ivar load_cell_gain: reported / true tension per channel (e.g. 2.0: a sensitivity off by 2).
    :ivar load_cell_order: reported channel k carries true channel ``load_cell_order[k]``.
    :ivar imu_sign: +1, or -1 for a flipped sensor.
    :ivar imu_axis_wrong: the joint turns about a sensor axis the driver does not read.
    :ivar motor_direction: +1, or -1: positive command and feedback run against the joint.
    """

    load_cell_gain: tuple[float, ...] = (1.0,) * N_CELLS
    load_cell_order: tuple[int, ...] = tuple(range(N_CELLS))
    imu_sign: int = 1
    imu_axis_wrong: bool = False
    motor_direction: int = 1

    @property
    def any(self) -> bool:
        """True if any mistake is set."""
        return self != Mistakes()

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str) -> "Mistakes":
        """:raises ConfigError: on unknown keys or bad values (naming the key and the reason)."""
        reject_unknown(cfg, {"load_cell_gain", "load_cell_order", "imu_sign", "imu_axis", "motor_direction"}, prefix)
        gain = cfg.get("load_cell_gain", [1.0] * N_CELLS)
        if (not isinstance(gain, list) or len(gain) != N_CELLS
                or not all(isinstance(g, (int, float)) and not isinstance(g, bool) and math.isfinite(g) and g > 0
                           for g in gain)):
            raise ConfigError(f"{prefix}.load_cell_gain", f"must be a list of {N_CELLS} numbers > 0, got {gain!r}")
        order = cfg.get("load_cell_order", list(range(N_CELLS)))
        if (not isinstance(order, list) or sorted(order) != list(range(N_CELLS))
                or not all(isinstance(i, int) and not isinstance(i, bool) for i in order)):
            raise ConfigError(f"{prefix}.load_cell_order",
                              f"must be a permutation of {list(range(N_CELLS))}, got {order!r}")
        signs = {}
        for key in ("imu_sign", "motor_direction"):
            v = cfg.get(key, 1)
            if isinstance(v, bool) or v not in (1, -1):
                raise ConfigError(f"{prefix}.{key}", f"must be 1 or -1, got {v!r}")
            signs[key] = int(v)
        axis = get_choice(cfg, "imu_axis", ("joint", "other"), prefix, "joint")
        return Mistakes(tuple(float(g) for g in gain), tuple(order), signs["imu_sign"], axis == "other",
                        signs["motor_direction"])


@dataclass(frozen=True)
class DeviceSettings:
    """All device models of the rig.

    :ivar preset: ``realistic`` or ``ideal`` (what the unset keys took).
    """

    preset: str = "realistic"
    drive: DriveFeedbackSettings = DriveFeedbackSettings()
    load_cells: LoadCellErrors = LoadCellErrors()
    imu: ImuErrors = ImuErrors()
    command: CommandTiming = REALISTIC_TIMING
    mistakes: Mistakes = field(default_factory=Mistakes)

    @staticmethod
    def ideal() -> "DeviceSettings":
        """The exact devices (exact velocity, no calibration errors, no bias or misalignment,
        every command exactly on time); noise and encoder quantisation stay as ``noise`` sets them."""
        return DeviceSettings("ideal", DriveFeedbackSettings(VelocitySource.EXACT), LoadCellErrors(0.0, 0.0, 0.0),
                              ImuErrors(0.0, 0.0), CommandTiming.ideal(), Mistakes())

    @staticmethod
    def realistic() -> "DeviceSettings":
        """The realistic defaults (module docstring)."""
        return DeviceSettings()

    @property
    def label(self) -> str:
        """Short description for reports, e.g. ``realistic (velocity vendor)`` or ``ideal``."""
        base = self.preset if self == _PRESETS[self.preset]() else f"{self.preset}, modified"
        extra = " + mistakes" if self.mistakes.any else ""
        return f"{base} (velocity {self.drive.velocity.value}){extra}"

    def with_mistakes(self, mistakes: Mistakes) -> "DeviceSettings":
        """A copy with these mistakes."""
        return replace(self, mistakes=mistakes)

    @staticmethod
    def from_config(value: Any, prefix: str = "plant.sensors") -> "DeviceSettings":
        """Parse ``sensors``: absent/None (realistic), ``"ideal"``, ``"realistic"`` or a mapping.

        :raises ConfigError: naming the offending key and the reason.
        """
        if value is None:
            return DeviceSettings.realistic()
        if isinstance(value, str):
            if value not in _PRESETS:
                raise ConfigError(prefix, f"must be one of {', '.join(_PRESETS)} or a mapping, got {value!r}")
            return _PRESETS[value]()
        if not isinstance(value, Mapping):
            raise ConfigError(prefix, f"must be one of {', '.join(_PRESETS)} or a mapping, got {value!r}")
        reject_unknown(value, {"preset", "drive", "load_cells", "imu", "command", "mistakes"}, prefix)
        preset = get_choice(value, "preset", tuple(_PRESETS), prefix, "realistic")
        d = _PRESETS[preset]()
        return DeviceSettings(
            preset,
            DriveFeedbackSettings.from_mapping(section(value, "drive", prefix, required=False), f"{prefix}.drive",
                                               d.drive),
            LoadCellErrors.from_mapping(section(value, "load_cells", prefix, required=False), f"{prefix}.load_cells",
                                        d.load_cells),
            ImuErrors.from_mapping(section(value, "imu", prefix, required=False), f"{prefix}.imu", d.imu),
            CommandTiming.from_mapping(section(value, "command", prefix, required=False), f"{prefix}.command",
                                       d.command),
            Mistakes.from_mapping(section(value, "mistakes", prefix, required=False), f"{prefix}.mistakes"),
        )


_PRESETS = {"realistic": DeviceSettings.realistic, "ideal": DeviceSettings.ideal}


class LoadCellModel:
    """True fixture tensions -> what the amplifier's four channels report (before noise).

    :param errors: calibration errors; ``mistakes``: gross errors; ``seed``: draws the
        per-channel errors (the same seed gives the same cells).
    """

    def __init__(self, errors: LoadCellErrors, mistakes: Mistakes, seed: int) -> None:
        rng = np.random.default_rng([int(seed), 0x10AD])
        self.errors = errors
        self.mistakes = mistakes
        self.scale = 1.0 + errors.scale_error * rng.uniform(-1.0, 1.0, N_CELLS)
        self.offset_N = errors.offset_N * rng.uniform(-1.0, 1.0, N_CELLS)
        self.drift_period_s = errors.drift_period_s * rng.uniform(1.0, 2.0, N_CELLS)
        self.drift_phase_rad = rng.uniform(0.0, 2.0 * math.pi, N_CELLS)
        self._gain = np.asarray(mistakes.load_cell_gain, dtype=float)
        self._order = np.asarray(mistakes.load_cell_order, dtype=int)

    def drift_N(self, t_s: float) -> np.ndarray:
        """The zero drift of each channel at time ``t_s`` [N]."""
        e = self.errors
        if e.drift_N == 0.0:
            return np.zeros(N_CELLS)
        return e.drift_N * np.sin(2.0 * math.pi * t_s / self.drift_period_s + self.drift_phase_rad)

    def report_N(self, true_N: np.ndarray, t_s: float) -> np.ndarray:
        """What the channels report for the true tensions (channel order of the amplifier) [N]."""
        f = np.asarray(true_N, dtype=float)[self._order] * self.scale + self.offset_N + self.drift_N(t_s)
        return f * self._gain


class ImuModel:
    """True joint angle and rate -> what the IMU reports about the axis the driver reads.

    :param errors: bias and misalignment; ``mistakes``: sign and axis mistakes.
    """

    def __init__(self, errors: ImuErrors, mistakes: Mistakes) -> None:
        self.errors = errors
        self.mistakes = mistakes
        a = math.radians(errors.misalignment_deg)
        self.cos_a = math.cos(a)
        self.sin_a = math.sin(a)

    def rate_vector_rad_s(self, dq_rad_s: float) -> tuple[float, float]:
        """The joint rate in the sensor frame: (about the sensor's joint axis, about its normal) [rad/s]."""
        return dq_rad_s * self.cos_a, dq_rad_s * self.sin_a

    def report(self, q_rad: float, dq_rad_s: float) -> tuple[float, float]:
        """(angle [rad], rate [rad/s]) about the sensor axis the driver reads, before noise.

        The angle is the twist of the sensor's orientation about the joint axis: a tilt of
        the sensor about a normal axis leaves it unchanged; the rate is the sensor-axis
        component plus the bias.
        """
        m = self.mistakes
        if m.imu_axis_wrong:            # the read axis is normal to the joint: it sees the leak only
            q, w = 0.0, self.rate_vector_rad_s(dq_rad_s)[1]
        else:
            q, w = q_rad, self.rate_vector_rad_s(dq_rad_s)[0]
        return m.imu_sign * q, m.imu_sign * w + self.errors.gyro_bias_rad_s
