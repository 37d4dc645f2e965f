"""Benchmark: ``capstan rig bringup --plant`` on the plant variants, identified values against
the truth, and the workflow's wall time.

The truth is read HERE from each plant file (the workflow never reads it). Prints one
Markdown table (docs/results/bring-up.md)::

    python tests/bench_rig_bringup.py [tests/plants/variant_a.yaml ...]
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

PLANTS = Path(__file__).parent / "plants"
START = Path(__file__).resolve().parents[1] / "config" / "rig_start.yaml"


def truth(plant_path: Path) -> dict[str, float]:
    """The plant file's values the identification should find (defaults as the plant's)."""
    p = yaml.safe_load(plant_path.read_text())
    link = p.get("output", {}).get("link", {})
    inp = p.get("input", {})
    return {"K_c": p.get("transmission", {}).get("stiffness_Nm_rad", 240.0),
            "J_m": inp.get("motor_inertia_kg_m2", 0.73),
            "b_m": inp.get("motor_damping_Nms_rad", 0.5),
            "m_g_l": link.get("m_g_l_Nm", 3.78), "J_l": link.get("inertia_kg_m2", 0.17),
            "mu": p.get("transmission", {}).get("mu", 0.052),
            "T0_N": p.get("pretension", {}).get("T0_N", 150.0)}


def run(plant_path: Path, out_dir: Path) -> dict:
    out = out_dir / f"tuned_{plant_path.stem}.yaml"
    t0 = time.monotonic()
    res = subprocess.run([sys.executable, "-m", "capstan.tools.cli", "rig", "bringup", "--config", str(START),
                          "--out", str(out), "--plant", str(plant_path), "--json"],
                         capture_output=True, text=True, timeout=1800)
    wall = time.monotonic() - t0
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
    rep = json.loads(lines[-1]) if lines else {"ok": False, "reason": res.stderr[-300:]}
    return {"plant": plant_path.name, "code": res.returncode, "wall_s": wall, "report": rep,
            "truth": truth(plant_path), "out": str(out) if out.exists() else None}


def main(argv: list[str]) -> int:
    plants = [Path(a) for a in argv] or sorted(PLANTS.glob("variant_*.yaml")) + [PLANTS / "nominal.yaml"]
    out_dir = Path(tempfile.mkdtemp(prefix="bench-bringup-"))
    load = os.getloadavg()
    print(f"machine: 2-core shared VM, load average at start {load[0]:.1f}; outputs in {out_dir}\n")
    print("| plant | result | wall [s] | K_c id / true | J_m id / true | m g l id / true | J_l id / true |")
    print("|---|---|---|---|---|---|---|")
    for p in plants:
        r = run(p, out_dir)
        rep, tr = r["report"], r["truth"]
        ident = rep.get("identification") or {}

        def cell(key: str) -> str:
            v = ident.get(key, {})
            if not isinstance(v, dict) or "value" not in v:
                return f"– / {tr[key]:.4g}"
            err = 100 * (v["value"] / tr[key] - 1)
            return f"{v['value']:.4g} ± {v.get('stderr', float('nan')):.2g} / {tr[key]:.4g} ({err:+.1f} %)"
        result = "tuned" if rep.get("ok") else f"stopped in {rep.get('step')}: {rep.get('reason', '')[:80]}"
        print(f"| {r['plant']} | {result} | {r['wall_s']:.0f} | {cell('K_c')} | {cell('J_m')} | "
              f"{cell('m_g_l')} | {cell('J_l')} |", flush=True)
        (out_dir / f"report_{p.stem}.json").write_text(json.dumps(r, default=str, indent=1))
    print(f"\nload average at end {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
