"""The archive form of a log: a lossless columnar rewrite of a live log.

``write_archive(LIVE, OUT)`` keeps what the live log stores and nothing twice:

* the cycles as columnar blocks, one message per second of cycles on
  ``/capstan/archive/cycles`` (:mod:`capstan.controller.log.columns`: time deltas, device
  receive times as ages, byte-shuffled columns), of the live file's stored fields (wire
  values; the SI values follow from them with the ``capstan.derivations`` metadata);
* the step's outputs only where they are needed: each output the replay of the archived
  inputs with the logged config reproduces bit for bit (at the live log's storage
  precision) on every cycle is left out and recomputed on reading; any other is stored
  as a column (a later file of a rotated run, whose controller state at the start is
  unknown, keeps them all) — so the archive is lossless by construction and checked at
  writing;
* events and stats as they are, and the live file's metadata.

``read_any(PATH)`` reads either form into the same :class:`LogData` (the archive's
records equal the live file's, bit for bit).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from mcap.reader import make_reader

from capstan.controller.log.columns import BLOCK_MESSAGE, Column, block_schema, decode_block, encode_block
from capstan.controller.log.mcap_log import CYCLE_TOPIC, DERIVATIONS_META, EVENTS_TOPIC, STATS_TOPIC, stored_dtype
from capstan.controller.log.mcap_writer import McapChunkWriter
from capstan.controller.log.reader import LogData, read_log, rebuild_derived
from capstan.controller.log.ring import dtype_from_json, dtype_to_json
from capstan.controller.log.schema import build_layout, quantize_float32
from capstan.models.common.errors import DataFormatError

ARCHIVE_TOPIC = "/capstan/archive/cycles"
ARCHIVE_META = "capstan.archive"
ARCHIVE_ZSTD_LEVEL = 19
_AGE_FIELDS = ("lc_t_ns", "imu_t_ns", "motor_t_ns")


@dataclass
class ArchiveResult:
    """What :func:`write_archive` wrote: sizes [bytes], cycles, recomputed fields."""

    path: Path
    source_bytes: int
    archive_bytes: int
    cycles: int
    duration_s: float
    recomputed: tuple[str, ...]


def _replay_outputs(data: LogData) -> np.ndarray | None:
    """The replayed records of a live log, or None if it cannot be replayed."""
    from capstan.controller.law.records import MEASUREMENT_FIELDS, STEP_OUTPUT_FIELDS
    from capstan.tools.offline.replay import build_controller, replay_records
    if not data.config.get("controller") or data.meta.get("file_index", "0") != "0":
        return None
    ctl = build_controller(data.config)
    inputs = tuple(f for f in ("cycle", *MEASUREMENT_FIELDS) if f in ctl.record.dtype.names)
    if ctl.record.dtype != data.records.dtype:
        return None
    return replay_records(data.records, ctl, inputs, STEP_OUTPUT_FIELDS).replayed


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes()


def _as_stored(values: np.ndarray, f32: bool, quantum: float | None = None) -> np.ndarray:
    """``values`` as the live log stores them (float32, rounded to ``quantum`` if given)."""
    if quantum is not None:
        return quantize_float32(values, quantum).astype(np.float64)
    return values.astype(np.float32).astype(np.float64) if f32 else values


def write_archive(src: str | Path, out: str | Path,
                  progress: Callable[[int, int], None] | None = None) -> ArchiveResult:
    """Rewrite the live log ``src`` as an archive ``out``.

    :raises DataFormatError: if ``src`` is not a readable capstan log, is already an
        archive, or the written archive does not read back equal (checked).
    """
    from capstan.controller.law.records import STEP_OUTPUT_FIELDS
    src, out = Path(src), Path(out)
    data = read_log(src, progress)
    if data.meta.get("archive"):
        raise DataFormatError(f"{src}: already an archive")
    with open(src, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        if summary is None:
            raise DataFormatError(f"{src}: no summary (run `capstan recover` on it first)")
        metas = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        chans = {c.topic: c for c in summary.channels.values()}
        others = [(ch.topic, m.log_time, m.data) for _, ch, m in reader.iter_messages(
            topics=[EVENTS_TOPIC, STATS_TOPIC], log_time_order=False)]
    cyc = chans[CYCLE_TOPIC]
    f32 = tuple(json.loads(cyc.metadata.get("float32_fields", "[]")))
    dropped = tuple(json.loads(cyc.metadata.get("derived_fields", "[]")))
    quanta = {k: float(v) for k, v in json.loads(cyc.metadata.get("float32_quanta", "{}")).items()}
    rec = data.records
    stored = stored_dtype(rec.dtype, dropped)
    replayed = _replay_outputs(data)
    recomputed = tuple(f for f in STEP_OUTPUT_FIELDS if f in stored.names and replayed is not None
                       and _same_bits(_as_stored(replayed[f], f in f32, quanta.get(f)), rec[f]))
    cols = []
    time_col = "t_ns" if "t_ns" in stored.names else ""
    for name in stored.names:
        if name in recomputed:
            continue
        dt = np.dtype("<f4") if name in f32 else stored[name]
        tr = "delta" if name in ("t_ns", "cycle") else "age_delta" if (name in _AGE_FIELDS and time_col) else "raw"
        cols.append(Column(name, dt, tr))
    if time_col:
        cols.sort(key=lambda c: c.name != time_col)          # the time column first
    with open(out, "wb") as oh:
        w = McapChunkWriter(oh, "zstd", ARCHIVE_ZSTD_LEVEL, chunk_size_bytes=4 << 20)
        w.start(library="capstan archive")
        for name, values in metas.items():
            w.add_metadata(name, values)
        w.add_metadata(ARCHIVE_META, {
            "format_version": "1", "source": src.name, "columns": json.dumps([c.to_json() for c in cols]),
            "record_dtype": json.dumps(dtype_to_json(rec.dtype)), "recomputed_fields": json.dumps(recomputed),
            "float32_fields": json.dumps(f32), "float32_quanta": json.dumps(quanta), "time_column": time_col})
        sid = w.register_schema(BLOCK_MESSAGE, "protobuf", block_schema(cols))
        ach = w.register_channel(ARCHIVE_TOPIC, "protobuf", sid, {})
        ids = {}
        for topic in (EVENTS_TOPIC, STATS_TOPIC):
            if topic in chans:
                sch = summary.schemas[chans[topic].schema_id]
                ids[topic] = w.register_channel(topic, chans[topic].message_encoding,
                                                w.register_schema(sch.name, sch.encoding, sch.data),
                                                dict(chans[topic].metadata))
        t_ns = np.round(rec["t_s"] * 1e9).astype(np.int64) if len(rec) else np.zeros(0, np.int64)
        sec = (t_ns - (t_ns[0] if len(t_ns) else 0)) // 1_000_000_000
        bounds = np.flatnonzero(np.diff(sec)) + 1 if len(sec) else np.zeros(0, np.int64)
        for a, b in zip(np.r_[0, bounds], np.r_[bounds, len(rec)]):
            if b > a:
                w.add_message(ach, int(t_ns[a]), encode_block(cols, rec[a:b], time_col))
        for topic, t, payload in others:
            w.add_message(ids[topic], t, payload)
        w.finish()
    back = read_archive(out)
    for name in rec.dtype.names:
        if not _same_bits(back.records[name], rec[name]):
            raise DataFormatError(f"{out}: field {name} does not read back bit for bit; archive not usable")
    dur = float(rec["t_s"][-1] - rec["t_s"][0]) if len(rec) > 1 else 0.0
    return ArchiveResult(out, src.stat().st_size, out.stat().st_size, len(rec), dur, recomputed)


def read_archive(path: str | Path) -> LogData:
    """Read an archive written by :func:`write_archive` (records recomputed where the
    archive says so).

    :raises DataFormatError: if the file is not a capstan archive or does not decode.
    """
    p = Path(path)
    try:
        fh = open(p, "rb")
    except OSError as exc:
        raise DataFormatError(f"{p}: cannot open: {exc.strerror or exc}") from exc
    with fh:
        reader = make_reader(fh)
        metas = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        if ARCHIVE_META not in metas:
            raise DataFormatError(f"{p}: not a capstan archive (no {ARCHIVE_META} metadata)")
        am = metas[ARCHIVE_META]
        cols = [Column.from_json(c) for c in json.loads(am["columns"])]
        time_col = am.get("time_column", "")
        parts: list[dict[str, np.ndarray]] = []
        events, stats_raw, stats_ch = [], [], None
        for _, ch, m in reader.iter_messages(log_time_order=False):
            if ch.topic == ARCHIVE_TOPIC:
                parts.append(decode_block(cols, m.data, time_col))
            elif ch.topic == EVENTS_TOPIC:
                events.append(json.loads(m.data))
            elif ch.topic == STATS_TOPIC:
                stats_raw.append(m.data)
                stats_ch = ch
    record_dtype = dtype_from_json(json.loads(am["record_dtype"]))
    recomputed = tuple(json.loads(am["recomputed_fields"]))
    f32 = set(json.loads(am.get("float32_fields", "[]")))
    quanta = {k: float(v) for k, v in json.loads(am.get("float32_quanta", "{}")).items()}
    held = np.dtype([(c.name, c.dtype) for c in cols])
    st = np.zeros(sum(len(x[cols[0].name]) for x in parts) if parts and cols else 0, held)
    for c in cols:
        st[c.name] = np.concatenate([x[c.name] for x in parts]) if parts else []
    partial = np.dtype([(n, record_dtype[n]) for n in record_dtype.names if n not in recomputed])
    records = np.zeros(len(st), record_dtype)
    base = rebuild_derived(st, partial, metas.get(DERIVATIONS_META, {}).get("derivations"), p)
    for n in partial.names:
        records[n] = base[n]
    if recomputed:
        config_yaml = metas.get("capstan.config", {}).get("yaml", "")
        data = LogData(p, records, config_yaml, _yaml(config_yaml, p), metas.get("capstan.log", {}))
        replayed = _replay_outputs(data)
        if replayed is None:
            raise DataFormatError(f"{p}: archive needs the replay to rebuild {', '.join(recomputed)}, "
                                  "but the stored config does not build a controller")
        for n in recomputed:
            records[n] = _as_stored(replayed[n], n in f32, quanta.get(n))
    stats = None
    if stats_ch is not None and stats_raw:
        lay = build_layout(dtype_from_json(json.loads(stats_ch.metadata["numpy_dtype"])), "capstan.Stats")
        stats = np.concatenate([lay.decode(b) for b in stats_raw])
    meta = dict(metas.get("capstan.log", {}), archive="1")
    config_yaml = metas.get("capstan.config", {}).get("yaml", "")
    return LogData(p, records, config_yaml, _yaml(config_yaml, p), meta, events, stats, False)


def _yaml(text: str, p: Path) -> dict:
    import yaml
    try:
        cfg = yaml.safe_load(text) if text else {}
    except yaml.YAMLError as exc:
        raise DataFormatError(f"{p}: stored config is not valid YAML: {exc}") from exc
    return cfg if isinstance(cfg, dict) else {}


def is_archive(path: str | Path) -> bool:
    """True if ``path`` is an archive (has the archive metadata); False for anything else."""
    try:
        with open(path, "rb") as fh:
            return any(m.name == ARCHIVE_META for m in make_reader(fh).iter_metadata())
    except Exception:  # noqa: BLE001 - a cut-off or foreign file is simply not an archive
        return False


def read_any(path: str | Path, progress: Callable[[int, int], None] | None = None,
             fields: tuple[str, ...] | None = None) -> LogData:
    """Read a live log or an archive into the same :class:`LogData`.

    :param fields: for a live log, the cycle fields to read (see :func:`read_log`); an
        archive is read whole.
    :raises DataFormatError: as :func:`read_log` / :func:`read_archive`.
    """
    return read_archive(path) if is_archive(path) else read_log(path, progress, fields)
