"""A picture of a force trace: the force's components and magnitude against time, the region's
relocations marked (matplotlib, Agg, no display)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from .output import atomic_write


def plot_trace(columns: dict, path, title: str = "") -> Path:
    """Force [N] against t [s] from the trace's columns (t_s, force_x_N, force_y_N, force_z_N,
    relocations), with a dotted line at each step where the region moved; written atomically."""
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise InputError("--png needs matplotlib: pip install matplotlib") from exc
    t = np.asarray(columns["t_s"], dtype=np.float64)
    f = np.column_stack([np.asarray(columns[f"force_{a}_N"], dtype=np.float64) for a in "xyz"])
    moved = np.flatnonzero(np.diff(np.asarray(columns["relocations"]), prepend=0) > 0)
    fig = Figure(figsize=(8, 4), dpi=110)
    ax = fig.add_subplot(1, 1, 1)
    for k, (name, colour) in enumerate(zip("xyz", ("tab:red", "tab:green", "tab:blue"))):
        ax.plot(t, f[:, k], lw=0.8, color=colour, label=f"F{name}")
    ax.plot(t, np.linalg.norm(f, axis=1), lw=1.4, color="black", label="|F|")
    for i in moved:
        ax.axvline(t[i], color="0.6", lw=0.5, ls=":")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("force [N]")
    ax.set_title(title + (f" ({len(moved)} region moves, dotted)" if len(moved) else ""), fontsize=9)
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    return path
