"""Import descriptions: map a delimited text file of another layout onto the
measurement-table channels (``tools.measurement_table``) without code written for
one file.

An import description is a YAML mapping::

    name: davinci-cable-tool          # free text, shown in reports
    delimiter: ","                     # field separator (default ","; "whitespace" allowed)
    comment: "%"                       # lines starting with this are header/comments
    skip_rows: 0                       # further non-comment lines to skip at the top
    header: comment                    # where column names are: comment | first_row | none
    channels:                          # channel -> column mapping
      t:      {column: 1, scale: 1.0, unit: s}
      q_in:   {column: 2, scale: "2*pi/8192", unit: rad}
      tau_out: {column: "Front-end Futek Torque [counts]", scale: 3.9811e-5, sign: -1, unit: Nm}
    meta: {r_in: 0.04}                 # copied into the table's sidecar meta
    # an extra channel that measures a torque channel or is tied to it algebraically
    # (a drive current, an environment command) is marked so, and the closure never
    # takes it for a mechanism:   current_in: {column: 4, unit: A, tied_to: tau_in}
    attribution: "..."                 # licence / citation text, copied into meta

Per channel: ``column`` is a 1-based index or a header name (matched case- and
whitespace-insensitively); ``value = sign * (scale * raw + offset)`` with ``offset``
in the channel's unit; ``sign`` is +1 or -1; ``scale`` is a number or an arithmetic
expression with ``pi``; ``unit`` must equal the standard unit for the standard
channels (``t`` s, ``tau_*`` Nm, ``q_*`` rad, ``dq_out`` rad/s, ``T_lc_*`` N) and is
recorded for extra channels. Rows whose time does not increase are dropped (and
counted in ``meta['import']``); blank lines are ignored anywhere.
"""

from __future__ import annotations

import ast
import math
import operator
import re
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from capstan.models.common.config_tools import get_choice, get_int, load_yaml, reject_unknown
from capstan.models.common.errors import ConfigError, DataFormatError
from capstan.models.common.measurement_table import STANDARD_COLUMNS, MeasurementTable

_TOP_KEYS = frozenset({"name", "delimiter", "comment", "skip_rows", "header", "channels", "meta",
                       "attribution", "description"})
_CHANNEL_KEYS = frozenset({"column", "scale", "offset", "sign", "unit", "description", "tied_to"})
#: what ``tied_to`` may name: the measured torques a channel can be a second look at
_TIE_TARGETS = ("tau_in", "tau_out")
_OPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
        ast.Div: operator.truediv, ast.Pow: operator.pow, ast.USub: operator.neg, ast.UAdd: operator.pos}


def _eval_number(expr: Any, key: str) -> float:
    """A number or a safe arithmetic expression (``+ - * / **``, ``pi``, ``e``).

    :raises ConfigError: naming ``key`` if the expression is invalid or not finite.
    """
    if isinstance(expr, bool):
        raise ConfigError(key, f"must be a number, got {expr!r}")
    if isinstance(expr, (int, float)):
        val = float(expr)
    elif isinstance(expr, str):
        def ev(node: ast.AST) -> float:
            if isinstance(node, ast.Expression):
                return ev(node.body)
            if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) \
                    and not isinstance(node.value, bool):
                return float(node.value)
            if isinstance(node, ast.Name) and node.id in ("pi", "e"):
                return math.pi if node.id == "pi" else math.e
            if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
                return _OPS[type(node.op)](ev(node.left), ev(node.right))
            if isinstance(node, ast.UnaryOp) and type(node.op) in _OPS:
                return _OPS[type(node.op)](ev(node.operand))
            raise ValueError("only numbers, pi, e and + - * / ** are allowed")
        try:
            val = ev(ast.parse(expr, mode="eval"))
        except (SyntaxError, ValueError, ZeroDivisionError) as exc:
            raise ConfigError(key, f"invalid expression {expr!r}: {exc}") from None
    else:
        raise ConfigError(key, f"must be a number or expression, got {expr!r}")
    if not math.isfinite(val):
        raise ConfigError(key, f"must be finite, got {expr!r}")
    return val


def _norm(name: str) -> str:
    return re.sub(r"\s+", " ", name.strip().lower())


class ImportDescription:
    """A validated import description (see module docstring).

    :raises ConfigError: on construction if any key is missing or invalid.
    """

    def __init__(self, cfg: Mapping[str, Any], where: str = "import") -> None:
        reject_unknown(cfg, _TOP_KEYS, where)
        self.where = where
        self.name = str(cfg.get("name", where))
        delim = cfg.get("delimiter", ",")
        if not isinstance(delim, str) or not delim:
            raise ConfigError(f"{where}.delimiter", f"must be a non-empty string, got {delim!r}")
        self.delimiter: str | None = None if delim == "whitespace" else delim
        comment = cfg.get("comment", "#")
        if not isinstance(comment, str) or not comment:
            raise ConfigError(f"{where}.comment", f"must be a non-empty string, got {comment!r}")
        self.comment = comment
        self.skip_rows = get_int(cfg, "skip_rows", where, 0, min_value=0)
        self.header = get_choice(cfg, "header", ("comment", "first_row", "none"), where, "none")
        chans = cfg.get("channels")
        if not isinstance(chans, Mapping) or not chans:
            raise ConfigError(f"{where}.channels", "missing or empty mapping channel -> column")
        if "t" not in chans:
            raise ConfigError(f"{where}.channels.t", "the time channel 't' is required")
        if "tau_in" not in chans and "tau_out" not in chans:
            raise ConfigError(f"{where}.channels", "needs at least one of tau_in, tau_out")
        self.channels: dict[str, dict[str, Any]] = {}
        #: extra channels that measure a torque channel or are tied to it algebraically
        #: (a drive current, an environment command): never candidate mechanisms of the closure
        self.tied_to: dict[str, str] = {}
        for ch, spec in chans.items():
            key = f"{where}.channels.{ch}"
            if not isinstance(spec, Mapping):
                raise ConfigError(key, "must be a mapping {column, scale, offset, sign, unit}")
            reject_unknown(spec, _CHANNEL_KEYS, key)
            col = spec.get("column")
            if isinstance(col, bool) or not isinstance(col, (int, str)) or (isinstance(col, int) and col < 1):
                raise ConfigError(f"{key}.column", f"must be a 1-based index or a header name, got {col!r}")
            sign = spec.get("sign", 1)
            if sign not in (1, -1):
                raise ConfigError(f"{key}.sign", f"must be 1 or -1, got {sign!r}")
            unit = spec.get("unit")
            std = STANDARD_COLUMNS.get(str(ch))
            if std is not None and unit is not None and unit != std:
                raise ConfigError(f"{key}.unit", f"channel '{ch}' is in {std}; scale the raw value "
                                                 f"to {std} and write unit: {std} (got {unit!r})")
            if std is None and unit is None:
                raise ConfigError(f"{key}.unit", "extra channels must state their unit")
            tied = spec.get("tied_to")
            if tied is not None:
                if tied not in _TIE_TARGETS:
                    raise ConfigError(f"{key}.tied_to", f"must be one of {', '.join(_TIE_TARGETS)}, got {tied!r}")
                if std is not None:
                    raise ConfigError(f"{key}.tied_to", f"only extra channels can be marked; '{ch}' is a standard channel")
                self.tied_to[str(ch)] = str(tied)
            self.channels[str(ch)] = {
                "column": col,
                "scale": _eval_number(spec.get("scale", 1.0), f"{key}.scale"),
                "offset": _eval_number(spec.get("offset", 0.0), f"{key}.offset"),
                "sign": float(sign),
                "unit": unit or std,
            }
        meta = cfg.get("meta", {}) or {}
        if not isinstance(meta, Mapping):
            raise ConfigError(f"{where}.meta", "must be a mapping")
        self.meta = dict(meta)
        if "attribution" in cfg:
            self.meta["attribution"] = str(cfg["attribution"])

    @staticmethod
    def load(path: str | Path) -> "ImportDescription":
        """Load and validate an import description YAML file.

        :raises ConfigError: if the file is unreadable or invalid.
        """
        return ImportDescription(load_yaml(path), str(path))

    def _split(self, line: str) -> list[str]:
        parts = line.split(self.delimiter) if self.delimiter else line.split()
        return [p.strip() for p in parts]

    def read(self, path: str | Path) -> MeasurementTable:
        """Read one data file with this description.

        :raises DataFormatError: if the file is unreadable, a field is not a number,
            a named column is not in the header, or the table invariants fail.
        """
        p = Path(path)
        try:
            lines = p.read_text(errors="replace").splitlines()
        except OSError as exc:
            raise DataFormatError(f"{p}: cannot read: {exc.strerror or exc}") from exc
        comments: list[str] = []
        data_lines: list[tuple[int, str]] = []
        skipped = 0
        for lineno, line in enumerate(lines, start=1):
            s = line.strip()
            if not s:
                continue
            if s.startswith(self.comment):
                comments.append(s[len(self.comment):])
                continue
            if skipped < self.skip_rows:
                skipped += 1
                continue
            data_lines.append((lineno, s))
        header: list[str] | None = None
        if self.header == "first_row" and data_lines:
            header = self._split(data_lines.pop(0)[1])
        if not data_lines:
            raise DataFormatError(f"{p}: no data rows")
        n_fields = len(self._split(data_lines[0][1]))
        if self.header == "comment":
            for c in reversed(comments):
                fields = self._split(c)
                if len(fields) == n_fields:
                    header = fields
                    break
        index: dict[str, int] = {}
        for ch, spec in self.channels.items():
            col = spec["column"]
            if isinstance(col, int):
                j = col - 1
            else:
                if header is None:
                    raise DataFormatError(f"{p}: channel '{ch}' names column {col!r} but the file has "
                                          f"no header with {n_fields} fields (header: {self.header})")
                names = [_norm(h) for h in header]
                if _norm(col) not in names:
                    raise DataFormatError(f"{p}: channel '{ch}': column {col!r} not in header {header}")
                j = names.index(_norm(col))
            if j >= n_fields:
                raise DataFormatError(f"{p}: channel '{ch}': column {col} but rows have {n_fields} fields")
            index[ch] = j
        raw = np.empty((len(data_lines), n_fields))
        for i, (lineno, s) in enumerate(data_lines):
            fields = self._split(s)
            if len(fields) != n_fields:
                raise DataFormatError(f"{p}:{lineno}: {len(fields)} fields, expected {n_fields}")
            try:
                raw[i] = [float(f) for f in fields]
            except ValueError as exc:
                raise DataFormatError(f"{p}:{lineno}: not a number ({exc})") from None
        cols = {ch: spec["sign"] * (spec["scale"] * raw[:, index[ch]] + spec["offset"])
                for ch, spec in self.channels.items()}
        t = cols["t"]
        keep = np.ones(t.shape[0], dtype=bool)
        last = -np.inf
        for i in range(t.shape[0]):           # drop rows whose time does not increase
            if not t[i] > last:
                keep[i] = False
            else:
                last = t[i]
        dropped = int((~keep).sum())
        cols = {k: v[keep] for k, v in cols.items()}
        meta = dict(self.meta)
        if self.tied_to:
            meta["tied_to"] = dict(self.tied_to)
        meta["import"] = {"description": self.name, "file": p.name, "rows": int(keep.sum()),
                          "dropped_nonincreasing_time": dropped,
                          "units": {ch: spec["unit"] for ch, spec in self.channels.items()}}
        return MeasurementTable(cols, meta, str(p))


def read_with_description(data_path: str | Path, description: str | Path | ImportDescription) -> MeasurementTable:
    """Read ``data_path`` through an import description (path or loaded).

    :raises ConfigError: if the description is invalid.
    :raises DataFormatError: if the data file does not match it.
    """
    desc = description if isinstance(description, ImportDescription) else ImportDescription.load(description)
    return desc.read(data_path)
