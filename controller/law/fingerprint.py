"""Fingerprint of the control law's code: which step a log was written by.

A replay is bit-exact only against the code that wrote the log. Every daemon log records
:func:`law_fingerprint` (``capstan.log`` metadata ``law_sha256``), so a replay that differs
can say whether the law changed since the log was written (an expected difference) or not
(the log or the replay is wrong), instead of leaving a rig engineer to guess.

The fingerprint covers every module of :mod:`capstan.controller.law` and the model modules
the step and its configuration call (:data:`MODEL_MODULES`): each module's name and the
SHA-256 of its source with line endings normalised.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import pkgutil
from pathlib import Path
from typing import Iterable

#: the model modules the law imports (``from capstan.models... import`` in controller/law)
MODEL_MODULES: tuple[str, ...] = (
    "capstan.models.closure.effects_runtime",
    "capstan.models.common.config_tools",
    "capstan.models.common.errors",
    "capstan.models.transmission.link",
    "capstan.models.transmission.pretension",
    "capstan.models.transmission.reduced",
    "capstan.models.transmission.routing",
)

#: the law's subpackage the fingerprint leaves out (an offline tool that the step never calls)
TUNING = "capstan.controller.law.tuning"

#: what :func:`law_fingerprint` returns when a source is not readable (e.g. a bytecode-only install)
UNAVAILABLE = "unavailable"


def law_modules() -> list[str]:
    """The dotted names the fingerprint covers, sorted."""
    import capstan.controller.law as law

    names = {"capstan.controller.law", *MODEL_MODULES}
    for m in pkgutil.walk_packages(law.__path__, "capstan.controller.law."):
        # the gain tuner (law/tuning/) is an offline tool on the loop analysis, not part of the law
        if m.name != TUNING and not m.name.startswith(TUNING + "."):
            names.add(m.name)
    return sorted(names)


def fingerprint_of(sources: Iterable[tuple[str, bytes]]) -> str:
    """SHA-256 hex digest over ``(module name, source bytes)`` pairs (order-independent;
    CRLF counts as LF, so a Windows checkout gives the same digest)."""
    h = hashlib.sha256()
    for name, data in sorted(sources):
        h.update(name.encode())
        h.update(b"\0")
        h.update(hashlib.sha256(data.replace(b"\r\n", b"\n")).digest())
    return h.hexdigest()


@functools.cache
def law_fingerprint() -> str:
    """The fingerprint of the installed law's sources (hex), or :data:`UNAVAILABLE`."""
    pairs = []
    for name in law_modules():
        spec = importlib.util.find_spec(name)
        origin = spec.origin if spec is not None else None
        if origin is None or not origin.endswith(".py"):
            return UNAVAILABLE
        try:
            pairs.append((name, Path(origin).read_bytes()))
        except OSError:
            return UNAVAILABLE
    return fingerprint_of(pairs)
