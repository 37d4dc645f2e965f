"""Excitation of the rig's identification runs, within the bring-up's safety limits.

Two runs, as the paper identified its rig:

* **link held** (:func:`held_excitation`): the link clamped near q_out = 0; an open-loop
  multisine motor torque (Schroeder phases, a flat band from ``f_low_hz`` to ``f_high_hz``
  plus a large slow component that makes the cables slide in the sheath), faded in and out.
  It shows the motor's inertia and damping (tau_m - tau_in) and the transmission's stiffness
  (tau_in + tau_out against the deflection).
* **link free** (:func:`free_excitation`): the link hanging free; a PD law on the motor angle
  tracks a slow raised-cosine sweep over +-``sweep_fraction`` x ``q_max_rad`` with a
  multisine torque on top. It shows the link's gravity (m g l), inertia and the friction.
  The free run needs feedback: the torque that keeps the link inside its angle range
  depends on m g l, which is what the run is there to measure.

Every command is clipped to +-``tau_max_Nm``; :meth:`Excitation.within_limits` names the
first limit the measured state passes (the caller then commands zero and stops).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from capstan.models.common.errors import ConfigError


@dataclass(frozen=True)
class ExcitationLimits:
    """Safety limits of an identification run (SI).

    :ivar tau_max_Nm: largest |motor torque command| [Nm].
    :ivar dq_max_rad_s: largest |motor speed| [rad/s].
    :ivar q_max_rad: largest |motor angle - start angle| [rad].
    """

    tau_max_Nm: float = 4.0
    dq_max_rad_s: float = 4.0
    q_max_rad: float = 0.8

    def __post_init__(self) -> None:
        require_positive(self, ("tau_max_Nm", "dq_max_rad_s", "q_max_rad"), "limits")


def require_positive(obj: Any, names: tuple[str, ...], prefix: str) -> None:
    """Check that each attribute ``names`` of ``obj`` is a finite number > 0.

    :raises ConfigError: naming ``prefix.name`` and the value.
    """
    for name in names:
        v = getattr(obj, name)
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0.0):
            raise ConfigError(f"{prefix}.{name}", f"must be a finite number > 0, got {v!r}")


def schroeder_multisine(freqs_hz: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Unit-peak multisine of equal amplitudes at ``freqs_hz`` with Schroeder phases (low crest
    factor), sampled at ``t_s``; normalised so that max |x| over ``t_s`` is 1."""
    k = np.arange(1, len(freqs_hz) + 1)
    ph = -np.pi * k * (k - 1) / len(freqs_hz)
    x = np.sin(2.0 * np.pi * np.outer(t_s, freqs_hz) + ph).sum(axis=1)
    return x / max(float(np.max(np.abs(x))), 1e-12)


def _fade(t_s: np.ndarray, duration_s: float, fade_s: float) -> np.ndarray:
    """Raised-cosine fade in over the first and out over the last ``fade_s``."""
    up = np.clip(t_s / fade_s, 0.0, 1.0)
    down = np.clip((duration_s - t_s) / fade_s, 0.0, 1.0)
    return (0.5 - 0.5 * np.cos(np.pi * up)) * (0.5 - 0.5 * np.cos(np.pi * down))


@dataclass
class Excitation:
    """A torque-command profile for one identification run, sampled at ``dt_s``.

    :ivar kind: ``"held"`` or ``"free"``.
    :ivar feedforward_Nm: the open-loop torque per cycle [Nm] (the multisine).
    :ivar q_ref_rad: the motor-angle reference per cycle (relative to the start) [rad], or
        None for an open-loop run.
    :ivar kp_Nm_rad, kd_Nms_rad: the PD gains on the motor angle (free run).
    """

    kind: str
    limits: ExcitationLimits
    dt_s: float
    feedforward_Nm: np.ndarray
    q_ref_rad: np.ndarray | None = None
    kp_Nm_rad: float = 0.0
    kd_Nms_rad: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)
    _q0_rad: float | None = None

    @property
    def duration_s(self) -> float:
        """Length of the run [s]."""
        return len(self.feedforward_Nm) * self.dt_s

    @property
    def n_cycles(self) -> int:
        """Number of control cycles of the run."""
        return len(self.feedforward_Nm)

    def reset(self) -> None:
        """Forget the latched start angle (before running the profile again)."""
        self._q0_rad = None

    def torque_Nm(self, t_s: float, q_m_rad: float, dq_m_rad_s: float) -> float:
        """Motor torque command at run time ``t_s`` [s] for the measured motor state, clipped to
        +-``tau_max_Nm`` (0 after the end). The first call latches ``q_m_rad`` as the start."""
        if self._q0_rad is None:
            self._q0_rad = float(q_m_rad)
        i = int(round(t_s / self.dt_s))
        if i < 0 or i >= self.n_cycles:
            return 0.0
        tau = float(self.feedforward_Nm[i])
        if self.q_ref_rad is not None:
            tau += self.kp_Nm_rad * (float(self.q_ref_rad[i]) - (q_m_rad - self._q0_rad)) - self.kd_Nms_rad * dq_m_rad_s
        lim = self.limits.tau_max_Nm
        return min(max(tau, -lim), lim)

    def within_limits(self, q_m_rad: float, dq_m_rad_s: float) -> str | None:
        """None while the motor is inside the angle and speed limits, else the reason (one line)."""
        lim = self.limits
        q0 = self._q0_rad if self._q0_rad is not None else q_m_rad
        if abs(q_m_rad - q0) > lim.q_max_rad:
            return (f"{self.kind} run: motor angle {q_m_rad - q0:+.3f} rad from the start is beyond the "
                    f"limit +-{lim.q_max_rad:g} rad")
        if abs(dq_m_rad_s) > lim.dq_max_rad_s:
            return f"{self.kind} run: motor speed {dq_m_rad_s:+.2f} rad/s is beyond the limit +-{lim.dq_max_rad_s:g} rad/s"
        return None

    def describe(self) -> dict[str, Any]:
        """What the run is, for the log and the provenance."""
        lim = self.limits
        return {"kind": self.kind, "duration_s": self.duration_s, "dt_s": self.dt_s,
                "limits": {"tau_max_Nm": lim.tau_max_Nm, "dq_max_rad_s": lim.dq_max_rad_s, "q_max_rad": lim.q_max_rad},
                "kp_Nm_rad": self.kp_Nm_rad, "kd_Nms_rad": self.kd_Nms_rad, **self.info}


def held_excitation(limits: ExcitationLimits, duration_s: float = 24.0, f_low_hz: float = 0.5,
                    f_high_hz: float = 12.0, slow_hz: float = 0.25, slow_fraction: float = 0.55,
                    dt_s: float = 1e-3, fade_s: float = 1.0) -> Excitation:
    """Link-held run: a slow sine (``slow_fraction`` of the peak, makes the cables slide) plus a
    flat multisine over ``[f_low_hz, f_high_hz]`` (the rest), peak 0.95 ``tau_max_Nm``.

    :raises ConfigError: on a band or duration that leaves no excitation.
    """
    if not (0.0 < f_low_hz < f_high_hz < 0.25 / dt_s):
        raise ConfigError("held_excitation", f"need 0 < f_low_hz < f_high_hz < {0.25 / dt_s:g} Hz, got "
                          f"{f_low_hz:g}, {f_high_hz:g}")
    if duration_s < 4.0 * fade_s + 2.0 / f_low_hz:
        raise ConfigError("held_excitation.duration_s", f"{duration_s:g} s is too short for the band and fades")
    t = np.arange(int(round(duration_s / dt_s))) * dt_s
    df = 1.0 / (duration_s - 2.0 * fade_s)
    freqs = np.arange(f_low_hz, f_high_hz + 0.5 * df, max(df, f_low_hz / 2.0))
    peak = 0.95 * limits.tau_max_Nm
    u = peak * (slow_fraction * np.sin(2.0 * np.pi * slow_hz * t)
                + (1.0 - slow_fraction) * schroeder_multisine(freqs, t)) * _fade(t, duration_s, fade_s)
    return Excitation("held", limits, dt_s, u, info={
        "band_hz": [float(freqs[0]), float(freqs[-1])], "n_lines": int(len(freqs)), "slow_hz": slow_hz,
        "peak_Nm": peak, "slow_fraction": slow_fraction, "needs": "link clamped near q_out = 0"})


def free_excitation(limits: ExcitationLimits, duration_s: float = 40.0, sweep_hz: float = 0.05,
                    sweep_fraction: float = 0.8, dither_fraction: float = 0.2, f_low_hz: float = 0.4,
                    f_high_hz: float = 3.0, dt_s: float = 1e-3, fade_s: float = 2.0) -> Excitation:
    """Link-free run: PD on the motor angle (kp = 2 tau_max / q_max, kd = 0.3 s x kp) tracking
    ``sweep_fraction q_max sin(2 pi sweep_hz t)`` (faded in), plus a multisine of
    ``dither_fraction tau_max`` over ``[f_low_hz, f_high_hz]`` (the link's inertia). The
    reference's speed stays below half ``dq_max_rad_s``.

    :raises ConfigError: if the sweep would be faster than the speed limit allows.
    """
    a = sweep_fraction * limits.q_max_rad
    if 2.0 * math.pi * sweep_hz * a > 0.5 * limits.dq_max_rad_s:
        raise ConfigError("free_excitation.sweep_hz", f"{sweep_hz:g} Hz over +-{a:.2f} rad is faster than half "
                          f"the speed limit {limits.dq_max_rad_s:g} rad/s")
    t = np.arange(int(round(duration_s / dt_s))) * dt_s
    fade = _fade(t, duration_s, fade_s)
    q_ref = a * np.sin(2.0 * np.pi * sweep_hz * t) * fade
    freqs = np.linspace(f_low_hz, f_high_hz, 12)
    u = dither_fraction * limits.tau_max_Nm * schroeder_multisine(freqs, t) * fade
    kp = 2.0 * limits.tau_max_Nm / limits.q_max_rad
    return Excitation("free", limits, dt_s, u, q_ref, kp, 0.3 * kp, info={
        "sweep_hz": sweep_hz, "sweep_amplitude_rad": a, "dither_band_hz": [f_low_hz, f_high_hz],
        "dither_Nm": dither_fraction * limits.tau_max_Nm, "needs": "link hanging free, its angle range clear"})
