"""What a recorded log costs on disk, and where (run on demand, prints figures).

    .venv/bin/python -m capstan.tools.bench.log_size LOG.mcap [--fields] [--quanta 1e-5,2**-16,2**-12]

Prints cycles, covered time, file bytes, bytes per cycle and MB/hour extrapolated from
the log's own duration (``bytes / (t_last - t_first) * 3600``), split into chunk
payload and message-index bytes (read with the ``mcap`` package's indexed reader). With
``--fields``: each stored field's cost after compression, measured by re-encoding the
log's cycles without it (zstd at the live level, the live chunk length). With
``--quanta``: the chunk bytes per cycle if the rounded float32 fields were rounded to
each given quantum instead (their unrounded values recomputed by replaying the logged
controller, then re-encoded the same way).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import zstandard
from mcap.reader import make_reader

from capstan.controller.log.mcap_log import CYCLE_TOPIC, DEFAULT_FLUSH_INTERVAL_S, stored_dtype
from capstan.controller.log.mcap_writer import message_rows
from capstan.controller.log.reader import read_log
from capstan.controller.log.schema import build_layout
from capstan.controller.log.writer import LIVE_ZSTD_LEVEL


def _encoded_bytes(records: np.ndarray, dtype: np.dtype, f32: tuple[str, ...], chunk: int,
                   quanta: dict[str, float]) -> float:
    """Compressed bytes per cycle of the message records (header + payload) in chunks."""
    f32 = tuple(f for f in f32 if f in dtype.names)
    lay = build_layout(dtype, "capstan.Cycle", f32, {f: q for f, q in quanta.items() if f in f32})
    t = np.round(records["t_s"] * 1e9).astype(np.int64)
    rows = message_rows(1, t, lay.encode(records))
    cz = zstandard.ZstdCompressor(level=LIVE_ZSTD_LEVEL)
    return sum(len(cz.compress(rows[i:i + chunk].tobytes())) for i in range(0, len(rows), chunk)) / len(rows)


def _replayed(records: np.ndarray, config: dict) -> np.ndarray | None:
    """``records`` with the step outputs recomputed by the logged controller (float64,
    unrounded), or None if the log has no controller config or a different dtype."""
    from capstan.controller.law.records import MEASUREMENT_FIELDS, STEP_OUTPUT_FIELDS
    from capstan.tools.offline.replay import build_controller, replay_records
    if not config.get("controller"):
        return None
    ctl = build_controller(config)
    if ctl.record.dtype != records.dtype:
        return None
    inputs = tuple(f for f in ("cycle", *MEASUREMENT_FIELDS) if f in ctl.record.dtype.names)
    return replay_records(records, ctl, inputs, STEP_OUTPUT_FIELDS).replayed


def _compare_quanta(records: np.ndarray, ch_meta: dict[str, str], spec: str, config: dict) -> None:
    """Print chunk bytes per cycle with the quantized fields rounded to each quantum of
    ``spec`` (any positive number; only powers of two leave low mantissa bits zero)."""
    from capstan.controller.law.records import LOG_FLOAT32_QUANTA
    f32 = tuple(json.loads(ch_meta.get("float32_fields", "[]")))
    dt = stored_dtype(records.dtype, tuple(json.loads(ch_meta.get("derived_fields", "[]"))))
    names = tuple(json.loads(ch_meta.get("float32_quanta", "{}"))) or tuple(f for f in LOG_FLOAT32_QUANTA if f in f32)
    chunk = int(round(DEFAULT_FLUSH_INTERVAL_S * 1000))
    print(f"  chunk bytes per cycle with {', '.join(names)} rounded to a quantum (re-encoded):")
    print(f"    {'as stored':>12s} {_encoded_bytes(records, dt, f32, chunk, {}):6.2f}")
    exact = _replayed(records, config)               # the values before any rounding
    if exact is None:
        print("    (the log's controller cannot be replayed: the stored values are rounded instead)")
        exact = records
    print(f"    {'float32':>12s} {_encoded_bytes(exact, dt, f32, chunk, {}):6.2f}")
    for text in (x.strip() for x in spec.split(",") if x.strip()):
        base, _, exp = text.partition("**")                   # "2**-12" or "1e-5"
        q = float(base) ** float(exp) if exp else float(base)
        r = exact.copy()
        for f in names:
            r[f] = np.round(r[f] / q) * q
        print(f"    {text:>12s} {_encoded_bytes(r, dt, f32, chunk, {}):6.2f}")


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns 0."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("log", type=Path)
    p.add_argument("--fields", action="store_true", help="per-field compressed cost")
    p.add_argument("--quanta", default="",
                   help="comma-separated quanta (e.g. 1e-5,2**-16,2**-12): chunk bytes per cycle with the "
                        "rounded float32 fields (the log's, else the daemon's) re-rounded to each")
    args = p.parse_args(argv)
    size = args.log.stat().st_size
    with open(args.log, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    chunk_b = sum(c.compressed_size for c in summary.chunk_indexes)
    index_b = sum(c.message_index_length for c in summary.chunk_indexes)
    cyc_ch = next(c for c in summary.channels.values() if c.topic == CYCLE_TOPIC)
    data = read_log(args.log)
    n = len(data.records)
    dur = float(data.records["t_s"][-1] - data.records["t_s"][0]) if n > 1 else 0.0
    print(f"{args.log}: {n} cycles over {dur:.1f} s, {size} B")
    print(f"  {size / n:.1f} B/cycle = {size / dur * 3600 / 1e6:.0f} MB/hour "
          f"(chunks {chunk_b / n:.1f} B/cycle, message indexes {index_b / n:.1f} B/cycle)")
    if args.quanta:
        _compare_quanta(data.records, cyc_ch.metadata, args.quanta, data.config)
    if args.fields:
        f32 = tuple(json.loads(cyc_ch.metadata.get("float32_fields", "[]")))
        dropped = tuple(json.loads(cyc_ch.metadata.get("derived_fields", "[]")))
        quanta = json.loads(cyc_ch.metadata.get("float32_quanta", "{}"))
        dt = stored_dtype(data.records.dtype, dropped)
        chunk = int(round(DEFAULT_FLUSH_INTERVAL_S * 1000))
        base = _encoded_bytes(data.records, dt, f32, chunk, quanta)
        print(f"  cycle messages re-encoded: {base:.1f} B/cycle compressed; per stored field "
              "(size with minus without it):")
        for name in dt.names:
            cost = base - _encoded_bytes(data.records, stored_dtype(dt, (name,)), f32, chunk, quanta)
            kind = str(dt[name]) if name not in f32 else "float32" if name not in quanta else f"f32/{quanta[name]:.2g}"
            print(f"    {name:22s} {kind:9s} {cost:6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
