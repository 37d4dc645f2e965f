"""The ``controller.safety`` section: the safety stage's limits, timeouts and the
command's resolution (:mod:`capstan.controller.law.safety` applies them every cycle)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from capstan.controller.law.safety import COMMAND_QUANTUM_NM
from capstan.models.common.config_tools import get_float, reject_unknown
from capstan.models.common.errors import ConfigError


@dataclass(frozen=True)
class SafetyConfig:
    """Limits and timeouts of the safety stage."""

    tau_max_Nm: float = 15.0
    dtau_max_Nm_s: float = 2000.0
    tau_fault_Nm: float = 60.0
    dtau_fault_Nm_s: float = 60000.0
    imu_timeout_s: float = 0.010
    loadcell_timeout_s: float = 0.005
    motor_timeout_s: float = 0.005
    command_quantum_Nm: float = COMMAND_QUANTUM_NM


def safety_from_mapping(c: Mapping[str, Any], p: str) -> SafetyConfig:
    """Parse ``controller.safety``.

    :raises ConfigError: naming the key (also when a fault limit is below its clamp).
    """
    reject_unknown(c, {"tau_max_Nm", "dtau_max_Nm_s", "tau_fault_Nm", "dtau_fault_Nm_s", "imu_timeout_s",
                       "loadcell_timeout_s", "motor_timeout_s", "command_quantum_Nm"}, p)
    d = SafetyConfig()
    if "tau_max_Nm" in c and "tau_fault_Nm" not in c:
        # the user set the clamp only: a clamp above the default fault limit is the clamp's error
        tmax = get_float(c, "tau_max_Nm", p, d.tau_max_Nm, min_value=0.0, min_exclusive=True)
        if tmax > d.tau_fault_Nm:
            raise ConfigError(f"{p}.tau_max_Nm", f"must be <= tau_fault_Nm = {d.tau_fault_Nm} "
                                                f"(the hard fault limit above the clamp), got {tmax}")
    s = SafetyConfig(
        get_float(c, "tau_max_Nm", p, d.tau_max_Nm, min_value=0.0, min_exclusive=True),
        get_float(c, "dtau_max_Nm_s", p, d.dtau_max_Nm_s, min_value=0.0, min_exclusive=True),
        get_float(c, "tau_fault_Nm", p, d.tau_fault_Nm, min_value=0.0, min_exclusive=True),
        get_float(c, "dtau_fault_Nm_s", p, d.dtau_fault_Nm_s, min_value=0.0, min_exclusive=True),
        get_float(c, "imu_timeout_s", p, d.imu_timeout_s, min_value=0.0, min_exclusive=True),
        get_float(c, "loadcell_timeout_s", p, d.loadcell_timeout_s, min_value=0.0, min_exclusive=True),
        get_float(c, "motor_timeout_s", p, d.motor_timeout_s, min_value=0.0, min_exclusive=True),
        get_float(c, "command_quantum_Nm", p, d.command_quantum_Nm, min_value=0.0, max_value=2.0 ** -10),
    )
    if s.command_quantum_Nm > 0.0 and math.frexp(s.command_quantum_Nm)[0] != 0.5:
        raise ConfigError(f"{p}.command_quantum_Nm", "must be 0 or a power of two (rounding to it is then "
                          f"exact and the same in a replay), got {s.command_quantum_Nm}")
    if s.tau_fault_Nm < s.tau_max_Nm:
        raise ConfigError(f"{p}.tau_fault_Nm", f"must be >= tau_max_Nm = {s.tau_max_Nm}, got {s.tau_fault_Nm}")
    if s.dtau_fault_Nm_s < s.dtau_max_Nm_s:
        raise ConfigError(f"{p}.dtau_fault_Nm_s",
                          f"must be >= dtau_max_Nm_s = {s.dtau_max_Nm_s}, got {s.dtau_fault_Nm_s}")
    if not math.isfinite(s.tau_max_Nm):
        raise ConfigError(f"{p}.tau_max_Nm", "must be finite")
    return s
