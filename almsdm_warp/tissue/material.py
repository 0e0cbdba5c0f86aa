"""Tissue as a material: springs, anchors, masses and dampers derived from E, nu and rho.

A spring network whose edge stiffness is a modulus times the volume (or area) around the edge over
its length squared (Van Gelder 1998) has, under a uniform strain, the energy of a continuum: so a
finer mesh gives the same organ, not a stiffer one. Volume mesh (tets), per edge ij:

    k_ij = E_net * sum(V_t, tets around ij) / l_ij^2

Surface mesh (a membrane of thickness t on a Winkler foundation), per edge and per vertex:

    k_ij = E_net * t * sum(A_f, triangles around ij) / l_ij^2,      k_i = kappa * A_i

with A_i a third of the area of each triangle at vertex i. A network of central springs has a fixed
Poisson ratio (1/4 for an isotropic tet network, 1/3 for a triangle network, in the linear limit), so
it cannot match E and nu at once. `POISSON_LAWS` names the choices of E_net:

- ``"indentation"`` (default, volume meshes): E_net = E (1 - 1/16) / (1 - nu^2). The network's
  indentation modulus E_net / (1 - 1/16) then equals the material's E / (1 - nu^2), the modulus
  that sets the force of a probe pressed into a body (Hertz, Boussinesq): what palpation measures.
- ``"young"``: E_net = E. Matches uniaxial stress (a free bar pulled) instead.

For a membrane the law is E_net = E (a triangle network's plane-stress modulus); `membrane_factor`
scales it. docs/calibration.md ("Springs from a material") has the measurements behind these choices;
scripts/material_check.py regenerates them.

Pure NumPy: the arrays it makes are what `Model` takes (stiffness [N/m], damping [N s/m], mass [kg]).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ..checks import check_fields
from ..mesh.topology import TET_EDGES, lumped_masses, tet_signed_volumes, triangle_areas, unique_edges

MATERIAL_KEYS: dict[str, tuple[str, type, float, str]] = {
    "youngs_modulus_kPa": ("youngs_modulus", float, 1.0e-3, "> 0"),
    "poisson_ratio": ("poisson_ratio", float, 1.0, "number"),
    "density_kg_per_m3": ("density", float, 1.0, "> 0"),
    "thickness_mm": ("thickness", float, 1000.0, ">= 0"),
    "foundation_kPa_per_mm": ("foundation", float, 1.0e-6, ">= 0"),
    "damping_ratio": ("damping_ratio", float, 1.0, ">= 0"),
    "rayleigh_alpha_per_s": ("rayleigh_alpha", float, 1.0, ">= 0"),
    "rayleigh_beta_s": ("rayleigh_beta", float, 1.0, ">= 0"),
}
"""The [tissue] keys of ``model = "material"`` in a scene file: key -> (Material attribute, type, file
units per SI unit, rule). Material checks the ranges (nu in (-1, 0.5), one kind of damping)."""

POISSON_LAWS = {
    "indentation": lambda nu: (1.0 - 1.0 / 16.0) / (1.0 - nu * nu),
    "young": lambda nu: 1.0,
}
"""E_net / E for each Poisson correction, as a function of the material's nu (volume meshes)."""


@dataclass(frozen=True)
class Material:
    """An isotropic, linear elastic tissue, in SI units.

    Damping is given one way or the other, not both: `damping_ratio`, or Rayleigh `rayleigh_alpha`
    and `rayleigh_beta` (all zero: no damping).
    """

    youngs_modulus: float
    """Young's modulus E [Pa], > 0 (soft tissue: about 1e3 to 1e5)."""
    poisson_ratio: float = 0.45
    """Poisson ratio nu, -1 < nu < 0.5."""
    density: float = 1000.0
    """Density rho [kg/m^3], > 0."""
    thickness: float = 0.0
    """Membrane thickness t [m] of a surface mesh, >= 0 (> 0 for a surface mesh); unused for tets."""
    foundation: float = 0.0
    """Winkler foundation modulus kappa [Pa/m], >= 0: the anchor pressure per unit displacement
    (1 kPa/mm = 1e6 Pa/m). Anchors k_i = kappa A_i on surface vertices."""
    damping_ratio: float = 0.0
    """zeta, 0 <= zeta: each damper as a fraction of the critical damping of its own spring, edge
    ij with the reduced mass m_i m_j / (m_i + m_j), anchor i with m_i: d = 2 zeta sqrt(k m)."""
    rayleigh_alpha: float = 0.0
    """Mass-proportional Rayleigh coefficient alpha [1/s], >= 0: vertex damping d_i += alpha m_i."""
    rayleigh_beta: float = 0.0
    """Stiffness-proportional Rayleigh coefficient beta [s], >= 0: d_ij = beta k_ij, d_i += beta k_i."""

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise TypeError(f"Material.{f.name} must be a number, got {type(value).__name__} {value!r}")
        check_fields(self, MATERIAL_KEYS)  # finite, and 0 or of the magnitude every parameter is held to
        rules = (
            ("youngs_modulus", self.youngs_modulus > 0.0, "> 0 [Pa]"),
            ("poisson_ratio", -1.0 < self.poisson_ratio < 0.5, "in (-1, 0.5)"),
            ("density", self.density > 0.0, "> 0 [kg/m^3]"),
            ("thickness", self.thickness >= 0.0, ">= 0 [m]"),
            ("foundation", self.foundation >= 0.0, ">= 0 [Pa/m]"),
            ("damping_ratio", self.damping_ratio >= 0.0, ">= 0"),
            ("rayleigh_alpha", self.rayleigh_alpha >= 0.0, ">= 0 [1/s]"),
            ("rayleigh_beta", self.rayleigh_beta >= 0.0, ">= 0 [s]"),
        )
        for name, ok, allowed in rules:
            value = getattr(self, name)
            if not math.isfinite(value) or not ok:
                raise ValueError(f"Material.{name} = {value!r}: must be {allowed}")
        if self.damping_ratio > 0.0 and (self.rayleigh_alpha > 0.0 or self.rayleigh_beta > 0.0):
            raise ValueError(
                f"Material: damping_ratio = {self.damping_ratio!r} and Rayleigh alpha = {self.rayleigh_alpha!r}, "
                f"beta = {self.rayleigh_beta!r} both given; give one or the other"
            )


@dataclass(frozen=True)
class UniformSprings:
    """The same constants on every edge and vertex: the paper's model, with SI values."""

    edge_stiffness: float
    """k_ij [N/m] on every edge."""
    anchor_stiffness: float
    """k_i [N/m] on every vertex."""
    edge_damping: float
    """d_ij [N s/m] on every edge."""
    anchor_damping: float
    """d_i [N s/m] on every vertex."""
    density: float
    """[kg/m^3], for the lumped masses."""
    thickness: float
    """Shell thickness [m] of a surface mesh, for its lumped masses."""


PAPER_SPRINGS = UniformSprings(
    edge_stiffness=62.0, anchor_stiffness=124.0, edge_damping=0.02, anchor_damping=0.1, density=1000.0, thickness=25.0e-3
)
"""The stomach scene's calibrated constants (docs/calibration.md): the default TissueParams."""


@dataclass(frozen=True)
class TissueSprings:
    """Per-edge and per-vertex parameters of a mesh's spring network, in SI units."""

    edge_stiffness: np.ndarray
    """k_ij [N/m], shape [edge_count], float64."""
    edge_damping: np.ndarray
    """d_ij [N s/m], shape [edge_count], float64."""
    anchor_stiffness: np.ndarray
    """k_i [N/m], shape [vertex_count], float64."""
    anchor_damping: np.ndarray
    """d_i [N s/m], shape [vertex_count], float64."""
    vertex_mass: np.ndarray
    """m_i [kg], shape [vertex_count], float64."""


def edge_element_measure(vertices, edges, triangles, tetrahedra=None, weights=None) -> np.ndarray:
    """Sum of the volumes of the tets around each edge [m^3], or of the triangle areas [m^2] for a
    surface mesh (no tets), shape [edge_count]; each element's times its `weights` entry where given
    (shape [element_count]: a per-element modulus factor). `edges` rows are (i, j) with i < j."""
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    measure = np.zeros(len(e), dtype=np.float64)
    if tetrahedra is not None and len(tetrahedra):
        el = np.asarray(tetrahedra, dtype=np.int64)
        local, size = TET_EDGES, np.abs(tet_signed_volumes(vertices, el))
    else:
        el = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        local, size = np.array([[0, 1], [1, 2], [0, 2]]), triangle_areas(vertices, el)
    if len(el) == 0:
        return measure
    if weights is not None:
        size = size * np.asarray(weights, dtype=np.float64)
    pairs = np.sort(el[:, local].reshape(-1, 2), axis=1)
    n = len(vertices)
    key, pair_key = e[:, 0] * n + e[:, 1], pairs[:, 0] * n + pairs[:, 1]
    order = np.argsort(key)
    sorted_key = key[order]  # searchsorted on a sorted copy: 5x sooner than through `sorter` on 1.5M edges
    idx = order[np.minimum(np.searchsorted(sorted_key, pair_key), max(len(key) - 1, 0))] if len(key) else None
    if idx is None or np.any(key[idx] != pair_key):
        raise ValueError("an element edge is missing from `edges` (rows must be (i, j) with i < j)")
    # np.add.at's sums, in the same order (bincount adds its weights in input order), 10x sooner
    return measure + np.bincount(idx, np.repeat(size, len(local)), minlength=len(e))


def vertex_areas(vertices, triangles, weights=None) -> np.ndarray:
    """Each vertex's share of the surface [m^2]: a third of each triangle at it, shape [vertex_count];
    each triangle's times its `weights` entry where given (shape [triangle_count])."""
    tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    areas = np.zeros(len(vertices), dtype=np.float64)
    share = triangle_areas(vertices, tri) / 3.0
    if weights is not None:
        share = share * np.asarray(weights, dtype=np.float64)
    areas += np.bincount(tri.reshape(-1), np.repeat(share, 3), minlength=len(vertices))
    return areas


def edge_stiffness(material: Material, vertices, edges, triangles, tetrahedra=None, *, law: str = "indentation",
                   membrane_factor: float = 1.0) -> np.ndarray:
    """k_ij [N/m] per edge (module docstring): volume law for tets, membrane law for a surface."""
    if law not in POISSON_LAWS:
        raise ValueError(f"law {law!r} is not one of {sorted(POISSON_LAWS)}")
    v = np.asarray(vertices, dtype=np.float64)
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    length_sq = np.einsum("ij,ij->i", v[e[:, 1]] - v[e[:, 0]], v[e[:, 1]] - v[e[:, 0]])
    if np.any(length_sq <= 0.0):
        bad = int(np.flatnonzero(length_sq <= 0.0)[0])
        raise ValueError(f"edge {bad} ({e[bad, 0]}, {e[bad, 1]}) has length 0: no stiffness can be derived")
    measure = edge_element_measure(v, e, triangles, tetrahedra)
    if tetrahedra is not None and len(tetrahedra):
        modulus = material.youngs_modulus * POISSON_LAWS[law](material.poisson_ratio)
    else:
        if material.thickness <= 0.0:
            raise ValueError("Material.thickness = 0: a surface mesh needs a membrane thickness > 0 [m]")
        modulus = material.youngs_modulus * material.thickness * membrane_factor
    return modulus * measure / length_sq


def anchor_stiffness(material: Material, vertices, triangles, tetrahedra=None, *, anchor_volume: bool = False):
    """k_i = kappa A_i [N/m] per vertex, A_i the vertex's surface share; zero on a tet mesh unless
    `anchor_volume` (then its surface triangles carry the foundation)."""
    if tetrahedra is not None and len(tetrahedra) and not anchor_volume:
        return np.zeros(len(vertices), dtype=np.float64)
    return material.foundation * vertex_areas(vertices, triangles)


def damping(material: Material, edges, k_edge, k_anchor, mass):
    """(d_ij [N s/m] per edge, d_i [N s/m] per vertex) from the damping ratio or Rayleigh coefficients."""
    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if material.damping_ratio > 0.0:
        mi, mj = mass[e[:, 0]], mass[e[:, 1]]
        reduced = np.divide(mi * mj, mi + mj, out=np.zeros(len(e)), where=(mi + mj) > 0.0)
        zeta = material.damping_ratio
        return 2.0 * zeta * np.sqrt(k_edge * reduced), 2.0 * zeta * np.sqrt(k_anchor * mass)
    return material.rayleigh_beta * k_edge, material.rayleigh_alpha * mass + material.rayleigh_beta * k_anchor


def springs_from_material(material: Material, vertices, triangles, tetrahedra=None, edges=None, *,
                          law: str = "indentation", membrane_factor: float = 1.0,
                          anchor_volume: bool = False) -> TissueSprings:
    """Every spring, anchor, damper and mass of a mesh (arrays in metres) from a material.

    `edges` default to the mesh's unique edges (tet edges for a volume mesh). Masses are the lumped
    masses of `mesh.topology.lumped_masses` (tets: rho V / 4 per corner; surface: rho t A / 3).
    """
    edges = unique_edges(triangles, tetrahedra) if edges is None else np.asarray(edges)
    tets = np.zeros((0, 4), dtype=np.int64) if tetrahedra is None else np.asarray(tetrahedra)
    k_edge = edge_stiffness(material, vertices, edges, triangles, tets, law=law, membrane_factor=membrane_factor)
    k_anchor = anchor_stiffness(material, vertices, triangles, tets, anchor_volume=anchor_volume)
    mass = lumped_masses(vertices, triangles, tets, material.density, material.thickness)
    d_edge, d_anchor = damping(material, edges, k_edge, k_anchor, mass)
    return TissueSprings(k_edge, d_edge, k_anchor, d_anchor, mass)


def springs_uniform(constants: UniformSprings, vertices, triangles, tetrahedra=None, edges=None) -> TissueSprings:
    """The paper's model: `constants` on every edge and vertex, lumped masses as for a material."""
    edges = unique_edges(triangles, tetrahedra) if edges is None else np.asarray(edges)
    tets = np.zeros((0, 4), dtype=np.int64) if tetrahedra is None else np.asarray(tetrahedra)
    n, m = len(vertices), len(edges)
    mass = lumped_masses(vertices, triangles, tets, constants.density, constants.thickness)
    return TissueSprings(
        np.full(m, constants.edge_stiffness), np.full(m, constants.edge_damping),
        np.full(n, constants.anchor_stiffness), np.full(n, constants.anchor_damping), mass,
    )


def springs_for_mesh(mesh, source, **options) -> TissueSprings:
    """`springs_from_material` or `springs_uniform` for a TissueMesh, on its own edges."""
    if isinstance(source, UniformSprings):
        return springs_uniform(source, mesh.vertices, mesh.triangles, mesh.tetrahedra, mesh.edges)
    return springs_from_material(source, mesh.vertices, mesh.triangles, mesh.tetrahedra, mesh.edges, **options)


def holding_notes(tissue, is_volume: bool, supported: bool) -> list[str]:
    """What keeps a press on this tissue from coming back to rest, one line each (empty: nothing).

    A tet mesh on a material has no anchors (a foundation acts on a surface), nor has a surface with
    no foundation: with no support only the
    local region's fixed outer ring holds the body, and a region grown from a sphere's patch can be
    most of a lobe, a cantilever on that ring whose lowest mode is below 1 Hz (the shipped liver:
    0.67 Hz, docs/calibration.md, "A tet liver with nothing under it"). Without mass-proportional
    damping nothing slows such a mode (a damping ratio damps each spring's own, much faster, mode),
    so the organ swings for seconds after the probe lets go. `tissue` of another kind (the paper's
    constants, with an anchor on every vertex): no notes.
    """
    if not isinstance(tissue, Material):
        return []
    notes = []
    unheld = (is_volume or tissue.foundation <= 0.0) and not supported  # no anchors, no support
    if unheld:
        what = "a tet mesh" if is_volume else "a surface with no foundation"
        notes.append(f"{what} on a material has no anchors and no support: only the region's fixed outer ring "
                     "holds it, and the body may swing on that ring after a press; give a support "
                     "(--support far-side, --fixed-below-mm, [support] fixed_below_mm)")
    undamped = tissue.damping_ratio <= 0.0 and tissue.rayleigh_beta <= 0.0
    if tissue.rayleigh_alpha <= 0.0 and (undamped or unheld):
        notes.append("the material has no mass-proportional damping (rayleigh_alpha_per_s, --rayleigh-alpha-per-s): "
                     "its slow modes are undamped and a press may not settle within its window")
    return notes


def material_as_dict(material: Material) -> dict:
    """The material in a scene file's keys and units (kPa, mm, kPa/mm), for JSON records."""
    return {key: getattr(material, attr) * factor for key, (attr, _kind, factor, _rule) in MATERIAL_KEYS.items()}
