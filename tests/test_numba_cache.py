"""The Numba cache is keyed by the sources: an edit in a *called* module takes effect.

Plain Numba caching checks a cached function against its own file only, so a compiled
caller keeps the old code of a callee edited in another module (numba issue #1833).
The test builds a two-module package, runs it in fresh processes before and after
editing the callee, with and without :func:`capstan.models.common.numba_cache.configure_cache`.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from capstan.models.common import numba_cache


_CALLER = """
from numba import njit
from libpkg.inner import value

@njit(cache=True)
def outer():
    return value() + 0.0
"""


def _callee(v: float) -> str:
    return f"from numba import njit\n\n@njit(cache=True)\ndef value():\n    return {v!r}\n"


def _run(tmp: Path, configured: bool) -> float:
    """A fresh interpreter: optionally key the cache by libpkg's sources, call outer()."""
    if configured:
        pre = (f"from capstan.models.common.numba_cache import configure_cache\n"
               f"configure_cache(roots=[{str(tmp / 'pkg' / 'libpkg')!r}], "
               f"base={str(tmp / 'keyed')!r})\n")
    else:
        pre = ""
    code = pre + "from libpkg.outer import outer\nprint(outer())\n"
    env = dict(os.environ, PYTHONPATH=str(tmp / "pkg"),
               NUMBA_CACHE_DIR=str(tmp / "plain"))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=120, check=True)
    return float(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_an_edit_in_a_called_module_takes_effect_only_with_the_keyed_cache(tmp_path: Path) -> None:
    pkg = tmp_path / "pkg" / "libpkg"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "outer.py").write_text(textwrap.dedent(_CALLER))
    (pkg / "inner.py").write_text(_callee(1.0))
    assert _run(tmp_path, configured=True) == 1.0
    assert _run(tmp_path, configured=False) == 1.0
    (pkg / "inner.py").write_text(_callee(2.0))
    assert _run(tmp_path, configured=True) == 2.0
    # plain Numba: the cached caller still holds the old callee (the hazard guarded against)
    assert _run(tmp_path, configured=False) == 1.0
    keyed = sorted(p.name for p in (tmp_path / "keyed").iterdir())
    assert len(keyed) == 2 and all(name.startswith(numba_cache.PREFIX) for name in keyed)


def test_fingerprint_follows_content_and_old_directories_are_pruned(tmp_path: Path) -> None:
    root = tmp_path / "pkg"
    root.mkdir()
    (root / "a.py").write_text("x = 1\n")
    fp1 = numba_cache.source_fingerprint([root])
    assert numba_cache.source_fingerprint([root]) == fp1
    (root / "a.py").write_text("x = 2\n")
    fp2 = numba_cache.source_fingerprint([root])
    assert fp2 != fp1
    base = tmp_path / "cache"
    for i in range(numba_cache.KEEP_OTHERS + 2):       # unused for decades
        d = base / f"{numba_cache.PREFIX}old{i}"
        d.mkdir(parents=True)
        os.utime(d, (1000.0 + i, 1000.0 + i))
    busy = [base / f"{numba_cache.PREFIX}busy{i}" for i in range(numba_cache.KEEP_OTHERS + 1)]
    for d in busy:                                       # used today: one more than KEEP_OTHERS
        d.mkdir()
    saved = numba_cache._configured
    try:
        path = numba_cache.configure_cache(roots=[root], base=base)
    finally:
        numba_cache._configured = saved
        numba_cache.numba_config.CACHE_DIR = str(saved) if saved else ""
    assert path == base / (numba_cache.PREFIX + fp2)
    left = sorted(p.name for p in base.iterdir())
    # the current directory and every directory used within a day stay; beyond the
    # KEEP_OTHERS most recent, the long-unused ones go
    assert left == sorted([path.name] + [d.name for d in busy])
