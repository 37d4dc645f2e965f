"""The configuration files shipped with capstan: the repository's ``config/`` folder,
installed as the data package ``capstan.config`` (so a plain ``pip install`` has them).

``capstan hil`` runs the shipped ``hil.yaml`` when no ``--config`` is given;
``capstan config show NAME`` prints a shipped file to start a rig's own from.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from capstan.models.common.errors import ConfigError, ConfigFileError

PACKAGE = "capstan.config"


def config_dir() -> Path:
    """Directory of the shipped configuration files.

    :raises ConfigError: if the installation carries no ``capstan.config`` data.
    """
    # a data-only namespace package: its search locations are the folder (plain install)
    # or the repository's config/ (editable install, next to the editable finder's hook)
    spec = importlib.util.find_spec(PACKAGE)
    for loc in (spec.submodule_search_locations or []) if spec is not None else []:
        path = Path(loc)
        if (path / "hil.yaml").is_file():
            return path
    raise ConfigError(PACKAGE, "the shipped configuration files are not installed")


def shipped_names() -> list[str]:
    """Names (relative paths) of every shipped configuration file."""
    root = config_dir()
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*")
                  if p.is_file() and p.suffix in (".yaml", ".service", ".json"))


def config_path(name: str) -> Path:
    """Path of the shipped file ``name`` (e.g. ``"hil.yaml"``, ``"scenarios/testbed_multisine.yaml"``).

    :raises ConfigFileError: if no such file is shipped (the message lists those that are).
    """
    path = config_dir() / name
    if not path.is_file():
        raise ConfigFileError(name, f"not a shipped file; shipped: {', '.join(shipped_names())}")
    return path
