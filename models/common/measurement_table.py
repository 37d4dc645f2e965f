"""The measurement table of the exchange format: a CSV with a header row plus a
YAML sidecar of the same stem (docs/measurement-table.md).

Columns are SI: ``t`` [s] (monotonic), ``tau_in``/``tau_out`` [Nm], ``q_in``/``q_out``
[rad], ``dq_out`` [rad/s], ``T_lc_in``/``T_lc_out`` [N]; any extra column is allowed
and described in the sidecar. ``t`` and at least one torque column are required.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from capstan.models.common.errors import DataFormatError

#: standard columns and their units
STANDARD_COLUMNS: dict[str, str] = {
    "t": "s",
    "tau_in": "Nm",
    "tau_out": "Nm",
    "q_in": "rad",
    "q_out": "rad",
    "dq_out": "rad/s",
    "T_lc_in": "N",
    "T_lc_out": "N",
}

#: sidecar keys with a known meaning (others are kept verbatim)
SIDECAR_KEYS = ("r_in", "r_out", "mu", "length", "curvature_profile", "environment")


@dataclass
class MeasurementTable:
    """One measured (or simulated) run.

    :ivar columns: column name -> 1-D float64 array, all of equal length.
    :ivar meta: sidecar mapping (``r_in`` [m], ``r_out`` [m], ``mu``, ``length`` [m],
        ``curvature_profile`` [[s_m, kappa_1_per_m], ...], ``environment`` {k_out, b_out}, ...).
    :ivar source: where it was read from (for reports), or ``""``.
    """

    columns: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        validate_columns(self.columns, self.source or "<table>")

    @property
    def t(self) -> np.ndarray:
        """Sample time [s]."""
        return self.columns["t"]

    def has(self, name: str) -> bool:
        """True if column ``name`` exists."""
        return name in self.columns

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise DataFormatError(f"{self.source or '<table>'}: no column '{name}'") from None

    def __len__(self) -> int:
        return int(self.columns["t"].shape[0])

    def slice(self, start: int, stop: int) -> "MeasurementTable":
        """Rows ``start:stop`` as a new table (same meta)."""
        return MeasurementTable({k: v[start:stop].copy() for k, v in self.columns.items()},
                                dict(self.meta), f"{self.source}[{start}:{stop}]")


def validate_columns(columns: Mapping[str, np.ndarray], where: str) -> None:
    """Check the table invariants.

    :raises DataFormatError: if ``t`` or every torque column is missing, lengths differ,
        ``t`` is not strictly increasing, or a standard column holds non-finite values.
    """
    if "t" not in columns:
        raise DataFormatError(f"{where}: required column 't' missing")
    if "tau_in" not in columns and "tau_out" not in columns:
        raise DataFormatError(f"{where}: needs at least one torque column (tau_in or tau_out)")
    n = len(columns["t"])
    for name, col in columns.items():
        if len(col) != n:
            raise DataFormatError(f"{where}: column '{name}' has {len(col)} rows, 't' has {n}")
    t = np.asarray(columns["t"], dtype=float)
    if n >= 2 and not np.all(np.diff(t) > 0):
        bad = int(np.argmax(~(np.diff(t) > 0)))
        raise DataFormatError(f"{where}: 't' must be strictly increasing (row {bad + 1} -> {bad + 2})")
    for name in STANDARD_COLUMNS:
        if name in columns and not np.all(np.isfinite(columns[name])):
            bad = int(np.argmax(~np.isfinite(columns[name])))
            raise DataFormatError(f"{where}: column '{name}' has a non-finite value at row {bad + 1}")


def sidecar_path(csv_path: str | Path) -> Path:
    """The sidecar of ``RUN.csv`` is ``RUN.yaml``."""
    return Path(csv_path).with_suffix(".yaml")


def read_table(csv_path: str | Path) -> MeasurementTable:
    """Read a measurement table and its sidecar (sidecar optional).

    :raises DataFormatError: if the file is unreadable, a value is not a number, or the
        table invariants fail.
    """
    path = Path(csv_path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise DataFormatError(f"{path}: empty file") from None
    if len(set(header)) != len(header):
        raise DataFormatError(f"{path}: duplicate column names in header {header}")
    rows: list[list[float]] = []
    for lineno, row in enumerate(reader, start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise DataFormatError(f"{path}:{lineno}: {len(row)} fields, header has {len(header)}")
        try:
            rows.append([float(c) for c in row])
        except ValueError as exc:
            raise DataFormatError(f"{path}:{lineno}: not a number ({exc})") from None
    data = np.array(rows, dtype=np.float64).reshape(len(rows), len(header))
    columns = {name: data[:, j].copy() for j, name in enumerate(header)}
    meta: dict[str, Any] = {}
    side = sidecar_path(path)
    if side.exists():
        try:
            loaded = yaml.safe_load(side.read_text())
        except yaml.YAMLError as exc:
            raise DataFormatError(f"{side}: invalid YAML: {exc}") from exc
        if loaded is not None and not isinstance(loaded, dict):
            raise DataFormatError(f"{side}: must be a mapping")
        meta = dict(loaded or {})
    return MeasurementTable(columns, meta, str(path))


def write_table(table: MeasurementTable, csv_path: str | Path, precision: int = 9) -> Path:
    """Write ``table`` as CSV (``t`` first, then standard columns, then extras) plus sidecar.

    Values are written with ``precision`` significant digits. Returns the CSV path.
    """
    path = Path(csv_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    order = ["t"] + [c for c in STANDARD_COLUMNS if c != "t" and c in table.columns]
    order += [c for c in table.columns if c not in order]
    data = np.column_stack([np.asarray(table.columns[c], dtype=np.float64) for c in order])
    with path.open("w", newline="") as fh:
        fh.write(",".join(order) + "\n")
        np.savetxt(fh, data, delimiter=",", fmt=f"%.{precision}g")
    meta = _plain(dict(table.meta))
    units = meta.setdefault("units", {})
    for c in order:
        if c in STANDARD_COLUMNS:
            units.setdefault(c, STANDARD_COLUMNS[c])
    sidecar_path(path).write_text(yaml.safe_dump(meta, sort_keys=False))
    return path


def _plain(obj: Any) -> Any:
    """Convert numpy scalars/arrays inside ``obj`` to plain Python for YAML."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return str(obj)
    return obj
