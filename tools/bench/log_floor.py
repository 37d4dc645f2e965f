"""How small can a 1 kHz cycle log get? Per-field compressed cost under other layouts.

Used by ``python -m capstan.tools.bench.logs --floor``. The daemon writes one protobuf message
per cycle (Foxglove plots every field against time); here the same records are
compressed **column by column** (each field's values of one 0.8 s chunk in a row,
zstd at the live level), which is the best case for zstd: a batched, columnar message
layout cannot do better with the same value representation. Then the representation
is changed field by field to what a fixed-point log would store, losslessly for these
records:

* times (``t_s`` and the receive times) as integer nanoseconds (within 1 ns of the
  logged float), receive times relative to ``t_s``; ``period_s``/``compute_s`` as
  integer nanoseconds;
* drive feedback in wire units: position counts, velocity units, torque per mille;
* load cells as the float32 bridge signal [mV/V] the amplifier sends;
* IMU values as the float32 the sensor sends.

Each layout's sum (plus the message framing it needs) is the floor for that design;
the figures say which product decision a size target requires.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import zstandard

#: message framing per message: 31 B record header (mostly compressed away) and a 16 B
#: message-index entry (uncompressed) that Foxglove's indexed reader needs
INDEX_ENTRY_BYTES = 16

TIME_FIELDS = ("lc_t_s", "imu_t_s", "motor_t_s")
DURATION_FIELDS = ("period_s", "compute_s")
STEP_STATE_FIELDS = ("tau_in_Nm", "T0_meas_N", "tau_g_Nm", "tau_fc_Nm", "tau_in_des_Nm", "err_Nm", "pd_Nm",
                     "d_hat_Nm", "tau_m_raw_Nm")


@dataclass(frozen=True)
class WireScales:
    """Scales from wire units to SI, as the drivers apply them."""

    lc_N_per_mV_V: float
    rad_per_count: float
    rad_s_per_unit: float
    rated_torque_Nm: float


def fixed_point_columns(records: np.ndarray, float32_fields: tuple[str, ...],
                        scales: WireScales) -> dict[str, np.ndarray]:
    """Each field as a fixed-point log would store it (see module docstring).

    :raises ValueError: if a converted column does not reproduce the record's values
        exactly (the conversion must be lossless for these records).
    """
    t_ns = np.round(records["t_s"] * 1e9).astype(np.int64)
    cols: dict[str, np.ndarray] = {}
    for name in records.dtype.names:
        v = records[name]
        if name == "t_s":
            c, back = t_ns, t_ns * 1e-9
        elif name in TIME_FIELDS:
            ns = np.round(v * 1e9).astype(np.int64)
            c, back = (ns - t_ns).astype(np.int32), ns / 1e9
        elif name in DURATION_FIELDS:
            c = np.round(v * 1e9).astype(np.int32)
            back = (c.astype(np.int64) * 1e-9).astype(np.float32).astype(np.float64)
            v = v.astype(np.float32).astype(np.float64)
        elif name in ("T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N"):
            c = (v / scales.lc_N_per_mV_V).astype(np.float32)
            back = scales.lc_N_per_mV_V * c.astype(np.float64)
        elif name == "q_m_rad":
            c = np.round(v / scales.rad_per_count).astype(np.int32)
            back = c * scales.rad_per_count
        elif name == "dq_m_rad_s":
            c = np.round(v / scales.rad_s_per_unit).astype(np.int32)
            back = c * scales.rad_s_per_unit
        elif name == "tau_m_meas_Nm":
            c = np.round(v * 1000.0 / scales.rated_torque_Nm).astype(np.int16)
            back = c * scales.rated_torque_Nm / 1000.0
        elif name == "dq_out_rad_s":
            c = v.astype(np.float32)
            back = c.astype(np.float64)
        elif name in float32_fields:
            # already logged as float32: the record value to reproduce is the float32 one
            c = v.astype(np.float32)
            back = v = c.astype(np.float64)
        else:
            c = back = v
        timelike = name in TIME_FIELDS or name == "t_s"
        ok = (np.max(np.abs(back - v), initial=0.0) <= 1e-9 if timelike
              else np.allclose(back, v, rtol=1e-7, atol=1e-12))
        if not ok:
            raise ValueError(f"{name}: fixed-point conversion loses more than rounding for these records")
        cols[name] = np.ascontiguousarray(c)
    return cols


#: resolution of a log quantised at the source (the driver / the step rounds to it, so
#: replay stays exact): far below each signal's noise on the rig
SOURCE_QUANTUM: dict[str, float] = {
    "t_s": 1e-6, "lc_t_s": 1e-6, "imu_t_s": 1e-6, "motor_t_s": 1e-6, "period_s": 1e-6, "compute_s": 1e-6,
    "T_up_in_N": 1e-3, "T_up_out_N": 1e-3, "T_lo_out_N": 1e-3, "T_lo_in_N": 1e-3,
    "q_out_rad": 1e-6, "dq_out_rad_s": 1e-5, "tau_out_ref_Nm": 1e-4, "cmd_scale": 1e-4,
    **{n: 1e-4 for n in STEP_STATE_FIELDS}, "tau_m_cmd_Nm": 1e-4,
}


def source_quantised_columns(records: np.ndarray, fixed: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Fixed-point columns with the fields of :data:`SOURCE_QUANTUM` as integer multiples
    of their quantum (receive times relative to ``t_s``; lossy against the records: it is
    what a source-quantised daemon would log, not a re-encoding of this log)."""
    cols = dict(fixed)
    t_q = np.round(records["t_s"] / SOURCE_QUANTUM["t_s"]).astype(np.int64)
    for name, q in SOURCE_QUANTUM.items():
        v = np.round(records[name] / q).astype(np.int64)
        if name == "t_s":
            cols[name] = t_q
        elif name in TIME_FIELDS:
            cols[name] = (v - t_q).astype(np.int32)
        else:
            cols[name] = v.astype(np.int32)
    return cols


def column_costs(columns: dict[str, np.ndarray], chunk_rows: int, level: int) -> dict[str, float]:
    """Bytes per row of each column compressed on its own, chunk by chunk."""
    cz = zstandard.ZstdCompressor(level=level)
    out = {}
    for name, col in columns.items():
        n = len(col)
        size = sum(len(cz.compress(col[i:i + chunk_rows].tobytes())) for i in range(0, n, chunk_rows))
        out[name] = size / n
    return out


def floor_table(records: np.ndarray, float32_fields: tuple[str, ...], scales: WireScales,
                chunk_rows: int, level: int, batch: int = 50) -> list[tuple[str, float]]:
    """(layout, bytes per record) rows: per-field costs, then layout totals.

    :param batch: cycles per message of the batched layouts (index entries amortised).
    """
    as_logged = {n: np.ascontiguousarray(records[n].astype(np.float32) if n in float32_fields else records[n])
                 for n in records.dtype.names}
    now = column_costs(as_logged, chunk_rows, level)
    fixed_cols = fixed_point_columns(records, float32_fields, scales)
    fixed = column_costs(fixed_cols, chunk_rows, level)
    quant = column_costs(source_quantised_columns(records, fixed_cols), chunk_rows, level)
    rows = [(f"  {n:16s} {str(as_logged[n].dtype):8s}", now[n], fixed[n]) for n in records.dtype.names]
    framing = INDEX_ENTRY_BYTES / batch + 1.0
    inputs_cmd = [n for n in records.dtype.names if n not in STEP_STATE_FIELDS]
    totals = [
        ("columnar, values as logged now, all fields", sum(now.values()) + framing),
        ("columnar, fixed point, all fields", sum(fixed.values()) + framing),
        ("columnar, fixed point, without the step state (recomputed on replay)",
         sum(fixed[n] for n in inputs_cmd) + framing),
        ("columnar, quantised at the source (1 us, 1 mN, 1 urad, 0.1 mNm), all fields",
         sum(quant.values()) + framing),
        ("columnar, quantised at the source, without the step state",
         sum(quant[n] for n in inputs_cmd) + framing),
    ]
    per_cycle = INDEX_ENTRY_BYTES + 4.0
    out: list[tuple[str, float]] = []
    for label, a, b in rows:
        out.append((f"{label} {a:6.2f} -> {b:6.2f}", b))
    out += [(f"TOTAL {label}: {v:.1f} B/record (incl. {framing:.2f} B framing at {batch} cycles/message)", v)
            for label, v in totals]
    q_all = sum(quant.values()) + per_cycle
    out.append((f"TOTAL per-cycle messages (as now: Foxglove-indexed), quantised at the source, all fields: "
                f"{q_all:.1f} B/record (incl. ~{per_cycle:.0f} B header and index entry)", q_all))
    return out
