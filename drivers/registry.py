"""Config-keyed device backends: role -> backend name -> (module, class), imported lazily.

A config section such as ``motor: {backend: canopen, channel: ..., ...}`` selects the
class; the remaining keys go either to the class's ``from_config(options, prefix)`` or,
where the table names a config class, to ``ConfigClass.from_mapping(options, prefix)``
whose result is passed to the class. Importing
this module imports no driver (as python-can's interface table), so a rig without
``canopen`` installed can still run tools that do not touch the drive.

Adding a backend: one line in :data:`BACKENDS`; the class implements the role's
interface of :mod:`capstan.drivers.interfaces` and validation raises
:class:`capstan.models.common.errors.ConfigError` on bad options.
"""

from __future__ import annotations

import importlib
from typing import Any, Mapping

from capstan.models.common.errors import ConfigError

#: role -> backend name -> (module, class, config class "module:Class" or "" for from_config)
BACKENDS: dict[str, dict[str, tuple[str, str, str]]] = {
    "motor": {
        "canopen": ("capstan.drivers.canopen.motor", "CanopenMotor", "capstan.drivers.canopen.config:MotorConfig"),
    },
    "imu": {
        "xsens": ("capstan.drivers.serial.xsens", "XsensImu", ""),
    },
    "load_cells": {
        "serial": ("capstan.drivers.serial.loadcell", "SerialLoadCells", ""),
    },
}


def backend_class(role: str, name: str, prefix: str | None = None) -> type:
    """The class implementing ``name`` for ``role`` (imported now).

    :raises ConfigError: for an unknown role/backend, or if the module cannot be imported.
    """
    key = f"{prefix or role}.backend"
    table = BACKENDS.get(role)
    if table is None:
        raise ConfigError(key, f"unknown device role {role!r}; one of {', '.join(BACKENDS)}")
    if name not in table:
        raise ConfigError(key, f"unknown backend {name!r}; one of {', '.join(sorted(table))}")
    module_name, class_name, _ = table[name]
    return _import(module_name, class_name, key, name)


def _import(module_name: str, attr: str, key: str, name: str) -> type:
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(key, f"backend {name!r} unavailable: cannot import {module_name}: {exc}") from exc
    try:
        return getattr(module, attr)
    except AttributeError:
        raise ConfigError(key, f"backend {name!r}: {module_name} has no {attr}") from None


def create(role: str, cfg: Mapping[str, Any], prefix: str | None = None) -> Any:
    """Instantiate the backend selected by ``cfg["backend"]`` with the other keys.

    :raises ConfigError: on an unknown backend or invalid options (from the backend).
    """
    prefix = prefix or role
    name = cfg.get("backend")
    if not isinstance(name, str):
        raise ConfigError(f"{prefix}.backend", f"missing or not a name, got {name!r}")
    cls = backend_class(role, name, prefix)
    options = {k: v for k, v in cfg.items() if k != "backend"}
    config_ref = BACKENDS[role][name][2]
    if config_ref:
        mod, _, attr = config_ref.partition(":")
        return cls(_import(mod, attr, f"{prefix}.backend", name).from_mapping(options, prefix))
    factory = getattr(cls, "from_config", None)
    if factory is None:
        raise ConfigError(f"{prefix}.backend", f"backend {name!r} ({cls.__name__}) has no from_config")
    return factory(options, prefix)
