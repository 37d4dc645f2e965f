"""``capstan decode xsens|loadcell CAPTURE [--json] [--config YAML]``.

Decodes a raw serial capture (the bytes as they came off the line, e.g. from
``cat /dev/ttyUSB0 > capture.bin`` or a logic-analyser export) frame by frame and
prints one line per frame, then a summary line with good/bad frame counts, counter
gaps and resyncs. With ``--json`` every line is a JSON object (JSON lines); the last
one has ``"summary": true``. With ``--config`` (a YAML file with an ``imu`` or
``load_cells`` section) the joint angle/rate or the tensions in N are added.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any, Iterator

from capstan.drivers.interfaces import LinkStats
from capstan.models.common.errors import DataFormatError, ProtocolError

HELP = "decode a raw serial capture (xsens | loadcell) into JSON lines"
_CHUNK = 1 << 16


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``capstan decode``."""
    parser.add_argument("device", choices=("xsens", "loadcell"), help="protocol of the capture")
    parser.add_argument("capture", type=Path, help="raw byte capture file")
    parser.add_argument("--json", action="store_true", help="JSON lines output")
    parser.add_argument("--config", type=Path, default=None,
                        help="YAML with an 'imu' / 'load_cells' section: add joint values / tensions [N]")


def _clean(x: Any) -> Any:
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, (tuple, list)):
        return [_clean(v) for v in x]
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    return x


def _chunks(path: Path) -> Iterator[bytes]:
    try:
        with path.open("rb") as f:
            while True:
                b = f.read(_CHUNK)
                if not b:
                    return
                yield b
    except OSError as exc:
        raise DataFormatError(f"cannot read capture {path}: {exc.strerror or exc}") from exc


def _section(path: Path | None, key: str, backend: str) -> dict[str, Any] | None:
    """The device section of a config file as the driver's config class takes it.

    ``backend`` is dropped as :func:`capstan.drivers.registry.create` drops it (it selects
    the class); a backend other than the decoder's protocol is refused.

    :raises ConfigError: naming the key, if the section is missing or of another backend.
    """
    if path is None:
        return None
    from capstan.models.common.config_tools import load_yaml, section
    from capstan.models.common.errors import ConfigError

    cfg = dict(section(load_yaml(path), key))
    name = cfg.pop("backend", backend)
    if name != backend:
        raise ConfigError(f"{key}.backend", f"this capture is decoded as {backend!r}, the config selects {name!r}")
    cfg.setdefault("port", "capture")
    return cfg


def decode_xsens(path: Path, config: Path | None = None) -> Iterator[dict[str, Any]]:
    """Decoded records of an Xsens capture; the last one is the summary.

    :raises DataFormatError: if the capture cannot be read.
    :raises ConfigError: if ``config`` has no valid ``imu`` section.
    """
    from capstan.drivers.serial.xsens import XsensConfig, joint_from_mtdata2
    from capstan.drivers.serial.xsens_protocol import (
        CoordSys, Mid, XbusParser, decode_output_configuration, error_name, mtdata2_well_formed, parse_mtdata2,
        xdi_name,
    )

    sec = _section(config, "imu", "xsens")
    imu_cfg = XsensConfig.from_mapping(sec) if sec is not None else None
    stats = LinkStats()
    parser = XbusParser(stats, validators={Mid.MT_DATA2: mtdata2_well_formed})
    n_bytes = 0
    last_counter = -1
    frame = 0
    for chunk in _chunks(path):
        n_bytes += len(chunk)
        for mid, data in parser.feed(chunk):
            frame += 1
            try:
                mid_name = Mid(mid).name
            except ValueError:
                mid_name = f"MID_0x{mid:02X}"
            rec: dict[str, Any] = {"frame": frame, "mid": mid_name}
            if mid == Mid.MT_DATA2:
                try:
                    m = parse_mtdata2(data)
                except ProtocolError as exc:
                    stats.bad_frames += 1
                    rec["error"] = str(exc)
                    yield rec
                    continue
                for key in ("packet_counter", "sample_time_fine", "quaternion", "euler_deg",
                            "rate_of_turn_rad_s", "status_word"):
                    val = getattr(m, key)
                    if val is not None:
                        rec[key] = val
                if m.coord_sys is not None:
                    try:
                        rec["coord_sys"] = CoordSys(m.coord_sys).name
                    except ValueError:
                        rec["coord_sys"] = f"COORD_0x{m.coord_sys:X}"
                if m.other:
                    rec["other"] = {xdi_name(k): (v.hex(" ") if isinstance(v, bytes) else v)
                                    for k, v in m.other.items()}
                if imu_cfg is not None:
                    joint = joint_from_mtdata2(m, imu_cfg)
                    if joint is not None:
                        rec["q_out_rad"], rec["dq_out_rad_s"] = joint
                if m.packet_counter is not None:
                    if last_counter >= 0:
                        d = (m.packet_counter - last_counter) & 0xFFFF
                        if d > 1:
                            stats.counter_gaps += d - 1
                            rec["counter_gap"] = d - 1
                    last_counter = m.packet_counter
            elif mid == Mid.ERROR:
                code = data[0] if data else -1
                rec["error_code"] = code
                rec["error"] = error_name(code)
            elif mid in (Mid.OUTPUT_CONFIGURATION, Mid.SET_OUTPUT_CONFIGURATION) and len(data) % 4 == 0:
                rec["output_configuration"] = [[xdi_name(x), f] for x, f in decode_output_configuration(data)]
            elif data:
                rec["data_hex"] = data.hex(" ")
            stats.good_frames += 1
            yield rec
    yield {"summary": True, "bytes": n_bytes, "good_frames": stats.good_frames, "bad_frames": stats.bad_frames,
           "counter_gaps": stats.counter_gaps, "resyncs": stats.resyncs, "bytes_skipped": stats.bytes_skipped,
           "trailing_bytes": parser.buffered}


def decode_loadcell(path: Path, config: Path | None = None) -> Iterator[dict[str, Any]]:
    """Decoded records of a load-cell amplifier capture; the last one is the summary.

    :raises DataFormatError: if the capture cannot be read.
    :raises ConfigError: if ``config`` has no valid ``load_cells`` section.
    """
    from capstan.drivers.serial.loadcell import LoadCellConfig, SerialLoadCells
    from capstan.drivers.serial.loadcell_protocol import LoadCellParser

    sec = _section(config, "load_cells", "serial")
    conv = SerialLoadCells(LoadCellConfig.from_mapping(sec)) if sec is not None else None
    parser = LoadCellParser()
    n_bytes = 0
    frame = 0
    for chunk in _chunks(path):
        n_bytes += len(chunk)
        for raw in parser.feed(chunk):
            frame += 1
            rec: dict[str, Any] = {"frame": frame, "raw_mV_V": raw}
            if conv is not None:
                rec["tensions_N"] = conv.to_tensions_N(raw)
            yield rec
    st = parser.stats
    yield {"summary": True, "bytes": n_bytes, "good_frames": st.good_frames, "bad_frames": st.bad_frames,
           "resyncs": st.resyncs, "bytes_skipped": st.bytes_skipped, "trailing_bytes": parser.buffered}


def _text(rec: dict[str, Any]) -> str:
    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.8g}"
        if isinstance(v, (list, tuple)):
            return "(" + ", ".join(fmt(x) for x in v) + ")"
        return str(v)

    if rec.get("summary"):
        return "summary: " + " ".join(f"{k}={v}" for k, v in rec.items() if k != "summary")
    head = f"#{rec['frame']}" + (f" {rec['mid']}" if "mid" in rec else "")
    body = " ".join(f"{k}={fmt(v)}" for k, v in rec.items() if k not in ("frame", "mid"))
    return f"{head} {body}".rstrip()


def run(args: argparse.Namespace) -> int:
    """Decode and print; exit code 0 (1 if the capture held no valid frame).

    :raises DataFormatError: if the capture cannot be read.
    :raises ConfigError: on a bad ``--config``.
    """
    if not args.capture.is_file():
        raise DataFormatError(f"capture file not found: {args.capture}")
    gen = decode_xsens if args.device == "xsens" else decode_loadcell
    out = sys.stdout
    last: dict[str, Any] = {}
    try:
        for rec in gen(args.capture, args.config):
            if args.json:
                out.write(json.dumps(_clean(rec)) + "\n")
            else:
                out.write(_text(rec) + "\n")
            last = rec
    except BrokenPipeError:  # e.g. piped into head
        return 0
    return 0 if last.get("good_frames", 0) > 0 else 1
