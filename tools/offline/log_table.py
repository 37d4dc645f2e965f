"""A daemon log as a measurement table (the library part of ``capstan export``, also used
when the offline tools are given a log).

Standard columns (see :mod:`capstan.models.common.measurement_table`) from the cycle records::

    t        = t_s
    tau_in   = r_in (T_up_in_N - T_lo_in_N)        r_in from the logged controller config
    q_out    = q_out_rad,  dq_out = dq_out_rad_s
    T_lc_in  = (T_up_in_N + T_lo_in_N) / 2         mean tension at the input-side fixtures
    T_lc_out = (T_up_out_N + T_lo_out_N) / 2       mean tension at the output-side fixtures
    q_in     = q_m_rad                             motor position (drives the input pulley)

The sidecar declares ``output: link`` (the daemon's output is a link moved by forces the
log does not measure; the closure's dynamic baseline then drives by q_in and tau_out).

Every record field is also written as an extra column under its own name (units in
the sidecar). A standard column whose source fields are absent is left out.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from capstan.models.common.errors import DataFormatError

def _controller_section(cfg: Mapping[str, Any]) -> Any:
    from capstan.controller.law.config import ControllerConfig
    section = cfg.get("controller")
    return ControllerConfig.from_mapping(section if isinstance(section, Mapping) else {})


def records_to_table(records: np.ndarray, config: Mapping[str, Any], source: str = "") -> Any:
    """Map cycle records onto a :class:`capstan.models.common.measurement_table.MeasurementTable`.

    :raises DataFormatError: if ``t_s`` is missing or no torque column can be formed,
        or the table invariants fail (e.g. ``t_s`` not increasing).
    :raises ConfigError: if the stored controller config is invalid.
    """
    from capstan.models.common.measurement_table import MeasurementTable

    names = set(records.dtype.names or ())
    if "t_s" not in names:
        raise DataFormatError(f"{source}: records have no 't_s' field")
    cc = _controller_section(config)
    r_in = cc.plant.r_in_m
    f8 = lambda name: records[name].astype(np.float64)  # noqa: E731
    cols: dict[str, np.ndarray] = {"t": f8("t_s")}
    if {"T_up_in_N", "T_lo_in_N"} <= names:
        cols["tau_in"] = r_in * (f8("T_up_in_N") - f8("T_lo_in_N"))
        cols["T_lc_in"] = 0.5 * (f8("T_up_in_N") + f8("T_lo_in_N"))
    if {"T_up_out_N", "T_lo_out_N"} <= names:
        cols["T_lc_out"] = 0.5 * (f8("T_up_out_N") + f8("T_lo_out_N"))
    for std, field in (("q_out", "q_out_rad"), ("dq_out", "dq_out_rad_s"), ("q_in", "q_m_rad")):
        if field in names:
            cols[std] = f8(field)
    for name in records.dtype.names:
        cols[name] = f8(name)
    units: dict[str, str] = {}
    try:
        from capstan.controller.law.records import RECORD_UNITS
        units = {n: RECORD_UNITS[n] for n in records.dtype.names if n in RECORD_UNITS}
    except ImportError:  # pragma: no cover - records module is part of the package
        pass
    ff = cc.feedforward
    meta: dict[str, Any] = {
        "r_in": cc.plant.r_in_m, "r_out": cc.plant.r_out_m, "mu": ff.mu,
        "length": ff.routing_length_m,
        "curvature_profile": [list(p) for p in ff.routing_profile],
        "source_log": source,
        "output": _output_kind(config),
        "mapping": {"tau_in": "r_in (T_up_in_N - T_lo_in_N)", "T_lc_in": "(T_up_in_N + T_lo_in_N)/2",
                    "T_lc_out": "(T_up_out_N + T_lo_out_N)/2", "q_in": "q_m_rad",
                    "q_out": "q_out_rad", "dq_out": "dq_out_rad_s", "t": "t_s"},
        "units": units,
    }
    return MeasurementTable(cols, meta, source)


def _output_kind(config: Mapping[str, Any]) -> str:
    """"link": the daemon drives a link moved by a hand and gravity, forces its log does not
    measure; "testbed" only when the logged config's simulated plant (``hil.plant.output.mode``)
    is the testbed."""
    hil = config.get("hil")
    plant = hil.get("plant") if isinstance(hil, Mapping) else None
    out = plant.get("output") if isinstance(plant, Mapping) else None
    return "testbed" if isinstance(out, Mapping) and out.get("mode") == "testbed" else "link"
