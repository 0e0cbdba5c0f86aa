"""A lesion: a sphere of stiffer tissue in an organ (a scene's ``[lesion]`` table).

Springs whose midpoint lies inside the sphere, and anchors of vertices inside it, are
`stiffness_factor` times stiffer (stiffness and damping both: the same tissue, denser), through
Model's `edge_scale` and `anchor_scale`. A sweep over the organ then shows it as the stiffest spot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..checks import check_limit
from ..errors import InputError

KEYS = ("center_mm", "radius_mm", "stiffness_factor")


@dataclass(frozen=True)
class Lesion:
    center: tuple
    """Centre of the sphere [m] (x, y, z)."""
    radius: float
    """Radius [m]."""
    stiffness_factor: float
    """Multiplier of spring and anchor stiffness and damping inside (> 0; > 1 for a hard lesion)."""

    def vertex_inside(self, vertices: np.ndarray) -> np.ndarray:
        """Boolean mask of the vertices [m] inside the sphere."""
        d = np.asarray(vertices, dtype=np.float64) - np.asarray(self.center, dtype=np.float64)
        return np.einsum("ij,ij->i", d, d) <= self.radius**2

    def scales(self, mesh):
        """(edge_scale [edge_count], anchor_scale [vertex_count]) for Model: the factor inside, 1 outside."""
        v = mesh.vertices
        e = mesh.edges
        edge_in = self.vertex_inside(0.5 * (v[e[:, 0]] + v[e[:, 1]]))
        edge_scale = np.where(edge_in, self.stiffness_factor, 1.0)
        anchor_scale = np.where(self.vertex_inside(v), self.stiffness_factor, 1.0)
        return edge_scale, anchor_scale

    def as_dict(self) -> dict:
        return {
            "center_mm": [c * 1e3 for c in self.center],
            "radius_mm": self.radius * 1e3,
            "stiffness_factor": self.stiffness_factor,
        }


def parse_lesion(table, where: str) -> Lesion:
    """A Lesion from a scene file's ``[lesion]`` table (mm), or InputError naming the file and key."""
    if not isinstance(table, dict):
        raise InputError(f"{where}: [lesion] must be a table, got {type(table).__name__}")
    unknown = [k for k in table if k not in KEYS]
    if unknown:
        raise InputError(f"{where}: unknown key {unknown[0]!r} in [lesion]; allowed: {', '.join(KEYS)}")
    missing = [k for k in KEYS[:2] if k not in table]
    if missing:
        raise InputError(f"{where}: [lesion] needs {missing[0]}")
    center = table["center_mm"]
    if (
        not isinstance(center, list)
        or len(center) != 3
        or not all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in center)
    ):
        raise InputError(f"{where}: [lesion] center_mm must be 3 finite numbers [x, y, z], got {center!r}")

    def positive(key, default=None):
        value = table.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise InputError(f"{where}: [lesion] {key} must be a finite number > 0, got {value!r}")
        return float(value)

    factor = positive("stiffness_factor", 5.0)
    check_limit(factor, "lesion_factor", f"{where}: [lesion] stiffness_factor")  # past it float32 stiffness means nothing
    return Lesion(
        center=tuple(float(c) / 1000.0 for c in center),
        radius=positive("radius_mm") / 1000.0,
        stiffness_factor=factor,
    )
