"""Input-torque excitations for testbed scenarios: sums of sines with optional hold
phases and a fade-in, or a table of tau_in(t).

A *hold* freezes the excitation: from ``start_s`` for ``duration_s`` the torque stays
at the value it had when the hold began, and the sine clock pauses, so the signal
resumes smoothly afterwards (the paper's motion-onset-after-rest situations).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from capstan.models.common.config_tools import get_float, reject_unknown
from capstan.models.common.errors import ConfigError


@dataclass(frozen=True)
class SineComponent:
    """One sine: ``amplitude_Nm * sin(2 pi frequency_hz t + phase_rad)``."""

    amplitude_Nm: float
    frequency_hz: float
    phase_rad: float = 0.0


@dataclass(frozen=True)
class Hold:
    """Hold the excitation at its current value from ``start_s`` for ``duration_s``."""

    start_s: float
    duration_s: float


@dataclass(frozen=True)
class Multisine:
    """Sum of sines plus offset, faded in over ``fade_in_s`` (raised cosine), with holds."""

    components: tuple[SineComponent, ...]
    offset_Nm: float = 0.0
    fade_in_s: float = 1.0
    holds: tuple[Hold, ...] = field(default_factory=tuple)

    def excitation_clock_s(self, t_s: np.ndarray) -> np.ndarray:
        """Map wall time to excitation time, which stands still during holds."""
        t = np.asarray(t_s, dtype=float)
        tau = t.copy()
        for h in sorted(self.holds, key=lambda h: h.start_s):
            inside = np.clip(t - h.start_s, 0.0, h.duration_s)
            tau -= inside
        return tau

    def torque_Nm(self, t_s: np.ndarray) -> np.ndarray:
        """Excitation torque at times ``t_s`` [s] -> [Nm]."""
        tau = self.excitation_clock_s(t_s)
        out = np.full_like(tau, self.offset_Nm)
        for c in self.components:
            out += c.amplitude_Nm * np.sin(2.0 * np.pi * c.frequency_hz * tau + c.phase_rad)
        if self.fade_in_s > 0.0:
            ramp = np.clip(tau / self.fade_in_s, 0.0, 1.0)
            out *= 0.5 - 0.5 * np.cos(np.pi * ramp)
        return out

    @property
    def peak_Nm(self) -> float:
        """Upper bound of |torque| (sum of amplitudes plus |offset|)."""
        return abs(self.offset_Nm) + sum(abs(c.amplitude_Nm) for c in self.components)


@dataclass(frozen=True)
class TorqueTable:
    """Piecewise-linear tau_in(t) from samples; held constant outside the table."""

    t_s: np.ndarray
    tau_Nm: np.ndarray

    def torque_Nm(self, t_s: np.ndarray) -> np.ndarray:
        """Interpolated torque at ``t_s`` [Nm]."""
        return np.interp(np.asarray(t_s, dtype=float), self.t_s, self.tau_Nm)

    @property
    def peak_Nm(self) -> float:
        """Largest |torque| in the table."""
        return float(np.max(np.abs(self.tau_Nm)))


Excitation = Multisine | TorqueTable


def excitation_from_mapping(cfg: Mapping[str, Any], prefix: str = "excitation",
                            base_dir: Path | None = None) -> Excitation:
    """Build an excitation from a scenario's ``excitation`` section.

    ``type: multisine`` with ``components: [{amplitude_Nm, frequency_hz, phase_rad}]``,
    ``offset_Nm``, ``fade_in_s``, ``holds: [{start_s, duration_s}]``; or ``type: table``
    with ``file`` (CSV with columns ``t`` and ``tau_in``, relative to ``base_dir``) or
    inline ``samples: [[t_s, tau_Nm], ...]``.

    :raises ConfigError: naming the offending key.
    """
    kind = cfg.get("type", "multisine")
    if kind == "multisine":
        reject_unknown(cfg, {"type", "components", "offset_Nm", "fade_in_s", "holds"}, prefix)
        comps_cfg = cfg.get("components")
        if not isinstance(comps_cfg, Sequence) or isinstance(comps_cfg, str) or not comps_cfg:
            raise ConfigError(f"{prefix}.components", "must be a non-empty list of sines")
        comps = []
        for i, c in enumerate(comps_cfg):
            p = f"{prefix}.components[{i}]"
            if not isinstance(c, Mapping):
                raise ConfigError(p, "must be a mapping {amplitude_Nm, frequency_hz, phase_rad}")
            reject_unknown(c, {"amplitude_Nm", "frequency_hz", "phase_rad"}, p)
            comps.append(SineComponent(get_float(c, "amplitude_Nm", p),
                                       get_float(c, "frequency_hz", p, min_value=0.0),
                                       get_float(c, "phase_rad", p, 0.0)))
        holds = []
        for i, h in enumerate(cfg.get("holds") or []):
            p = f"{prefix}.holds[{i}]"
            if not isinstance(h, Mapping):
                raise ConfigError(p, "must be a mapping {start_s, duration_s}")
            reject_unknown(h, {"start_s", "duration_s"}, p)
            holds.append(Hold(get_float(h, "start_s", p, min_value=0.0),
                              get_float(h, "duration_s", p, min_value=0.0)))
        return Multisine(tuple(comps), get_float(cfg, "offset_Nm", prefix, 0.0),
                         get_float(cfg, "fade_in_s", prefix, 1.0, min_value=0.0), tuple(holds))
    if kind == "table":
        reject_unknown(cfg, {"type", "file", "samples"}, prefix)
        if "samples" in cfg:
            arr = np.asarray(cfg["samples"], dtype=float)
            if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 2:
                raise ConfigError(f"{prefix}.samples", "must be a list of at least two [t_s, tau_Nm] pairs")
        elif "file" in cfg:
            from capstan.models.common.measurement_table import read_table  # local: tools depends on models, not vice versa at import

            path = Path(cfg["file"])
            if base_dir is not None and not path.is_absolute():
                path = base_dir / path
            try:
                tab = read_table(path)
            except Exception as exc:  # DataFormatError
                raise ConfigError(f"{prefix}.file", str(exc)) from exc
            if not tab.has("tau_in"):
                raise ConfigError(f"{prefix}.file", "table needs columns 't' and 'tau_in'")
            arr = np.column_stack([tab.t, tab["tau_in"]])
        else:
            raise ConfigError(prefix, "type 'table' needs 'file' or 'samples'")
        if not np.all(np.diff(arr[:, 0]) > 0):
            raise ConfigError(prefix, "table times must be strictly increasing")
        if not np.all(np.isfinite(arr)):
            raise ConfigError(prefix, "table holds non-finite values")
        return TorqueTable(arr[:, 0].copy(), arr[:, 1].copy())
    raise ConfigError(f"{prefix}.type", f"must be 'multisine' or 'table', got {kind!r}")
