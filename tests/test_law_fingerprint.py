"""The control law's fingerprint (``law_sha256`` in every daemon log): it covers every module
the step's code comes from, and it changes with any byte of them."""

from __future__ import annotations

import ast
import importlib.util

from capstan.controller.law.fingerprint import MODEL_MODULES, fingerprint_of, law_fingerprint, law_modules


def _imports_of(name: str) -> set[str]:
    spec = importlib.util.find_spec(name)
    assert spec is not None and spec.origin is not None, name
    tree = ast.parse(open(spec.origin, encoding="utf-8").read())
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("capstan."):
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("capstan."))
    return out


def test_every_module_the_law_imports_is_covered() -> None:
    """Walk the law's imports transitively: every capstan module they reach is fingerprinted
    (a model module the step calls that is left out would let the law change unseen)."""
    covered = set(law_modules())
    seen: set[str] = set()
    todo = list(covered)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        todo.extend(_imports_of(name))
    packages = {n for n in seen if importlib.util.find_spec(n).submodule_search_locations is not None}
    assert seen - packages <= covered, sorted(seen - packages - covered)
    assert set(MODEL_MODULES) <= seen                    # no stale entry either
    assert "capstan.controller.law.step" in covered and "capstan.controller.law.fingerprint" in covered


def test_the_digest_changes_with_any_byte_and_not_with_order_or_line_endings() -> None:
    a = [("m.a", b"x = 1\ny = 2\n"), ("m.b", b"z = 3\n")]
    d = fingerprint_of(a)
    assert len(d) == 64 and int(d, 16) >= 0
    assert fingerprint_of(list(reversed(a))) == d
    assert fingerprint_of([("m.a", b"x = 1\r\ny = 2\r\n"), ("m.b", b"z = 3\r\n")]) == d
    assert fingerprint_of([("m.a", b"x = 1\ny = 3\n"), ("m.b", b"z = 3\n")]) != d
    assert fingerprint_of([("m.c", b"x = 1\ny = 2\n"), ("m.b", b"z = 3\n")]) != d   # a module renamed
    assert fingerprint_of(a[:1]) != d                                                  # a module removed


def test_the_installed_law_has_a_stable_fingerprint() -> None:
    d = law_fingerprint()
    assert len(d) == 64
    sources = []
    for name in law_modules():
        spec = importlib.util.find_spec(name)
        sources.append((name, open(spec.origin, "rb").read()))
    assert fingerprint_of(sources) == d
