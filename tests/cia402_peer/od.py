"""Object dictionary of the peer drive, read from an EDS with configparser (CiA 306).

Independent of canopen's EDS importer and of capstan: each entry holds its CiA 301
data type, access type, PDO mappability and current value (a Python int). Defaults of
the form ``$NODEID+0x180`` are resolved for the drive's node id.
"""

from __future__ import annotations

import configparser
import re
from dataclasses import dataclass

#: CiA 301 basic data types: code -> (size in bytes, signed)
DATA_TYPES: dict[int, tuple[int, bool]] = {
    0x0001: (1, False), 0x0002: (1, True), 0x0003: (2, True), 0x0004: (4, True),
    0x0005: (1, False), 0x0006: (2, False), 0x0007: (4, False),
    0x0010: (3, True), 0x0015: (8, True), 0x0016: (3, False), 0x001B: (8, False),
}


@dataclass
class Entry:
    """One sub-object: type, access, mappability and current value."""

    index: int
    sub: int
    name: str
    size: int
    signed: bool
    access: str
    mappable: bool
    default: int
    value: int

    @property
    def readable(self) -> bool:
        return self.access != "wo"

    @property
    def writable(self) -> bool:
        return self.access in ("rw", "wo", "rww", "rwr")

    def encode(self, value: int | None = None) -> bytes:
        v = self.value if value is None else value
        return int(v).to_bytes(self.size, "little", signed=self.signed)

    def decode(self, data: bytes) -> int:
        return int.from_bytes(data[:self.size], "little", signed=self.signed)

    def in_range(self, value: int) -> bool:
        bits = 8 * self.size
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if self.signed else (0, (1 << bits) - 1)
        return lo <= value <= hi


def _number(text: str, node_id: int) -> int:
    text = text.strip()
    if not text:
        return 0
    text = re.sub(r"\$NODEID", str(node_id), text, flags=re.IGNORECASE)
    total = 0
    for part in text.split("+"):
        part = part.strip()
        total += int(part, 0) if part else 0
    return total


def load_eds(path: str, node_id: int) -> dict[tuple[int, int], Entry]:
    """Every sub-object of basic type in the EDS, keyed by (index, sub-index).

    Objects of type VAR are stored under sub-index 0. Strings and domains are skipped
    (the peer's SDO server is expedited only).
    """
    cp = configparser.ConfigParser(strict=False, interpolation=None)
    cp.optionxform = str  # type: ignore[assignment]
    cp.read(path, encoding="latin-1")
    out: dict[tuple[int, int], Entry] = {}
    for section in cp.sections():
        m = re.fullmatch(r"([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]+))?", section)
        if not m:
            continue
        s = cp[section]
        if int(s.get("ObjectType", "0x7"), 0) != 0x7:
            continue
        dtype = int(s.get("DataType", "0"), 0)
        if dtype not in DATA_TYPES:
            continue
        size, signed = DATA_TYPES[dtype]
        index, sub = int(m.group(1), 16), int(m.group(2) or "0", 16)
        try:
            default = _number(s.get("DefaultValue", ""), node_id)
        except ValueError:
            default = 0
        out[(index, sub)] = Entry(index, sub, s.get("ParameterName", ""), size, signed,
                                  s.get("AccessType", "rw").lower(), s.get("PDOMapping", "0") == "1",
                                  default, default)
    return out
