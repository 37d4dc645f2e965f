"""Small helpers to validate configuration mappings loaded from YAML.

Every failure raises :class:`capstan.models.common.errors.ConfigError` naming the dotted key and the
reason, so a bad config refuses to start with a message a rig engineer can act on.
"""

from __future__ import annotations

import math
import re
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Mapping

import yaml

from capstan.models.common.errors import ConfigError, ConfigFileError

_MISSING = object()


@dataclass(frozen=True)
class KeyUse:
    """One key as a parser read it (see :func:`recording_keys`).

    :ivar path: dotted key, list indices written ``[]`` (``controller.feedforward.effects[].amp_Nm``).
    :ivar kind: ``float``, ``int``, ``choice``, ``bool``, ``section`` or ``key`` (allowed in its
        section but read by a parser of its own, e.g. a routing or a list).
    :ivar default: the default the parser passed (None: required or not stated).
    :ivar min_value: lower bound, or None.
    :ivar max_value: upper bound, or None.
    :ivar min_exclusive: the lower bound itself is refused.
    :ivar choices: the allowed words of a ``choice``.
    """

    path: str
    kind: str
    default: Any = None
    min_value: float | None = None
    max_value: float | None = None
    min_exclusive: bool = False
    choices: tuple[str, ...] = ()


_RECORD: ContextVar[list[KeyUse] | None] = ContextVar("capstan_config_key_record", default=None)
_INDEX = re.compile(r"\[\d+\]")


@contextmanager
def recording_keys() -> Iterator[list[KeyUse]]:
    """Record every key the parsers of this module read while the block runs (the
    configuration reference is generated from these records, ``capstan config reference``)."""
    uses: list[KeyUse] = []
    token = _RECORD.set(uses)
    try:
        yield uses
    finally:
        _RECORD.reset(token)


def _note(prefix: str, key: str, kind: str, default: Any = _MISSING, **bounds: Any) -> None:
    uses = _RECORD.get()
    if uses is None:
        return
    path = _INDEX.sub("[]", f"{prefix}.{key}" if prefix else str(key))
    uses.append(KeyUse(path, kind, None if default is _MISSING else default, **bounds))


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Load a YAML mapping from ``path``.

    :raises ConfigFileError: if the file is missing, unparsable or not a mapping.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ConfigFileError(str(p), f"cannot read file: {exc.strerror or exc}") from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigFileError(str(p), f"invalid YAML: {exc}") from exc
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigFileError(str(p), f"top level must be a mapping, got {type(data).__name__}")
    return data


def section(cfg: Mapping[str, Any], key: str, prefix: str = "", required: bool = True) -> Mapping[str, Any]:
    """Return the sub-mapping ``cfg[key]`` (empty mapping if optional and absent).

    :raises ConfigError: if missing (and required) or not a mapping.
    """
    path = f"{prefix}.{key}" if prefix else key
    _note(prefix, key, "section")
    if key not in cfg:
        if required:
            raise ConfigError(path, "missing section")
        return {}
    val = cfg[key]
    if not isinstance(val, Mapping):
        raise ConfigError(path, f"must be a mapping, got {type(val).__name__}")
    return val


def get_float(cfg: Mapping[str, Any], key: str, prefix: str = "", default: Any = _MISSING,
              min_value: float | None = None, max_value: float | None = None,
              min_exclusive: bool = False) -> float:
    """Return ``cfg[key]`` as a finite float within bounds.

    :raises ConfigError: if missing without default, not a number, not finite or out of range.
    """
    path = f"{prefix}.{key}" if prefix else key
    _note(prefix, key, "float", default, min_value=min_value, max_value=max_value, min_exclusive=min_exclusive)
    if key not in cfg or cfg[key] is None:
        if default is _MISSING:
            raise ConfigError(path, "missing required number")
        return float(default)
    val = cfg[key]
    if isinstance(val, bool) or not isinstance(val, (int, float)):
        raise ConfigError(path, f"must be a number, got {val!r}")
    x = float(val)
    if not math.isfinite(x):
        raise ConfigError(path, f"must be finite, got {val!r}")
    if min_value is not None:
        if min_exclusive and not x > min_value:
            raise ConfigError(path, f"must be > {min_value}, got {x}")
        if not min_exclusive and x < min_value:
            raise ConfigError(path, f"must be >= {min_value}, got {x}")
    if max_value is not None and x > max_value:
        raise ConfigError(path, f"must be <= {max_value}, got {x}")
    return x


def get_int(cfg: Mapping[str, Any], key: str, prefix: str = "", default: Any = _MISSING,
            min_value: int | None = None, max_value: int | None = None) -> int:
    """Return ``cfg[key]`` as an int within bounds.

    :raises ConfigError: if missing without default, not an integer or out of range.
    """
    path = f"{prefix}.{key}" if prefix else key
    _note(prefix, key, "int", default, min_value=min_value, max_value=max_value)
    if key not in cfg or cfg[key] is None:
        if default is _MISSING:
            raise ConfigError(path, "missing required integer")
        return int(default)
    val = cfg[key]
    if isinstance(val, bool) or not isinstance(val, int):
        raise ConfigError(path, f"must be an integer, got {val!r}")
    if min_value is not None and val < min_value:
        raise ConfigError(path, f"must be >= {min_value}, got {val}")
    if max_value is not None and val > max_value:
        raise ConfigError(path, f"must be <= {max_value}, got {val}")
    return int(val)


def get_choice(cfg: Mapping[str, Any], key: str, choices: tuple[str, ...], prefix: str = "",
               default: Any = _MISSING) -> str:
    """Return ``cfg[key]`` which must be one of ``choices``.

    :raises ConfigError: if missing without default or not one of the choices.
    """
    path = f"{prefix}.{key}" if prefix else key
    _note(prefix, key, "choice", default, choices=tuple(choices))
    if key not in cfg or cfg[key] is None:
        if default is _MISSING:
            raise ConfigError(path, f"missing; one of {', '.join(choices)}")
        return str(default)
    val = cfg[key]
    if val not in choices:
        raise ConfigError(path, f"must be one of {', '.join(choices)}, got {val!r}")
    return str(val)


def get_bool(cfg: Mapping[str, Any], key: str, prefix: str = "", default: Any = _MISSING) -> bool:
    """Return ``cfg[key]`` as a bool.

    :raises ConfigError: if missing without default or not a boolean.
    """
    path = f"{prefix}.{key}" if prefix else key
    _note(prefix, key, "bool", default)
    if key not in cfg or cfg[key] is None:
        if default is _MISSING:
            raise ConfigError(path, "missing required boolean")
        return bool(default)
    val = cfg[key]
    if not isinstance(val, bool):
        raise ConfigError(path, f"must be true or false, got {val!r}")
    return val


def reject_unknown(cfg: Mapping[str, Any], allowed: set[str] | frozenset[str], prefix: str = "") -> None:
    """Refuse keys not in ``allowed`` (catches typos such as ``cutof_hz``).

    :raises ConfigError: naming the first unknown key.
    """
    for key in sorted(allowed):
        _note(prefix, key, "key")
    for key in cfg:
        if key not in allowed:
            path = f"{prefix}.{key}" if prefix else str(key)
            raise ConfigError(path, f"unknown key; expected one of {', '.join(sorted(allowed))}")
