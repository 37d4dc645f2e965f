"""Load runs for the offline tools: a measurement table (``RUN.csv`` + sidecar), a
file of another layout through an import description, or a daemon MCAP log.

* ``*.csv`` -> :func:`capstan.models.common.measurement_table.read_table`
* ``*.mcap`` -> :func:`capstan.tools.offline.archive.read_any` (live log or archive) + the export mapping of
  ``capstan.tools.offline.log_table.records_to_table``; only the measurement channels (and channels
  whose name says temperature) are kept, not the controller's internal terms, which
  would otherwise "explain" the residual by echoing the measurement
* anything else -> needs an import description (``--import DESC.yaml``)

The output torque of a daemon log: when the log has no ``tau_out`` (the link use case
has no output torque sensor), it is the cable torque on the output pulley from the
output-side load cells, ``r_out (T_up_out - T_lo_out)``; failing those, a
``tau_out_Nm`` / ``tau_load_Nm`` style field is used; otherwise the run cannot be closed
and a DataFormatError says so.
"""

from __future__ import annotations

from pathlib import Path

from capstan.models.common.errors import DataFormatError
from capstan.tools.offline.importer import ImportDescription
from capstan.models.common.measurement_table import STANDARD_COLUMNS, MeasurementTable, read_table

#: record fields that may carry the transmitted output torque in a daemon log
_TAU_OUT_FIELDS = ("tau_out_Nm", "tau_out_meas_Nm", "tau_link_Nm", "tau_load_Nm")


def _from_mcap(path: Path) -> MeasurementTable:
    try:
        from capstan.tools.offline.archive import read_any
        from capstan.tools.offline.log_table import records_to_table
    except ImportError as exc:  # pragma: no cover - both modules are part of the package
        raise DataFormatError(f"{path}: MCAP logs need controller.log_reader ({exc})") from exc
    data = read_any(path)                    # a live log or its archive
    table = records_to_table(data.records, data.config, str(path))
    cols = {k: v for k, v in table.columns.items() if k in STANDARD_COLUMNS or "temp" in k.lower()}
    if "tau_out" not in cols and {"T_up_out_N", "T_lo_out_N"} <= set(table.columns):
        cols["tau_out"] = float(table.meta["r_out"]) * (table.columns["T_up_out_N"] - table.columns["T_lo_out_N"])
    if "tau_out" not in cols:
        for f in _TAU_OUT_FIELDS:
            if f in table.columns:
                cols["tau_out"] = table.columns[f]
                break
    if "tau_out" not in cols or "tau_in" not in cols:
        raise DataFormatError(f"{path}: the log has no output torque (tau_out) or no input torque; "
                              "the closure predicts tau_out from tau_in and needs both")
    t0 = float(cols["t"][0])
    cols["t"] = cols["t"] - t0
    meta = dict(table.meta)
    meta["t0_s"] = t0
    return MeasurementTable(cols, meta, str(path))


def load_run(path: str | Path, description: ImportDescription | None = None) -> MeasurementTable:
    """Load one run (see module docstring).

    :raises DataFormatError: if the file cannot be read or mapped.
    :raises ConfigError: if the import description is invalid.
    """
    p = Path(path)
    if not p.exists():
        raise DataFormatError(f"{p}: no such file")
    suffix = p.suffix.lower()
    if description is not None and suffix not in (".mcap",):
        return description.read(p)
    if suffix == ".csv":
        return read_table(p)
    if suffix == ".mcap":
        return _from_mcap(p)
    raise DataFormatError(f"{p}: unknown layout '{suffix}'; give an import description with --import "
                          "(e.g. config/imports/davinci.yaml)")


def load_runs(paths: list[str], import_path: str | None = None) -> list[MeasurementTable]:
    """Load several runs with an optional import description path.

    :raises DataFormatError: if a file cannot be read or mapped.
    :raises ConfigError: if the import description is invalid.
    """
    desc = ImportDescription.load(import_path) if import_path else None
    return [load_run(p, desc) for p in paths]
