"""A picture of a sweep: the organ coloured by stiffness under the probe (matplotlib, Agg, no display)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError


def plot_sweep(mesh, columns: dict, path, title: str = "") -> Path:
    """Two views of the surface, each vertex coloured by the stiffness of the nearest swept point."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    except ImportError as exc:
        raise InputError("--png needs matplotlib: pip install matplotlib") from exc
    from scipy.spatial import cKDTree

    from .output import atomic_write

    v = mesh.vertices * 1e3
    tri = mesh.triangles
    pts = np.column_stack([columns["x_mm"], columns["y_mm"], columns["z_mm"]])
    stiff = np.asarray(columns["stiffness_N_per_mm"], dtype=np.float64)
    _, near = cKDTree(pts).query(v)
    face_value = stiff[near][tri].mean(axis=1)
    finite = np.isfinite(face_value)
    lo, hi = (np.nanmin(face_value[finite]), np.nanmax(face_value[finite])) if finite.any() else (0.0, 1.0)
    norm = matplotlib.colors.Normalize(vmin=lo, vmax=hi if hi > lo else lo + 1e-9)
    cmap = matplotlib.colormaps["viridis"]
    fig = plt.figure(figsize=(10, 4.8), dpi=110)
    for k, (elev, azim) in enumerate(((30, -60), (30, 120))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        poly = Poly3DCollection(v[tri], facecolors=cmap(norm(np.nan_to_num(face_value, nan=lo))), edgecolors="none")
        ax.add_collection3d(poly)
        span = np.ptp(v, axis=0).max() / 2
        mid = (v.max(axis=0) + v.min(axis=0)) / 2
        for set_lim, m in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid):
            set_lim(m - span, m + span)
        ax.view_init(elev=elev, azim=azim)
        ax.set_axis_off()
    fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap), ax=fig.axes, shrink=0.7, label="stiffness [N/mm]")
    fig.suptitle(title)
    path = Path(path)

    def write(tmp):
        fig.savefig(tmp, format="png")

    try:
        atomic_write(path, write)
    finally:
        plt.close(fig)
    return path
