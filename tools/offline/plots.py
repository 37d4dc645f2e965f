"""Hysteresis plots of a measurement table (PNG via matplotlib's Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from capstan.models.common.measurement_table import MeasurementTable  # noqa: E402


def hysteresis_plots(table: MeasurementTable, out_stem: str | Path, title: str = "") -> list[Path]:
    """Write tau_in-tau_out and tau_in-deflection loops (and a time series) as PNG.

    Returns the written paths: ``STEM_torque.png``, ``STEM_deflection.png``, ``STEM_time.png``.
    Loops need the columns they plot; a missing column skips that figure.
    """
    stem = Path(out_stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    t = table.t
    if table.has("tau_in") and table.has("tau_out"):
        fig, ax = plt.subplots(figsize=(5.5, 4.5))
        ax.plot(table["tau_in"], table["tau_out"], lw=0.6)
        lim = float(np.max(np.abs(table["tau_in"])))
        ax.plot([-lim, lim], [-lim, lim], "k--", lw=0.6, label="ideal (no loss)")
        ax.set_xlabel("tau_in [Nm]")
        ax.set_ylabel("tau_out [Nm]")
        ax.set_title(f"{title} torque transmission".strip())
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left")
        path = stem.with_name(stem.name + "_torque.png")
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    if table.has("tau_in") and table.has("q_in") and table.has("q_out"):
        fig, ax = plt.subplots(figsize=(5.5, 4.5))
        defl = table["q_in"] - table["q_out"]
        ax.plot(defl * 1e3, table["tau_in"], lw=0.6)
        ax.set_xlabel("deflection q_in - q_out [mrad]")
        ax.set_ylabel("tau_in [Nm]")
        ax.set_title(f"{title} torque vs deflection".strip())
        ax.grid(True, alpha=0.3)
        path = stem.with_name(stem.name + "_deflection.png")
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for name in ("tau_in", "tau_out"):
        if table.has(name):
            ax.plot(t, table[name], lw=0.6, label=name)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("torque [Nm]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right")
    path = stem.with_name(stem.name + "_time.png")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    written.append(path)
    return written
