"""What a scene's surface becomes where it is pressed: the mesh as read, its volume filled with tets
(`[mesh] volume = "auto"`, `--volume auto`: mesh/volume.py) or its wall as a layer of tets (`[tissue] wall =
"tets"`, `--wall tets`: tissue/wall.py). One rule for every front end: palpate, sweep, trace, datasets.

The edges where the probe presses are contact_edge(R, d) = 0.45 x the Hertz contact radius (the project's
resolution rule, docs/calibration.md), within 4 such edges of every pressed point (a press's contact, a
sweep's points, a path's contacts) and growing away from them; the paper's probe (R = 0) gets fTetWild's
uniform default. A wall's layers are no higher than that edge, nor than the surface's mean edge.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError


def needs_volume(choice: str, mesh, tissue, law: str | None = None) -> bool:
    """Whether `choice` ("auto" or "off") makes `mesh` a volume: auto, a surface mesh, a Material and a
    volumetric law (tissue/laws.py; None: the law a volume would get, default_law)."""
    from ..tissue.laws import LAWS, default_law
    from ..tissue.material import Material

    law = default_law(True, tissue) if law is None else law
    return (choice == "auto" and not mesh.is_volume and isinstance(tissue, Material)
            and law in LAWS and LAWS[law].volumetric)


def tets_wanted(scene, mesh, volume: str | None = None, wall: str | None = None) -> str | None:
    """"wall", "volume" or None: what `scene` makes of `mesh` (`volume` and `wall`, where given, in place of
    its [mesh] volume and [tissue] wall). InputError for a wall of tets on a mesh or tissue that has none
    (a tet mesh, the paper's constants) and for a wall and a volume both asked."""
    from ..tissue.material import Material

    volume = scene.volume if volume is None else volume
    wall = scene.wall if wall is None else wall
    if wall == "tets":
        if mesh.is_volume or not isinstance(scene.tissue, Material):
            what = f"{mesh.name} is already tets" if mesh.is_volume else "the tissue is the paper's per-spring constants"
            raise InputError(f"a wall of tets (--wall tets, [tissue] wall) is made of a surface of a material; {what}")
        if volume == "auto":
            raise InputError("--wall tets and --volume auto ([tissue] wall, [mesh] volume) both make the surface tets: "
                             "a wall of its thickness, or the whole volume inside it; give one")
        return "wall"
    return "volume" if needs_volume(volume, mesh, scene.tissue, scene.law) else None


def pressed_edge(probe_radius: float, depth: float) -> float | None:
    """The resolved edge [m] where a sphere of `probe_radius` [m] presses `depth` [m] (mesh.volume.contact_edge),
    or None for the paper's probe (R = 0) or no press."""
    from ..mesh.volume import contact_edge

    if probe_radius > 0.0 and depth > 0.0 and math.isfinite(probe_radius):
        return contact_edge(probe_radius, depth)
    return None


def make_tets(kind: str, scene, mesh, near, probe_radius: float, depth: float):
    """`mesh` made tets as `kind` ("wall" or "volume", tets_wanted) for presses of a sphere of `probe_radius`
    [m], `depth` [m] deep at `near` (a point or points [k, 3] on the surface [m]; None: nowhere in particular)."""
    from ..mesh.volume import tetrahedralize
    from ..tissue.wall import extrude_wall

    edge = pressed_edge(probe_radius, depth)
    if kind == "wall":
        mean = float(mesh.edge_rest_length.mean())
        wall = extrude_wall(mesh, scene.tissue.thickness, edge=mean if edge is None else min(edge, mean))
        if scene.tissue.foundation > 0.0:  # anchors act on a surface: a tet mesh has none
            wall.notes = (*wall.notes, f"the foundation ({scene.tissue.foundation * 1e-6:g} kPa/mm) is the membrane's: "
                                       "a wall of tets has none, its inner surface is free")
        return wall
    if edge is None or near is None or not len(np.asarray(near).reshape(-1, 3)):
        return tetrahedralize(mesh)
    return tetrahedralize(mesh, near=near, near_edge=edge)


def snap_to(mesh, points, fixed_below: float | None = None):
    """(points, vertices) of `points` [k, 3] [m] on `mesh`'s surface: each point's nearest surface vertex,
    less those a support holds (z below `fixed_below` [m]); InputError where it holds every one."""
    from scipy.spatial import cKDTree

    surface = mesh.surface_vertices
    vertices = surface[cKDTree(mesh.vertices[surface]).query(np.asarray(points, dtype=np.float64))[1]].astype(np.int64)
    keep = np.ones(len(vertices), dtype=bool) if fixed_below is None else mesh.vertices[vertices, 2] >= fixed_below
    if not keep.any():
        raise InputError(f"every sampled point is held by the support (z below {fixed_below * 1e3:g} mm)")
    return np.asarray(points, dtype=np.float64)[keep], vertices[keep]


def sweep_tets(kind: str, scene, surface, count: int, depth: float):
    """A sweep's tets: `count` points sampled on `surface` as a sweep samples them (batch.sampling, the scene's
    support), and `surface` made tets as `kind`, finest at every one of them (a sweep that covers the organ gets
    the resolved edge all over its surface, one that presses a few spots gets it there). Returns (tets, points
    [k, 3] on the surface [m]): snap_to puts the points on the tets once their support is known."""
    from ..batch.sampling import pressable_points

    points, _vertices = pressable_points(surface, count, scene.fixed_below)
    return make_tets(kind, scene, surface, points, scene.probe_radius, depth), points


def scene_tets(scene, surface, count: int, depth: float, volume: str | None = None):
    """A dataset's scene (no flags: its own keys, `volume` in place of its [mesh] volume where given) pressed at
    `count` points `depth` [m] deep: (the scene with its support resolved on the tets, the tets, (points, vertices)
    on them) as sweep_tets makes them; (scene, surface, None) where it keeps its surface."""
    from ..region.contact import top_vertex

    kind = tets_wanted(scene, surface, volume)
    if kind is None:
        return scene, surface, None
    resolved = scene.with_support(surface, float(surface.vertices[top_vertex(surface), 2]))
    tets, points = sweep_tets(kind, resolved, surface, count, depth)
    scene = scene.with_support(tets, float(tets.vertices[top_vertex(tets), 2]))
    return scene, tets, snap_to(tets, points, scene.fixed_below)
