"""A picture of a force trace: the force's components and magnitude against time over the probe's
path, the peak and the region's relocations marked (matplotlib, Agg, no pyplot, no display)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from .output import atomic_write

AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")


def region_moves(relocations) -> np.ndarray:
    """Rows at which the region moved: where the running count of relocations goes up."""
    return np.flatnonzero(np.diff(np.asarray(relocations), prepend=0) > 0)


def trace_figure(columns: dict, title: str = ""):
    """The figure of a trace (matplotlib Figure, not yet saved) from its columns (t_s, probe_{x,y,z}_mm,
    force_{x,y,z}_N, relocations): the force above, the probe's position below, on one time axis."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    t = np.asarray(columns["t_s"], dtype=np.float64)
    f = np.column_stack([np.asarray(columns[f"force_{a}_N"], dtype=np.float64) for a in "xyz"])
    moved = region_moves(columns["relocations"])
    fig = Figure(figsize=(9, 6), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    force, probe = fig.subplots(2, 1, sharex=True, height_ratios=(3, 2))
    for k, (name, colour) in enumerate(zip("xyz", AXIS_COLOURS)):
        force.plot(t, f[:, k], lw=0.8, color=colour, label=f"$F_{name}$, along {name}")
    mag = np.linalg.norm(f, axis=1)
    force.plot(t, mag, lw=1.4, color="black", label="|F|, magnitude")
    peak = int(np.argmax(mag))
    force.plot([t[peak]], [mag[peak]], "o", ms=4, color="black")
    force.annotate(f"peak {mag[peak]:.3f} N at t = {t[peak]:.3f} s", (t[peak], mag[peak]), xytext=(0, 10),
                   textcoords="offset points", ha="center", fontsize=8)
    force.set_ylim(top=force.get_ylim()[1] + 0.12 * np.ptp(force.get_ylim()))  # room for the peak's label
    force.set_ylabel("force on the probe [N]")
    if "probe_x_mm" in columns:
        for k, (name, colour) in enumerate(zip("xyz", AXIS_COLOURS)):
            p = np.asarray(columns[f"probe_{name}_mm"], dtype=np.float64)
            probe.plot(t, p - p[0], lw=1.0, color=colour, label=f"{name}")
    probe.set_ylabel("probe from its start [mm]")
    probe.set_xlabel("t [s]")
    for ax in (force, probe):
        for i in moved:
            ax.axvline(t[i], color="0.55", lw=0.6, ls=":")
        if len(moved):
            ax.plot([], [], color="0.55", lw=0.6, ls=":", label=f"region moved ({len(moved)}x)")
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8)
        ax.grid(alpha=0.3)
    force.set_title(title, fontsize=10)
    return fig


def plot_trace(columns: dict, path, title: str = "") -> Path:
    """Write trace_figure(...) to the PNG `path` (a temporary file, then a rename)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError as exc:
        raise InputError("--png needs matplotlib: pip install matplotlib") from exc
    fig = trace_figure(columns, title)
    path = Path(path)
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
    return path
