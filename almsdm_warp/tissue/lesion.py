"""A lesion: a sphere of stiffer tissue in an organ (a scene's ``[lesion]`` table).

On a material (``model = "material"``) the lesion is a stiffer material: each element (tet, or
triangle of a membrane) whose centroid lies inside the sphere has Young's modulus (and, on a surface,
foundation modulus: the tissue under the wall) `stiffness_factor` times higher, and every spring is
derived from the elements around it, each with its own E (tissue.material: k_ij = E_net sum(f_t V_t)
/ l_ij^2, an anchor from its triangles' f_t A_t / 3). An edge half inside gets the volume-weighted
stiffness, so refining the mesh converges to the sphere. Model's dampers follow the scaled springs by
the material's damping law.

On the paper's constants: springs whose midpoint lies inside the sphere, and anchors of vertices
inside it, are `stiffness_factor` times stiffer (stiffness and damping both: the same tissue,
denser).

Either way `Lesion.scales` gives Model's `edge_scale` and `anchor_scale`. A sweep over the organ
then shows the lesion as the stiffest spot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..checks import check_limit
from ..errors import InputError
from .material import Material, edge_element_measure, vertex_areas

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

    def element_factor(self, vertices: np.ndarray, elements: np.ndarray) -> np.ndarray:
        """Modulus factor of each element (rows of vertex ids): `stiffness_factor` where its centroid
        [m] is inside the sphere, else 1, shape [element_count]."""
        el = np.asarray(elements, dtype=np.int64)
        centroid = np.asarray(vertices, dtype=np.float64)[el].mean(axis=1) if len(el) else np.zeros((0, 3))
        return np.where(self.vertex_inside(centroid), self.stiffness_factor, 1.0)

    def scales(self, mesh, tissue=None):
        """(edge_scale [edge_count], anchor_scale [vertex_count]) for Model: on a Material (`tissue`),
        each spring's and anchor's stiffness with the per-element E over the uniform one (module
        docstring); otherwise the factor on springs whose midpoint, and anchors whose vertex, is inside."""
        v = mesh.vertices
        e = mesh.edges
        if isinstance(tissue, Material):
            volume = mesh.tetrahedra is not None and len(mesh.tetrahedra) > 0
            elements = mesh.tetrahedra if volume else mesh.triangles
            tets = mesh.tetrahedra if volume else None
            uniform = edge_element_measure(v, e, mesh.triangles, tets)
            stiff = edge_element_measure(v, e, mesh.triangles, tets, weights=self.element_factor(v, elements))
            area = vertex_areas(v, mesh.triangles)
            area_stiff = vertex_areas(v, mesh.triangles, weights=self.element_factor(v, mesh.triangles))
            return _ratio(stiff, uniform), _ratio(area_stiff, area)
        edge_in = self.vertex_inside(0.5 * (v[e[:, 0]] + v[e[:, 1]]))
        edge_scale = np.where(edge_in, self.stiffness_factor, 1.0)
        anchor_scale = np.where(self.vertex_inside(v), self.stiffness_factor, 1.0)
        return edge_scale, anchor_scale

    def model_scales(self, mesh, tissue=None, law: str | None = None) -> dict:
        """Model's keywords for this lesion under tissue law `law` (None: the mesh's default, default_law):
        a volumetric law's per-tet modulus factor (element_scale: element_factor of each tet), else the
        springs' (edge_scale, anchor_scale: scales)."""
        from .laws import law_entry, resolve_law

        if law_entry(resolve_law(law, mesh, tissue)).volumetric:
            return {"element_scale": self.element_factor(mesh.vertices, mesh.tetrahedra)}
        edge_scale, anchor_scale = self.scales(mesh, tissue)
        return {"edge_scale": edge_scale, "anchor_scale": anchor_scale}

    def as_dict(self) -> dict:
        return {
            "center_mm": [c * 1e3 for c in self.center],
            "radius_mm": self.radius * 1e3,
            "stiffness_factor": self.stiffness_factor,
        }


def _ratio(weighted: np.ndarray, plain: np.ndarray) -> np.ndarray:
    """weighted / plain, 1 where plain is 0 (an interior vertex has no surface share)."""
    return np.divide(weighted, plain, out=np.ones_like(plain), where=plain > 0.0)


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
