"""Testbed scenarios: a YAML file describing the plant, the excitation and the sensors,
run on the distributed plant into a measurement table.

Scenario keys (all sections optional except ``excitation``)::

    name: testbed_multisine
    duration_s: 60.0          # simulated time
    sample_rate_hz: 1000.0    # rows per second in the measurement table
    seed: 0                   # sensor-noise seed
    adaptive: true            # error-controlled integration (false: fixed steps of 1/sample_rate)
    transmission: {...}       # see models/plant/config.py
    routing: {...}
    pretension: {...}
    output: {mode: testbed, k_out_Nm_rad: 20, b_out_Nms_rad: 2}
    noise: {...}              # see models/rig.SensorNoise
    excitation: {...}         # see models/plant/excitation.py
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from capstan.models.common.config_tools import get_bool, get_float, get_int, load_yaml, reject_unknown, section
from capstan.models.distributed.model import DistributedModel, OutputMode
from capstan.models.common.errors import ConfigError
from capstan.models.plant.excitation import Excitation, excitation_from_mapping
from capstan.models.plant.config import PlantSpec, plant_from_mapping
from capstan.models.plant.rig import SensorNoise
from capstan.models.common.measurement_table import MeasurementTable

SCENARIO_KEYS = {"name", "duration_s", "sample_rate_hz", "seed", "adaptive", "transmission", "routing",
                 "pretension", "output", "noise", "excitation", "input"}


@dataclass(frozen=True)
class Scenario:
    """A parsed testbed scenario."""

    name: str
    duration_s: float
    sample_rate_hz: float
    seed: int
    adaptive: bool
    plant: PlantSpec
    noise: SensorNoise
    excitation: Excitation

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], base_dir: Path | None = None) -> "Scenario":
        """Parse a scenario mapping.

        :raises ConfigError: naming the offending key.
        """
        reject_unknown(cfg, SCENARIO_KEYS)
        if "excitation" not in cfg:
            raise ConfigError("excitation", "missing section: a testbed scenario needs an input torque")
        plant_cfg = {k: cfg[k] for k in ("transmission", "routing", "pretension", "output", "input") if k in cfg}
        if section(plant_cfg, "input", required=False).get("mode", "torque") != "torque":
            raise ConfigError("input.mode", "testbed scenarios command the input torque: use 'torque'")
        plant = plant_from_mapping(plant_cfg)
        if plant.boundary.output_mode != OutputMode.TESTBED:
            raise ConfigError("output.mode", "testbed scenarios need output mode 'testbed'")
        return Scenario(
            name=str(cfg.get("name", "scenario")),
            duration_s=get_float(cfg, "duration_s", "", 20.0, min_value=0.0, min_exclusive=True),
            sample_rate_hz=get_float(cfg, "sample_rate_hz", "", 1000.0, min_value=10.0, max_value=100000.0),
            seed=get_int(cfg, "seed", "", 0),
            adaptive=get_bool(cfg, "adaptive", "", True),
            plant=plant,
            noise=SensorNoise.from_mapping(section(cfg, "noise", required=False)),
            excitation=excitation_from_mapping(section(cfg, "excitation"), "excitation", base_dir),
        )

    @staticmethod
    def load(path: str | Path) -> "Scenario":
        """Load a scenario YAML file.

        :raises ConfigError: if unreadable or invalid.
        """
        p = Path(path)
        return Scenario.from_mapping(load_yaml(p), p.parent)


@dataclass
class ScenarioRun:
    """Result of a scenario run: the measurement table and what it cost."""

    table: MeasurementTable
    wall_s: float
    truth: dict[str, np.ndarray]


def run_scenario(sc: Scenario) -> ScenarioRun:
    """Simulate ``sc`` and build the measurement table with sensor noise.

    :raises OperatingRangeError: if the scenario makes a cable go slack.
    :raises IntegrationError: if the integrator fails.
    """
    n = int(round(sc.duration_s * sc.sample_rate_hz)) + 1
    t = np.arange(n) / sc.sample_rate_hz
    u = sc.excitation.torque_Nm(t)
    model = DistributedModel(sc.plant.transmission, sc.plant.boundary)
    start = time.perf_counter()
    res = model.simulate(t, u, adaptive=sc.adaptive)
    wall = time.perf_counter() - start
    rng = np.random.default_rng(sc.seed)
    nz = sc.noise

    def noisy(x: np.ndarray, std: float) -> np.ndarray:
        return x + rng.normal(0.0, std, x.shape) if std > 0 else x.copy()

    fix = np.asarray(res.fixture_tensions_N, dtype=float)
    fix_meas = noisy(fix, nz.tension_N)
    cols = {
        "t": t,
        "tau_in": noisy(np.asarray(res.tau_in_Nm), nz.torque_Nm),
        "tau_out": noisy(np.asarray(res.tau_out_Nm), nz.torque_Nm),
        "q_in": np.asarray(res.q_in_rad, dtype=float).copy(),
        "q_out": noisy(np.asarray(res.q_out_rad), nz.angle_rad),
        "dq_out": noisy(np.asarray(res.dq_out_rad_s), nz.rate_rad_s) + nz.rate_bias_rad_s,
        "T_lc_in": 0.5 * (fix_meas[:, 0] + fix_meas[:, 3]),
        "T_lc_out": 0.5 * (fix_meas[:, 1] + fix_meas[:, 2]),
        "tau_in_cmd": u,
        "T_up_in": fix_meas[:, 0],
        "T_up_out": fix_meas[:, 1],
        "T_lo_out": fix_meas[:, 2],
        "T_lo_in": fix_meas[:, 3],
    }
    spec = sc.plant
    tr = spec.transmission
    s_grid = np.linspace(0.0, spec.routing.length_m, 60)
    meta: dict[str, Any] = {
        "r_in": tr.r_in_m,
        "r_out": tr.r_out_m,
        "mu": tr.mu,
        "length": spec.routing.length_m,
        "curvature_profile": [[float(s), float(k)] for s, k in zip(s_grid, spec.routing.kappa_1_per_m(s_grid))],
        "environment": {"k_out": spec.boundary.k_out_Nm_rad, "b_out": spec.boundary.b_out_Nms_rad},
        "source": "capstan simulate (distributed model)",
        "scenario": sc.name,
        "n_nodes": int(len(tr.theta_upper_rad)),
        "theta_total_rad": float(spec.routing.theta_total_rad),
        "stiffness_Nm_rad": tr.stiffness_Nm_rad,
        "pretension_N": {"upper_in": spec.pretension.upper_in_N, "upper_out": spec.pretension.upper_out_N,
                         "lower_in": spec.pretension.lower_in_N, "lower_out": spec.pretension.lower_out_N},
        "T0_eq_N": float(spec.T0_eq_N),
        "units": {"tau_in_cmd": "Nm", "T_up_in": "N", "T_up_out": "N", "T_lo_out": "N", "T_lo_in": "N"},
    }
    truth = {"tau_out": np.asarray(res.tau_out_Nm, dtype=float), "tau_in": np.asarray(res.tau_in_Nm, dtype=float),
             "q_out": np.asarray(res.q_out_rad, dtype=float), "dq_out": np.asarray(res.dq_out_rad_s, dtype=float)}
    return ScenarioRun(MeasurementTable(cols, meta, sc.name), wall, truth)
