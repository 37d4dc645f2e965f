"""Numba's on-disk cache, kept in a directory keyed by the package sources.

Numba checks a cached function against its *own* source file only: when a function it
calls (and inlines) lives in another module, an edit there is not noticed and the old
machine code keeps running (numba issue #1833; documented under "Cache Notes" in
Numba's JIT docs). Module-level constants read inside compiled code (fault bits, record
dtypes) are frozen the same way. For a controller that drives a motor, an upgrade of
``controller/law/safety.py`` that leaves ``controller/law/step.py`` untouched must not leave the
old safety stage compiled into the step.

:func:`configure_cache` therefore points Numba at ``BASE/src-<fingerprint>``, where the
fingerprint hashes every ``.py`` file of the ``capstan.controller``, ``capstan.drivers``,
``capstan.models`` and ``capstan.tools`` packages (wherever they are installed: the
repository folders in an editable install, site-packages otherwise) and the Numba version: any change of the sources starts a fresh
cache, and an unchanged tree reuses its own. ``BASE`` is ``$NUMBA_CACHE_DIR`` when set
(the systemd unit and CI set it), else ``$XDG_CACHE_HOME/capstan/numba`` (default
``~/.cache/capstan/numba``). The newest few fingerprint directories are kept, older ones
removed once unused for a day. Each package's ``__init__`` calls :func:`configure_cache`
before any of its compiled modules is imported; Numba fixes a function's cache path when
the function is decorated.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import shutil
import time
from collections.abc import Iterable
from pathlib import Path

import numba
from numba.core import config as numba_config

logger = logging.getLogger(__name__)

PACKAGES = ("capstan.controller", "capstan.drivers", "capstan.models", "capstan.tools")
PREFIX = "src-"
#: fingerprint directories kept besides the current one (other checkouts, older versions)
KEEP_OTHERS = 3
#: a directory used this recently is never removed (another process may be compiling into it)
MIN_AGE_S = 86400.0

_configured: Path | None = None


def package_roots() -> list[Path]:
    """The four package directories of this installation (found through the import
    system, so an editable install yields the repository folders)."""
    roots = []
    for name in PACKAGES:
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.submodule_search_locations:
            roots.append(Path(list(spec.submodule_search_locations)[0]).resolve())
    return roots


def source_fingerprint(roots: Iterable[Path]) -> str:
    """Hex digest over the Numba version and every ``.py`` file under ``roots`` (path
    relative to its package's parent, and content).

    :raises OSError: if a source file cannot be read.
    """
    h = hashlib.sha256(numba.__version__.encode())
    for root in sorted(Path(r) for r in roots):
        for path in sorted(root.rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            h.update(path.relative_to(root.parent).as_posix().encode() + b"\0")
            h.update(path.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def default_base() -> Path:
    """``$NUMBA_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/capstan/numba``."""
    env = os.environ.get("NUMBA_CACHE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(xdg) / "capstan" / "numba"


def _prune(base: Path, current: Path) -> None:
    """Remove fingerprint directories beyond the ``KEEP_OTHERS`` most recently used that
    have not been used for ``MIN_AGE_S``."""
    now = time.time()
    others = []
    for d in base.glob(PREFIX + "*"):
        if d.is_dir() and d != current:
            try:
                others.append((d.stat().st_mtime, d))
            except OSError:
                continue
    others.sort(reverse=True)
    for mtime, d in others[KEEP_OTHERS:]:
        if now - mtime >= MIN_AGE_S:
            shutil.rmtree(d, ignore_errors=True)


def configure_cache(roots: Iterable[Path] | None = None, base: Path | None = None) -> Path | None:
    """Point Numba's cache at ``base/src-<fingerprint of roots>``.

    Without arguments (the package ``__init__`` calls) this runs once per process; with
    ``roots`` or ``base`` it always reconfigures (functions decorated afterwards use it).

    :param roots: package directories to fingerprint (default: this installation's).
    :param base: parent of the fingerprint directories (default :func:`default_base`).
    :returns: the cache directory, or None when it cannot be created or the sources
        cannot be read (then Numba's own locations apply, with a warning in the log).
    """
    global _configured
    if _configured is not None and roots is None and base is None:
        return _configured
    base = default_base() if base is None else Path(base)
    try:
        path = base / (PREFIX + source_fingerprint(package_roots() if roots is None else roots))
        path.mkdir(parents=True, exist_ok=True)
        os.utime(path)
    except OSError as exc:
        logger.warning("Numba cache not keyed by the sources (%s): an edit in a called "
                       "module may leave stale compiled code; clear the cache after upgrades",
                       exc)
        return None
    numba_config.CACHE_DIR = str(path)
    _prune(base, path)
    _configured = path
    return path
