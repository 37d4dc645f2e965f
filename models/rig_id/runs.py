"""One logged identification run as the fits read it: the daemon's cycle-record fields
(``controller/law/records.py``) at the loop rate, from a measurement table
(``tools/offline/log_table.py``) or from plain arrays.

Derived here once: the input and output torques from the four load cells
(``tau_in = r_in (T_up_in - T_lo_in)``, ``tau_out = r_out (T_up_out - T_lo_out)``) and the
IMU's own samples (the 400 Hz stream, not the values the 1 kHz records hold between them).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from capstan.models.common.errors import DataFormatError

#: record fields a run must have
REQUIRED = ("q_m_rad", "T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N", "q_out_rad")
#: fewest cycles a run may have
MIN_CYCLES = 2000


@dataclass(frozen=True)
class RigRun:
    """A run at the loop rate (arrays of equal length, SI).

    :ivar tau_m_Nm: the motor torque the drive applied: its reported torque when logged,
        else the command.
    :ivar tau_m_is_measured: True if ``tau_m_Nm`` is the drive's reported torque.
    :ivar imu_index: indices of the cycles where a new IMU sample arrived.
    """

    t_s: np.ndarray
    q_m_rad: np.ndarray
    dq_m_rad_s: np.ndarray
    tau_m_cmd_Nm: np.ndarray
    tau_m_Nm: np.ndarray
    tau_m_is_measured: bool
    tensions_N: np.ndarray          # (n, 4): upper in, upper out, lower out, lower in
    q_out_rad: np.ndarray
    dq_out_rad_s: np.ndarray
    imu_index: np.ndarray
    r_in_m: float
    r_out_m: float
    source: str = ""

    @property
    def dt_s(self) -> float:
        """Median sample period [s]."""
        return float(np.median(np.diff(self.t_s)))

    @property
    def tau_in_Nm(self) -> np.ndarray:
        """Input torque from the input-side load cells [Nm]."""
        return self.r_in_m * (self.tensions_N[:, 0] - self.tensions_N[:, 3])

    @property
    def tau_out_Nm(self) -> np.ndarray:
        """Output torque from the output-side load cells [Nm]."""
        return self.r_out_m * (self.tensions_N[:, 1] - self.tensions_N[:, 2])

    @property
    def mean_tension_N(self) -> np.ndarray:
        """Mean of the four load cells [N] (the pretension at rest)."""
        return self.tensions_N.mean(axis=1)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @staticmethod
    def from_arrays(cols: Mapping[str, Any], r_in_m: float, r_out_m: float, source: str = "") -> "RigRun":
        """Build from record-field arrays (``t_s`` or ``t``, and :data:`REQUIRED`; optional
        ``dq_m_rad_s``, ``tau_m_cmd_Nm``, ``tau_m_meas_Nm``, ``dq_out_rad_s``, ``imu_new``).

        :raises DataFormatError: naming a missing column, a length mismatch, non-finite values,
            a run shorter than :data:`MIN_CYCLES` or a time axis that does not increase.
        """
        where = source or "<run>"
        t = cols.get("t_s", cols.get("t"))
        if t is None:
            raise DataFormatError(f"{where}: no column 't_s' (loop time)")
        missing = [c for c in REQUIRED if c not in cols]
        if "tau_m_cmd_Nm" not in cols and "tau_m_meas_Nm" not in cols:
            missing.append("tau_m_cmd_Nm or tau_m_meas_Nm")
        if missing:
            raise DataFormatError(f"{where}: missing column(s) {', '.join(missing)}")
        t = np.asarray(t, dtype=float)
        n = len(t)
        if n < MIN_CYCLES:
            raise DataFormatError(f"{where}: {n} cycles, an identification run needs at least {MIN_CYCLES}")

        def col(name: str, default: np.ndarray | None = None) -> np.ndarray:
            if name not in cols:
                assert default is not None
                return default
            a = np.asarray(cols[name], dtype=float)
            if a.shape != (n,):
                raise DataFormatError(f"{where}: column '{name}' has shape {a.shape}, expected ({n},)")
            if not np.all(np.isfinite(a)):
                raise DataFormatError(f"{where}: column '{name}' holds non-finite values")
            return a

        if not np.all(np.diff(t) > 0):
            raise DataFormatError(f"{where}: column 't_s' does not increase")
        q_m = col("q_m_rad")
        dq_m = col("dq_m_rad_s", np.gradient(q_m, t))
        meas = "tau_m_meas_Nm" in cols
        tau_cmd = col("tau_m_cmd_Nm", col("tau_m_meas_Nm") if meas else None)
        tau_m = col("tau_m_meas_Nm") if meas else tau_cmd
        T = np.column_stack([col(c) for c in ("T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N")])
        q_out = col("q_out_rad")
        dq_out = col("dq_out_rad_s", np.gradient(q_out, t))
        if "imu_new" in cols:
            imu = np.flatnonzero(col("imu_new") > 0.5)
        else:     # held between samples: a new sample changes the angle or the rate
            imu = np.flatnonzero(np.r_[True, (np.diff(q_out) != 0.0) | (np.diff(dq_out) != 0.0)])
        if len(imu) < MIN_CYCLES // 10:
            raise DataFormatError(f"{where}: only {len(imu)} IMU samples")
        return RigRun(t, q_m, dq_m, tau_cmd, tau_m, meas, T, q_out, dq_out, imu, float(r_in_m), float(r_out_m), where)

    @staticmethod
    def from_table(table: Any, r_in_m: float | None = None, r_out_m: float | None = None) -> "RigRun":
        """Build from a :class:`capstan.models.common.measurement_table.MeasurementTable` of the
        daemon's records (``records_to_table``: every record field is a column; pulley radii
        from its sidecar unless given).

        :raises DataFormatError: as :meth:`from_arrays`, or if no pulley radius is known.
        """
        meta = table.meta or {}
        r_in = r_in_m if r_in_m is not None else meta.get("r_in")
        r_out = r_out_m if r_out_m is not None else meta.get("r_out")
        if r_in is None or r_out is None:
            raise DataFormatError(f"{table.source or '<table>'}: no pulley radii (sidecar 'r_in' / 'r_out')")
        return RigRun.from_arrays(table.columns, float(r_in), float(r_out), table.source)
