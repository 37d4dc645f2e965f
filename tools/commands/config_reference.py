"""The configuration reference (``docs/configuration.md``), generated from the parsers themselves.

Every key of a daemon config is read by one of the validating helpers of
:mod:`capstan.models.common.config_tools` (``get_float``, ``get_int``, ``get_choice``,
``get_bool``, ``section``, ``reject_unknown``). Under :func:`recording_keys` those helpers note
each key with its type, default and bounds; this module runs the real parsers over the
shipped configs (and the optional sections none of them carries), so the reference lists what
the code accepts, with the code's defaults. The one line of meaning per key is the only thing
written by hand (:data:`capstan.tools.offline.config_meanings.MEANINGS`);
``tests/test_config_reference.py`` fails when a key has none, when a meaning names a key the
code no longer reads, and when the committed ``docs/configuration.md`` differs from
``capstan config reference``.
"""

from __future__ import annotations

import copy
import math
from typing import Any, Mapping

from capstan.models.common.config_tools import KeyUse, load_yaml, recording_keys
from capstan.tools.offline.config_meanings import MEANINGS, SECTIONS_INTRO, UNITS
from capstan.tools.offline.shipped import config_path

#: the shipped daemon configs whose parse the reference is built from
SHIPPED = ("rig.yaml", "hil.yaml", "hil_effect.yaml")

#: optional sections none of the shipped daemon configs carries (parsed on top of hil.yaml)
_OPTIONAL: dict[str, Any] = {
    "lab_override": {"reason": "reference", "ranges": False, "margins": False},
    "hil": {"hand": {}},
}

#: unit of a key, from the end of its name (longest first); keys without one are unitless
_UNITS: tuple[tuple[str, str], ...] = (
    ("_N_per_mV_V", "N/(mV/V)"), ("_Nms_rad", "N m s/rad"), ("_Nm_rad", "N m/rad"),
    ("_Nm_s", "N m/s"), ("_kg_m2", "kg m²"), ("_rad_s", "rad/s"), ("_1_per_m", "1/m"),
    ("_Ns_m", "N s/m"), ("_1_s", "1/s"), ("_mV_V", "mV/V"), ("_cycles", "cycles"),
    ("_hz", "Hz"), ("_Nm", "N m"), ("_rad", "rad"), ("_deg", "°"), ("_dB", "dB"), ("_GB", "GB"),
    ("_MB", "MB"), ("_ms", "ms"), ("_us", "µs"), ("_m", "m"), ("_N", "N"), ("_s", "s"),
    ("baudrate", "Bd"),
)

_SPECIFIC = ("float", "int", "choice", "bool")


def _merge(uses: list[KeyUse]) -> dict[str, KeyUse]:
    """One record per key: a typed read wins over a mere "allowed here"; the first default seen
    (the shipped configs are parsed in :data:`SHIPPED` order) is kept."""
    keys: dict[str, KeyUse] = {}
    for u in uses:
        old = keys.get(u.path)
        if old is None or (old.kind not in _SPECIFIC and u.kind in _SPECIFIC) or (
                old.kind == "key" and u.kind == "section"):
            keys[u.path] = u
    return keys


def _parse_all(raw: Mapping[str, Any]) -> None:
    """Run every parser of a daemon config over ``raw`` (the recorder notes the keys)."""
    from capstan.controller.law.config import ControllerConfig
    from capstan.controller.runtime.config import DaemonConfig
    from capstan.drivers.canopen.config import MotorConfig
    from capstan.drivers.serial.loadcell import LoadCellConfig
    from capstan.drivers.serial.xsens_config import XsensConfig
    from capstan.models.plant.rig import SimulatedRig
    from capstan.tools.hil.plant import HilSettings

    DaemonConfig.from_mapping(raw)
    ControllerConfig.from_mapping(raw.get("controller", {}))

    def options(role: str) -> dict[str, Any]:
        return {k: v for k, v in raw[role].items() if k != "backend"}

    MotorConfig.from_mapping(options("motor"), "motor")
    XsensConfig.from_mapping(options("imu"), "imu")
    LoadCellConfig.from_mapping(options("load_cells"), "load_cells")
    if "hil" in raw:
        HilSettings.from_mapping(raw["hil"], "hil")
        SimulatedRig.from_mapping(raw["hil"]["plant"], "hil.plant")


def collect_keys() -> dict[str, KeyUse]:
    """Every key the daemon's parsers read, by dotted path.

    :raises ConfigError: if a shipped config does not parse.
    """
    with recording_keys() as uses:
        for name in SHIPPED:
            _parse_all(load_yaml(config_path(name)))
        extra = copy.deepcopy(load_yaml(config_path("hil.yaml")))
        for sec, body in _OPTIONAL.items():
            extra[sec] = {**extra.get(sec, {}), **body}
        _parse_all(extra)
    return _merge(uses)


def unit_of(path: str) -> str:
    """The unit a key's name states (``""`` if none; :data:`UNITS` where the name misleads)."""
    if path in UNITS:
        return UNITS[path]
    name = path.rsplit(".", 1)[-1]
    for suffix, unit in _UNITS:
        if name.endswith(suffix):
            return unit
    return ""


def _num(x: Any) -> str:
    if isinstance(x, float):
        if math.isinf(x):
            return "∞"
        return f"{x:g}"
    return str(x)


def _range(u: KeyUse) -> str:
    if u.kind == "choice":
        return " \\| ".join(u.choices)
    if u.kind == "bool":
        return "true \\| false"
    if u.min_value is None and u.max_value is None:
        return ""
    lo = "" if u.min_value is None else ("> " if u.min_exclusive else "≥ ") + _num(u.min_value)
    hi = "" if u.max_value is None else "≤ " + _num(u.max_value)
    return ", ".join(s for s in (lo, hi) if s)


def _default(u: KeyUse) -> str:
    if u.kind in ("section", "key"):
        return ""
    if u.default is None:
        return "required"
    if isinstance(u.default, bool):
        return "true" if u.default else "false"
    return _num(u.default)


def missing_meanings(keys: Mapping[str, KeyUse]) -> list[str]:
    """Keys the code reads that have no line of meaning."""
    return sorted(k for k in keys if not MEANINGS.get(k, "").strip())


def stale_meanings(keys: Mapping[str, KeyUse]) -> list[str]:
    """Meanings of keys the code no longer reads."""
    return sorted(k for k in MEANINGS if k not in keys)


def render(keys: Mapping[str, KeyUse]) -> str:
    """The Markdown reference: one table per top-level section."""
    out = ["# Configuration reference", "",
           "Generated by `capstan config reference > docs/configuration.md` from the parsers "
           "themselves (`capstan.tools.commands.config_reference`); do not edit by hand. "
           "`tests/test_config_reference.py` fails when this file is out of date or a key has no "
           "meaning.", "",
           "A daemon config (`capstan run --config FILE`, `capstan hil --config FILE`) is YAML. "
           "Units are SI and stated in the key names; an absent key takes the default below; an "
           "unknown key, a wrong type or a value outside its range is refused at start-up, naming "
           "the key. A range that depends on another key (a cutoff below the Nyquist frequency of "
           "`controller.dt_s`) is shown for the shipped value of that key. Safety-relevant keys "
           "must also lie in the plausible ranges of `controller/runtime/plausibility.py` and the "
           "gains must meet the torque loop's margins (`capstan experiment loop`), unless a "
           "`lab_override` section says why.", ""]
    by_top: dict[str, list[str]] = {}
    for path in keys:
        by_top.setdefault(path.split(".", 1)[0], []).append(path)
    for top in sorted(by_top, key=lambda t: (list(SECTIONS_INTRO).index(t) if t in SECTIONS_INTRO else 99, t)):
        out += [f"## `{top}`", ""]
        if top in SECTIONS_INTRO:
            out += [SECTIONS_INTRO[top], ""]
        out += ["| key | type | unit | range | default | meaning |", "|---|---|---|---|---|---|"]
        for path in sorted(by_top[top]):
            if path == top:
                continue
            u = keys[path]
            meaning = MEANINGS.get(path, "").replace("|", "\\|")
            out.append(f"| `{path}` | {u.kind} | {unit_of(path)} | {_range(u)} | {_default(u)} | {meaning} |")
        out.append("")
    return "\n".join(out)


def _yaml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_yaml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{k}: {_yaml_value(x)}" for k, x in v.items()) + "}"
    return str(v)


def _example_lines(m: Mapping[str, Any], path: str, indent: int) -> list[str]:
    lines = []
    for key, v in m.items():
        p = f"{path}.{key}"
        note = MEANINGS.get(p, "")
        unit = unit_of(p)
        note = f"{note} [{unit}]" if unit and note else note
        pad = " " * indent
        if isinstance(v, Mapping) and key != "effects_shape":
            lines.append(f"{pad}{key}:" + (f"  # {note}" if note else ""))
            lines += _example_lines(v, p, indent + 2)
        else:
            text = f"{pad}{key}: {_yaml_value(v)}"
            lines.append(f"{text:<40} # {note}" if note else text)
    return lines


def controller_example() -> str:
    """``config/controller.yaml``: the ``controller`` section with every key at the code's default
    and its meaning as a comment, generated like the reference (``capstan config reference
    --controller-example``), so the example cannot drift from the defaults."""
    from capstan.controller.law.config import ControllerConfig
    m = ControllerConfig().to_mapping()
    routing = m["feedforward"]["routing"]
    kappa = {k for _, k in routing["curvature_profile"]}
    if len(kappa) == 1:                  # a uniform bend: the form a user writes
        m["feedforward"]["routing"] = {"length_m": routing["length_m"],
                                       "theta_rad": round(kappa.pop() * routing["length_m"], 12)}
    head = ["# The controller section of a capstan configuration, every key at its default.",
            "# Generated by `capstan config reference --controller-example > config/controller.yaml`",
            "# from the code's defaults (do not edit by hand; docs/configuration.md has the ranges).",
            "# A config states only the keys it changes; absent keys take these values."]
    return "\n".join(head + ["controller:"] + _example_lines(m, "controller", 2)) + "\n"


def reference() -> str:
    """The whole reference as ``docs/configuration.md`` holds it.

    :raises ConfigError: if a shipped config does not parse.
    """
    return render(collect_keys())
