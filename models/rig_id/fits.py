"""The fits of the rig's plant from identification runs (:class:`capstan.models.rig_id.runs.RigRun`),
each a linear regression on measured signals with a block-sandwich covariance
(:func:`capstan.models.closure.identification.sandwich_cov`: honest when the residual is
autocorrelated, as every residual of filtered signals is).

* :func:`fit_stiffness` — link held. The pull-pull cables' mean differential tension is
  ``K_c / r (q_m - rho q_out)`` exactly, whatever the friction (the sum of a cable's segment
  elongations is its ends' displacement); the load cells give only the ends, whose mean
  ``(tau_in + tau_out) / 2`` equals it while the cables slide along their whole length (the
  friction then takes a constant torque per unit bending off the differential tension, a linear
  profile). Stuck stretches after a reversal bend the profile (the end mean then overstates the
  deflection's torque), so only the cycles where the transmission's torque loss
  ``tau_in - tau_out`` is near its saturated value are fitted. The spread of the estimate over
  that selection's threshold is added to its uncertainty as a systematic term.
* :func:`fit_motor` — link held (any run with motion): ``tau_m - tau_in = J_m ddq_m + b_m dq_m
  + c``, every signal low-passed by the same zero-phase Butterworth filter (which commutes with
  differentiation, so the regression stays exact), ddq_m and dq_m by central differences of the
  filtered quantised encoder angle; the command's delay in cycles is the one that fits best.
  Half the spread over three cutoffs is added as a systematic term (here and in the link's fit).
* :func:`fit_link` — link free: ``tau_out = J_l ddq_out + b_l dq_out + m g l sin q_out + c`` on
  the IMU angle (its own samples, interpolated to the loop rate) and the output load cells,
  filtered alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, filtfilt

from capstan.models.closure.identification import sandwich_cov
from capstan.models.common.errors import ModelError
from capstan.models.rig_id.runs import RigRun

#: cycles trimmed at each end of a filtered run (the filter's start-up)
EDGE_CYCLES = 500
#: thresholds on |tau_in - tau_out| (fractions of its 99th percentile) the stiffness is fitted above
SLIDE_FRACTIONS = (0.6, 0.7, 0.8)


@dataclass(frozen=True)
class Estimate:
    """An identified value with its 1-sigma uncertainty (SI).

    :ivar stderr: statistical (block-sandwich) and stated systematic parts in quadrature.
    """

    value: float
    stderr: float
    unit: str
    method: str = ""

    @property
    def rel_stderr(self) -> float:
        """stderr / |value| (inf for a zero value)."""
        return self.stderr / abs(self.value) if self.value != 0.0 else math.inf

    def to_dict(self) -> dict[str, float | str]:
        return {"value": self.value, "stderr": self.stderr, "unit": self.unit, "method": self.method}


def _lowpass(x: np.ndarray, cutoff_hz: float, dt_s: float) -> np.ndarray:
    b, a = butter(4, min(cutoff_hz * 2.0 * dt_s, 0.9))
    return filtfilt(b, a, x, axis=0)


def _lsq(B: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least squares with the block-sandwich covariance: (theta, cov, residual)."""
    scale = np.maximum(np.sqrt((B ** 2).mean(axis=0)), 1e-300)
    th, *_ = np.linalg.lstsq(B / scale, y, rcond=None)
    th = th / scale
    r = y - B @ th
    return th, sandwich_cov(B, r), r


def _trim(n: int) -> slice:
    if n <= 4 * EDGE_CYCLES:
        raise ModelError(f"a run of {n} cycles is too short to fit (needs > {4 * EDGE_CYCLES})")
    return slice(EDGE_CYCLES, n - EDGE_CYCLES)


def link_angle_rad(run: RigRun) -> np.ndarray:
    """The IMU angle at the loop rate, linearly interpolated between its own samples [rad]."""
    i = run.imu_index
    return np.interp(run.t_s, run.t_s[i], run.q_out_rad[i])


def fit_stiffness(run: RigRun, cutoff_hz: float = 20.0) -> Estimate:
    """Torsional stiffness K_c [Nm/rad] from a link-held run (see the module docstring).

    :raises ModelError: if the transmission never slides (no torque loss to select on).
    """
    dt = run.dt_s
    sl = _trim(len(run))
    rho = run.r_out_m / run.r_in_m
    q_out = link_angle_rad(run)
    defl = _lowpass(run.q_m_rad - rho * q_out, cutoff_hz, dt)[sl]
    y = _lowpass(run.tau_in_Nm + run.tau_out_Nm, cutoff_hz, dt)[sl]
    gap = _lowpass(run.tau_in_Nm - run.tau_out_Nm, cutoff_hz, dt)[sl]
    top = float(np.percentile(np.abs(gap), 99))
    if not top > 0.0:
        raise ModelError("held run: no torque loss across the transmission; the cables never slid")
    ks, ses = [], []
    for frac in SLIDE_FRACTIONS:
        m = np.abs(gap) > frac * top
        if m.sum() < 200 or np.ptp(defl[m]) <= 0.0:
            raise ModelError(f"held run: only {int(m.sum())} cycles with the cables sliding; excite with more torque")
        # the two slide directions are separate stretches: a common slope, an offset per direction
        B = np.column_stack([defl[m], (gap[m] > 0).astype(float), (gap[m] < 0).astype(float)])
        th, cov, _ = _lsq(B, y[m])
        ks.append(th[0] / 2.0)
        ses.append(math.sqrt(max(cov[0, 0], 0.0)) / 2.0)
    k = ks[1]
    sys_ = 0.5 * (max(ks) - min(ks))
    return Estimate(float(k), float(math.hypot(ses[1], sys_)), "Nm/rad",
                    f"held: (tau_in + tau_out)/2 vs q_m - rho q_out where |tau_in - tau_out| > "
                    f"{SLIDE_FRACTIONS[1]:g} x its 99th percentile; K over {list(SLIDE_FRACTIONS)}: "
                    f"{', '.join(f'{x:.1f}' for x in ks)}")


@dataclass(frozen=True)
class MotorFit:
    """Motor-side fit: inertia, damping, the command's delay and the fit's RMSE."""

    J_m: Estimate
    b_m: Estimate
    delay_cycles: int
    rmse_Nm: float


def _motor_at(run: RigRun, cutoff_hz: float, delays: range) -> tuple[int, np.ndarray, np.ndarray, float]:
    """(delay, theta = [J_m, b_m, c], cov, rmse) of the motor regression at one cutoff, the best of ``delays``."""
    dt = run.dt_s
    qf = _lowpass(run.q_m_rad, cutoff_hz, dt)
    dq = np.gradient(qf, dt)
    ddq = np.gradient(dq, dt)
    tau_in = _lowpass(run.tau_in_Nm, cutoff_hz, dt)
    tau_m = _lowpass(run.tau_m_Nm, cutoff_hz, dt)
    n = len(run)
    sl = _trim(n)
    B = np.column_stack([ddq, dq, np.ones(n)])
    best = None
    for d in delays:
        # the torque commanded at cycle i acts from cycle i + d
        y = np.r_[np.full(d, tau_m[0]), tau_m[:n - d]] - tau_in
        th, cov, r = _lsq(B[sl], y[sl])
        rms = float(np.sqrt(np.mean(r ** 2)))
        if best is None or rms < best[3]:
            best = (d, th, cov, rms)
    assert best is not None
    return best


def fit_motor(run: RigRun, cutoff_hz: float = 15.0, max_delay_cycles: int = 10) -> MotorFit:
    """Motor inertia J_m [kg m^2] and damping b_m [Nm s/rad] from ``tau_m - tau_in`` (module docstring).

    With only the command logged, the delay (0..``max_delay_cycles``) with the smallest residual is
    applied; with the drive's reported torque, 0 is expected and is what the fit then finds. Half the
    spread of the estimates at ``cutoff_hz`` x {2/3, 1, 4/3} is added to their uncertainty (the
    filter and the differences' own error at the band's top).

    :raises ModelError: if the motor did not move.
    """
    if np.ptp(run.q_m_rad) <= 0.0:
        raise ModelError("held run: the motor encoder did not move; nothing to identify J_m from")
    mid = _motor_at(run, cutoff_hz, range(max_delay_cycles + 1))
    d, th, cov, rms = mid
    fits = [_motor_at(run, 2.0 / 3.0 * cutoff_hz, range(d, d + 1)), mid, _motor_at(run, 4.0 / 3.0 * cutoff_hz, range(d, d + 1))]
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    spread = 0.5 * np.ptp(np.array([f[1] for f in fits]), axis=0)
    se = np.hypot(se, spread)
    how = f"tau_m - tau_in = J ddq_m + b dq_m + c, {cutoff_hz:g} Hz zero-phase low-pass, delay {d} cycles"
    return MotorFit(Estimate(float(th[0]), float(se[0]), "kg m^2", how),
                    Estimate(float(th[1]), float(se[1]), "Nm s/rad", how), d, rms)


@dataclass(frozen=True)
class LinkFit:
    """Link fit: gravity torque amplitude, inertia, damping, output-torque offset."""

    m_g_l: Estimate
    J_l: Estimate
    b_l: Estimate
    offset_Nm: float
    rmse_Nm: float


def _link_at(run: RigRun, q: np.ndarray, cutoff_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    dt = run.dt_s
    qf = _lowpass(q, cutoff_hz, dt)
    dq = np.gradient(qf, dt)
    ddq = np.gradient(dq, dt)
    s = _lowpass(np.sin(q), cutoff_hz, dt)
    y = _lowpass(run.tau_out_Nm, cutoff_hz, dt)
    sl = _trim(len(run))
    B = np.column_stack([ddq, dq, s, np.ones(len(run))])
    return _lsq(B[sl], y[sl])


def fit_link(run: RigRun, cutoff_hz: float = 6.0) -> LinkFit:
    """The link's m g l [Nm], inertia J_l [kg m^2] and damping b_l [Nm s/rad] from a free run.

    Half the spread of the estimates at ``cutoff_hz`` x {2/3, 1, 4/3} is added to their uncertainty.

    :raises ModelError: if the link swung less than 0.1 rad (m g l and the offset are then
        not separable).
    """
    q = link_angle_rad(run)
    if np.ptp(q) < 0.1:
        raise ModelError(f"free run: the link moved {np.ptp(q):.3f} rad; m g l needs a swing of at least 0.1 rad")
    fits = [_link_at(run, q, f * cutoff_hz) for f in (2.0 / 3.0, 1.0, 4.0 / 3.0)]
    th, cov, r = fits[1]
    se = np.hypot(np.sqrt(np.clip(np.diag(cov), 0.0, None)), 0.5 * np.ptp(np.array([f[0] for f in fits]), axis=0))
    how = f"free: tau_out = J_l ddq + b_l dq + m g l sin q + c, IMU angle, {cutoff_hz:g} Hz zero-phase low-pass"
    return LinkFit(Estimate(float(th[2]), float(se[2]), "Nm", how), Estimate(float(th[0]), float(se[0]), "kg m^2", how),
                   Estimate(float(th[1]), float(se[1]), "Nm s/rad", how), float(th[3]), float(np.sqrt(np.mean(r ** 2))))
