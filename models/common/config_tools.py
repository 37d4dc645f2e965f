"""Small helpers to validate configuration mappings loaded from YAML.

Every failure raises :class:`capstan.models.common.errors.ConfigError` naming the dotted key and the
reason, so a bad config refuses to start with a message a rig engineer can act on.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

import yaml

from capstan.models.common.errors import ConfigError

_MISSING = object()


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Load a YAML mapping from ``path``.

    :raises ConfigError: if the file is missing, unparsable or not a mapping.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ConfigError(str(p), f"cannot read file: {exc.strerror or exc}") from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(str(p), f"invalid YAML: {exc}") from exc
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(str(p), f"top level must be a mapping, got {type(data).__name__}")
    return data


def section(cfg: Mapping[str, Any], key: str, prefix: str = "", required: bool = True) -> Mapping[str, Any]:
    """Return the sub-mapping ``cfg[key]`` (empty mapping if optional and absent).

    :raises ConfigError: if missing (and required) or not a mapping.
    """
    path = f"{prefix}.{key}" if prefix else key
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
    for key in cfg:
        if key not in allowed:
            path = f"{prefix}.{key}" if prefix else str(key)
            raise ConfigError(path, f"unknown key; expected one of {', '.join(sorted(allowed))}")
