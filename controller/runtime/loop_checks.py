"""The daemon loop's small per-cycle and per-window checks: sensor freshness, the rig's
limits, the safety stage's rate step, CPU accounting and the log writer's supervision."""

from __future__ import annotations

from typing import Any

from capstan.controller.runtime.config import DaemonConfig
from capstan.controller.runtime.timing import process_cpu_s


def writer_is_lost(sink: Any) -> bool:
    """Supervise the log writer (restarts it by policy); True if it is lost for good."""
    supervise = getattr(sink, "supervise", None)
    return callable(supervise) and int(supervise()) == 2      # WriterHealth.LOST


def rate_step_Nm(cfg: DaemonConfig, period_s: float) -> float:
    """The safety stage's rate clamp per cycle [Nm] (0 if the controller section is unreadable)."""
    c = cfg.controller.get("safety", {}) if hasattr(cfg.controller, "get") else {}
    try:
        return float(c.get("dtau_max_Nm_s", 2000.0)) * period_s if hasattr(c, "get") else 0.0
    except (TypeError, ValueError):
        return 0.0


def cpu_snapshot(sink: Any) -> dict[str, float]:
    """CPU seconds used so far by this process and by the log writer process (if any)."""
    out = {"daemon": process_cpu_s()}
    proc = getattr(sink, "proc", None)
    if proc is not None and proc.poll() is None:
        try:
            out["log_writer"] = process_cpu_s(proc.pid)
        except OSError:
            pass
    return out


def all_fresh(t_s: float, fresh_s: float, *stamps: float) -> bool:
    """True if every time stamp is at most ``fresh_s`` old at ``t_s``."""
    for st in stamps:
        if not t_s - st <= fresh_s:
            return False
    return True


def limit_violation(r: Any, lim: Any) -> str:
    """Readable description of the first violated limit, or "" (NaN never passes)."""
    q = r["q_out_rad"]
    if not lim.q_out_min_rad <= q <= lim.q_out_max_rad:
        return f"q_out_rad {q:.4g} outside [{lim.q_out_min_rad}, {lim.q_out_max_rad}]"
    if not abs(r["dq_out_rad_s"]) <= lim.dq_out_max_rad_s:
        return f"|dq_out_rad_s| {r['dq_out_rad_s']:.4g} > {lim.dq_out_max_rad_s}"
    if not abs(r["dq_m_rad_s"]) <= lim.dq_m_max_rad_s:
        return f"|dq_m_rad_s| {r['dq_m_rad_s']:.4g} > {lim.dq_m_max_rad_s}"
    for name in ("T_up_in_N", "T_up_out_N", "T_lo_out_N", "T_lo_in_N"):
        T = r[name]
        if not lim.tension_min_N <= T <= lim.tension_max_N:
            return f"{name} {T:.4g} outside [{lim.tension_min_N}, {lim.tension_max_N}]"
    return ""
