#!/usr/bin/env python3
"""Generate the project's own default meshes, in millimetres, under scenes/.

    python scripts/make_scenes.py            # (re)write scenes/stomach.obj and scenes/liver.vtu
    python scripts/make_scenes.py --check    # exit 1 if the files in scenes/ are not what this makes
    python scripts/make_scenes.py --out DIR  # write into DIR instead

Deterministic: no randomness, coordinates rounded to 0.1 um, so running it twice gives
byte-identical files. Needs numpy, meshio and trimesh only (not the package itself).

stomach.obj, a closed genus-0 surface of 1002 vertices and 2000 triangles:
  1. a class-I geodesic sphere of frequency 10 (each icosahedron face cut into 10 x 10
     triangles; the vertices on the icosahedron's edges are shared by index, not merged by
     position; projected to the unit sphere), its poles on two opposite icosahedron vertices;
  2. mapped onto a stomach: a tube swept along a curved (J) centre line, with a wide round
     fundus (a hemispherical cap, radius 40 mm) that tapers to a narrow round pylorus (radius
     17 mm), its cross-section flattened front to back. Each vertex keeps its longitude; its
     latitude goes to a position along the stomach by a blend of the area-preserving and the
     conformal maps of the sphere onto that surface, so that triangles keep both their size
     and their shape about as well as one mesh of fixed connectivity can;
  3. a few passes of area-weighted smoothing that slide the vertices along that surface
     (never off it), to even out what the bend squeezed.

liver.vtu, a tetrahedral volume of 700 vertices and 2340 tetrahedra:
  a structured 14 x 10 x 5 grid, each hexahedron cut into 5 tets with alternating parity (so
  the faces of neighbouring cells conform), mapped by a smooth map with positive Jacobian
  everywhere into a wedge: a thick, domed right lobe that thins to a flat left lobe, flatter
  underneath; every tet positively oriented (det[b-a, c-a, d-a] > 0).

Axes: +z is where a probe comes from (out of the body of a patient lying on the back): the
stomach's broad front face and the liver's domed top face +z. Stomach: its centre line lies in
the x-y plane, fundus at the top (+y), pylorus towards +x. Liver: x runs from the tip of the
left lobe to the right lobe, y from the thin front edge to the back. Each mesh is centred on
its bounding box.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
DECIMALS = 4  # coordinates are rounded to 0.1 um before they are written

# ------------------------------------------------------------------------------------------
# stomach
# ------------------------------------------------------------------------------------------
STOMACH = dict(
    frequency=10,  # geodesic frequency: 10 f^2 + 2 = 1002 vertices, 20 f^2 = 2000 triangles
    fundus_radius_mm=40.0,  # radius of the round fundus (hemispherical cap)
    pylorus_radius_mm=17.0,  # radius of the round pyloric end (hemispherical cap)
    body_length_mm=105.0,  # centre-line length of the tapering body between the two caps
    start_angle_deg=-80.0,  # direction of the centre line at the fundus: down, 10 deg towards +x
    turn_deg=100.0,  # how far the centre line turns (the J), spread as a Gaussian ...
    bend_at=0.7,  # ... centred at this fraction of the body ...
    bend_width=0.4,  # ... with this standard deviation (fraction of the body)
    flatten=0.85,  # front-to-back over side-to-side size of each cross-section
    conformal_blend=0.5,  # latitude map: 0 = area-preserving, 1 = conformal
    smoothing_passes=60,
    smoothing_step=0.5,
)
TABLE = 4000  # samples per piece (fundus cap, body, pyloric cap) of the profile tables


def icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """The 12 vertices (poles on +-z) and 20 outward-wound faces of a unit icosahedron."""
    z, r = 1.0 / np.sqrt(5.0), 2.0 / np.sqrt(5.0)
    verts = [(0.0, 0.0, 1.0)]
    verts += [(r * np.cos(2 * np.pi * k / 5), r * np.sin(2 * np.pi * k / 5), z) for k in range(5)]
    verts += [(r * np.cos(2 * np.pi * (k + 0.5) / 5), r * np.sin(2 * np.pi * (k + 0.5) / 5), -z) for k in range(5)]
    verts += [(0.0, 0.0, -1.0)]
    faces = []
    for k in range(5):
        u0, u1 = 1 + k, 1 + (k + 1) % 5
        l0, l1 = 6 + k, 6 + (k + 1) % 5
        faces += [(0, u0, u1), (u0, l0, u1), (u1, l0, l1), (11, l1, l0)]
    return np.array(verts, dtype=np.float64), np.array(faces, dtype=np.int64)


def geodesic_sphere(freq: int) -> tuple[np.ndarray, np.ndarray]:
    """Class-I geodesic sphere: (vertices on the unit sphere [10 f^2 + 2, 3], triangles [20 f^2, 3]).

    Vertices are numbered: the 12 icosahedron vertices, then the f-1 inner points of each
    icosahedron edge (as first met), then each face's interior points. Points on an edge are
    made once, by the edge's key, so neighbouring faces share them exactly.
    """
    ico_v, ico_f = icosahedron()
    points: list[np.ndarray] = list(ico_v)
    edge_points: dict[tuple[int, int], list[int]] = {}

    def on_edge(a: int, b: int, m: int) -> int:
        """The id of the m-th of the f-1 inner points of edge a->b (m = 1 .. f-1, from a)."""
        key, mm = ((a, b), m) if a < b else ((b, a), freq - m)
        if key not in edge_points:
            p, q = ico_v[key[0]], ico_v[key[1]]
            edge_points[key] = []
            for s in range(1, freq):
                edge_points[key].append(len(points))
                points.append(p + (q - p) * (s / freq))
        return edge_points[key][mm - 1]

    triangles = []
    for a, b, c in ico_f:
        grid: dict[tuple[int, int], int] = {}
        for i in range(freq + 1):  # weight of b
            for j in range(freq + 1 - i):  # weight of c
                k = freq - i - j  # weight of a
                if i == 0 and j == 0:
                    vid = int(a)
                elif j == 0 and k == 0:
                    vid = int(b)
                elif i == 0 and k == 0:
                    vid = int(c)
                elif j == 0:
                    vid = on_edge(a, b, i)
                elif i == 0:
                    vid = on_edge(a, c, j)
                elif k == 0:
                    vid = on_edge(b, c, j)
                else:
                    vid = len(points)
                    points.append((ico_v[a] * k + ico_v[b] * i + ico_v[c] * j) / freq)
                grid[i, j] = vid
        for i in range(freq):
            for j in range(freq - i):
                triangles.append((grid[i, j], grid[i + 1, j], grid[i, j + 1]))
                if i + j < freq - 1:
                    triangles.append((grid[i + 1, j], grid[i + 1, j + 1], grid[i, j + 1]))
    verts = np.array(points, dtype=np.float64)
    verts /= np.linalg.norm(verts, axis=1, keepdims=True)
    return verts, np.array(triangles, dtype=np.int64)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def stomach_profile(p: dict) -> dict:
    """Tables for the map from the sphere's polar angle to the stomach.

    The stomach is a tube of radius R(u) about a plane centre line C(u), u its arc length
    from the fundus pole (0) to the pyloric pole (L). Returned: `t` (polar angle on the
    sphere, increasing), with `u` and `R` at each t; and the centre line sampled on `cu`:
    position `cxy` and tangent angle `cang`.
    """
    rf, rp, lb = p["fundus_radius_mm"], p["pylorus_radius_mm"], p["body_length_mm"]
    n = TABLE
    # meridian: fundus cap (angle beta from the pole), body (cosine taper), pyloric cap
    beta_f = np.linspace(0.0, np.pi / 2, n)
    tau = np.linspace(0.0, 1.0, n)[1:]
    beta_p = np.linspace(np.pi / 2, 0.0, n)[1:]
    u = np.concatenate([rf * (1 - np.cos(beta_f)), rf + lb * tau, rf + lb + rp * np.cos(beta_p)])
    R = np.concatenate([rf * np.sin(beta_f), rp + (rf - rp) * (1 + np.cos(np.pi * tau)) / 2, rp * np.sin(beta_p)])
    ds = np.hypot(np.diff(u), np.diff(R))
    # area-preserving latitude: (1 - cos t) / 2 = the fraction of the area up to u
    area = np.concatenate([[0.0], np.cumsum(np.pi * (R[1:] + R[:-1]) * ds)])
    area /= area[-1]
    t_area = np.arccos(np.clip(1 - 2 * area, -1.0, 1.0))
    # conformal latitude: ln tan(t/2) = integral of ds / R (+ a constant); exact on the caps
    with np.errstate(divide="ignore"):
        lam_f = np.log(np.tan(beta_f / 2))
        body = slice(n - 1, 2 * n - 2)
        lam_b = lam_f[-1] + np.cumsum(ds[body] / (0.5 * (R[n - 1 : 2 * n - 2] + R[n : 2 * n - 1])))
        lam_p = lam_b[-1] - np.log(np.tan(beta_p / 2))
    lam = np.concatenate([lam_f, lam_b, lam_p])
    mid = int(np.searchsorted(area, 0.5))  # the two maps agree at half the area
    shift = np.log(np.tan(t_area[mid] / 2)) - lam[mid]
    with np.errstate(over="ignore"):
        t_conf = 2 * np.arctan(np.exp(lam + shift))
    w = p["conformal_blend"]
    t = w * t_conf + (1 - w) * t_area
    t[0], t[-1] = 0.0, np.pi
    if not np.all(np.diff(t) > 0):
        raise RuntimeError("stomach profile: latitude map is not monotone")
    # centre line: tangent angle turns by turn_deg, as a Gaussian bump of curvature on the body
    length = u[-1]
    cu = np.linspace(0.0, length, 8 * n + 1)
    s = (cu - (rf + p["bend_at"] * lb)) / (p["bend_width"] * lb)
    kappa = np.exp(-0.5 * s * s)
    kappa *= np.radians(p["turn_deg"]) / np.trapezoid(kappa, cu)
    du = np.diff(cu)
    cang = np.radians(p["start_angle_deg"]) + np.concatenate([[0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * du)])
    tangent = np.stack([np.cos(cang), np.sin(cang)], axis=1)
    cxy = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * (tangent[1:] + tangent[:-1]) * du[:, None], axis=0)])
    kmax = float(np.max(kappa * np.interp(cu, u, R)))
    if kmax >= 0.7:
        raise RuntimeError(f"stomach profile: bend too tight for the radius (max R*kappa = {kmax:.2f})")
    return dict(t=t, u=u, R=R, cu=cu, cxy=cxy, cang=cang, flatten=p["flatten"], max_r_kappa=kmax)


def stomach_map(sphere: np.ndarray, prof: dict) -> np.ndarray:
    """Map points on the unit sphere (poles on z) to the stomach surface [mm]."""
    t = np.arccos(np.clip(sphere[:, 2], -1.0, 1.0))
    phi = np.arctan2(sphere[:, 1], sphere[:, 0])
    u = np.interp(t, prof["t"], prof["u"])
    R = np.interp(t, prof["t"], prof["R"])
    ang = np.interp(u, prof["cu"], prof["cang"])
    cx = np.interp(u, prof["cu"], prof["cxy"][:, 0])
    cy = np.interp(u, prof["cu"], prof["cxy"][:, 1])
    zero = np.zeros_like(u)
    normal = np.stack([-np.sin(ang), np.cos(ang), zero], axis=1)  # in the bending plane
    binormal = np.array([0.0, 0.0, -1.0])  # out of it (sign: triangles stay wound outward)
    ring = np.cos(phi)[:, None] * normal + prof["flatten"] * np.sin(phi)[:, None] * binormal
    return np.stack([cx, cy, zero], axis=1) + R[:, None] * ring


def smooth_on_surface(sphere: np.ndarray, tris: np.ndarray, prof: dict, passes: int, step: float) -> np.ndarray:
    """Area-weighted (centroidal) smoothing of the mapped mesh, done on the sphere's points.

    Each pass moves each vertex a `step` of the way towards the area-weighted centroid of its
    triangles, in the tangent plane of the stomach: the 3D move is pulled back through the
    map's Jacobian (finite differences on the sphere), so vertices slide along the surface.
    """
    n = len(sphere)
    h = 1e-6
    p = sphere.copy()
    for _ in range(passes):
        x = stomach_map(p, prof)
        c = x[tris]
        area = 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
        centre = c.mean(axis=1)
        weight = np.zeros(n)
        target = np.zeros((n, 3))
        for k in range(3):
            weight += np.bincount(tris[:, k], area, n)
            for d in range(3):
                target[:, d] += np.bincount(tris[:, k], area * centre[:, d], n)
        move = step * (target / weight[:, None] - x)
        # orthonormal tangent basis of the sphere at p
        axis = np.where(np.abs(p[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        e1 = _unit(np.cross(axis, p))
        e2 = np.cross(p, e1)
        j1 = (stomach_map(_unit(p + h * e1), prof) - x) / h
        j2 = (stomach_map(_unit(p + h * e2), prof) - x) / h
        a11, a12, a22 = (j1 * j1).sum(1), (j1 * j2).sum(1), (j2 * j2).sum(1)
        b1, b2 = (j1 * move).sum(1), (j2 * move).sum(1)
        det = a11 * a22 - a12 * a12
        d1 = (a22 * b1 - a12 * b2) / det
        d2 = (a11 * b2 - a12 * b1) / det
        p = _unit(p + d1[:, None] * e1 + d2[:, None] * e2)
    return p


def make_stomach(p: dict = STOMACH) -> tuple[np.ndarray, np.ndarray, dict]:
    """(vertices [mm], triangles, profile) of the stomach, centred on its bounding box."""
    sphere, tris = geodesic_sphere(p["frequency"])
    prof = stomach_profile(p)
    sphere = smooth_on_surface(sphere, tris, prof, p["smoothing_passes"], p["smoothing_step"])
    verts = stomach_map(sphere, prof)
    verts -= 0.5 * (verts.min(axis=0) + verts.max(axis=0))
    return _round(verts), tris, prof


# ------------------------------------------------------------------------------------------
# liver
# ------------------------------------------------------------------------------------------
LIVER = dict(
    grid=(14, 10, 5),  # points along x (left-right), y (front-back), z (bottom-top)
    width_mm=200.0,  # left-right
    right_depth_mm=160.0,  # front-back size of the right lobe (before its corners round off) ...
    left_depth_mm=80.0,  # ... and of the tip of the left lobe
    right_thickness_mm=90.0,  # greatest top-bottom size (in the right lobe) ...
    left_thickness_mm=30.0,  # ... and at the tip of the left lobe
    front_edge=0.45,  # thickness at the front edge, as a fraction of the thickest in that section
    back_edge=0.6,  # thickness at the back edge, as a fraction
    bottom_share=0.2,  # the share of the thickness below the widest level (flat bottom, domed top)
    round_edges=0.2,  # the walls' top and bottom edges are pulled in by this share of the wall height
)

# 5-tet split of a hexahedron, corners numbered dx + 2 dy + 4 dz. Even cells use the even
# corners {0, 3, 5, 6} for the central tet; odd cells are the same split mirrored in x.
_HEX_EVEN = np.array([[0, 3, 5, 6], [1, 0, 3, 5], [2, 0, 6, 3], [4, 0, 5, 6], [7, 3, 6, 5]])


def _mirror_x(corner: np.ndarray) -> np.ndarray:
    return corner ^ 1  # dx -> 1 - dx


def liver_grid(shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(parameter points in [0, 1]^3 [n, 3], positively oriented tets [m, 4]) of the split grid.

    Point (i, j, k) has id i + nx (j + ny k). Orientation is fixed on the integer grid
    (exact), before any mapping.
    """
    nx, ny, nz = shape
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    ijk = np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1)
    params = ijk / np.array([nx - 1, ny - 1, nz - 1], dtype=np.float64)
    tets = []
    for ck in range(nz - 1):
        for cj in range(ny - 1):
            for ci in range(nx - 1):
                corners = [
                    (ci + dx) + nx * ((cj + dy) + ny * (ck + dz))
                    for dz in (0, 1)
                    for dy in (0, 1)
                    for dx in (0, 1)
                ]
                split = _HEX_EVEN if (ci + cj + ck) % 2 == 0 else _mirror_x(_HEX_EVEN)
                tets.extend([[corners[c] for c in tet] for tet in split])
    tets = np.array(tets, dtype=np.int64)
    vol = _tet_volumes(ijk.astype(np.float64), tets)
    flip = vol < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    assert np.all(_tet_volumes(ijk.astype(np.float64), tets) > 0)
    return params, tets


def liver_map(params: np.ndarray, p: dict = LIVER) -> np.ndarray:
    """Map grid parameters to the liver [mm].

    a: tip of the left lobe (0) to the right lobe (1) -> x; b: front (0) to back (1) -> y;
    c: bottom (0) to top (1) -> z. The map is smooth and keeps a positive Jacobian (checked on
    every tet), so the grid's positively oriented tets stay positive.
    """
    a, b, c = params[:, 0], params[:, 1], params[:, 2]
    r = 2 * a - 1  # -1 .. 1, left to right
    s = 2 * b - 1  # -1 .. 1, front to back
    # plan view: a wedge, deep right lobe tapering to the left tip, which sits a little forward
    taper = 1 - (1 - a) ** 1.5
    depth = p["left_depth_mm"] + (p["right_depth_mm"] - p["left_depth_mm"]) * taper
    shift = -0.1 * p["right_depth_mm"] * (1 - taper)
    right = ((1 + r) / 2) ** 4  # 0 over most of the organ, 1 at the right end
    # thickness: thin left tip, thickest at a = 0.75, a little less at the right end;
    # across: front_edge at b = 0, back_edge at b = 1, 1 near b = 0.6 (the dome)
    thick = p["left_thickness_mm"] + (p["right_thickness_mm"] - p["left_thickness_mm"]) * np.sin(np.pi * a / 1.5) ** 2
    edge = p["front_edge"] + (p["back_edge"] - p["front_edge"]) * b
    h = thick * (edge + (1 - edge) * np.sin(np.pi * b**1.35))
    # the walls bulge at mid height and round off towards the top and bottom edges, by a
    # share of the local wall height
    pinch = (1 - np.sin(np.pi * c)) * p["round_edges"] * h
    s_round = s - pinch * s**3 / depth
    r_round = r - pinch * right * r**3 / p["width_mm"]
    x = 0.5 * p["width_mm"] * r_round
    fb = shift + 0.5 * depth * s_round * (1 - 0.1 * right * s**2)
    z = h * (c - p["bottom_share"])
    return np.stack([x, fb, z], axis=1)


def make_liver(p: dict = LIVER) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [mm], positively oriented tets) of the liver, centred on its bounding box."""
    params, tets = liver_grid(p["grid"])
    verts = liver_map(params, p)
    verts -= 0.5 * (verts.min(axis=0) + verts.max(axis=0))
    return _round(verts), tets


# ------------------------------------------------------------------------------------------
# quality
# ------------------------------------------------------------------------------------------
def _round(v: np.ndarray) -> np.ndarray:
    return np.round(v, DECIMALS) + 0.0  # + 0.0 turns -0.0 into 0.0


def _tet_volumes(verts: np.ndarray, tets: np.ndarray) -> np.ndarray:
    p = verts[tets]
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6.0


def _angles_deg(c: np.ndarray) -> np.ndarray:
    """Interior angles [m, 3] of triangles given as corners [m, 3, 3]."""
    out = []
    for k in range(3):
        u = c[:, (k + 1) % 3] - c[:, k]
        v = c[:, (k + 2) % 3] - c[:, k]
        cos = np.einsum("ij,ij->i", u, v) / (np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1))
        out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.stack(out, axis=1)


def _edges(tris: np.ndarray) -> np.ndarray:
    return np.unique(np.sort(tris[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1), axis=0)


def surface_report(verts: np.ndarray, tris: np.ndarray) -> dict:
    """Counts and quality of a triangle surface [mm]."""
    import trimesh

    c = verts[tris]
    ang = _angles_deg(c)
    e = _edges(tris)
    length = np.linalg.norm(verts[e[:, 1]] - verts[e[:, 0]], axis=1)
    area = 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
    mesh = trimesh.Trimesh(verts, tris, process=False)
    return dict(
        vertices=len(verts),
        triangles=len(tris),
        edges=len(e),
        min_angle_deg=float(ang.min()),
        max_angle_deg=float(ang.max()),
        edge_min_mm=float(length.min()),
        edge_mean_mm=float(length.mean()),
        edge_max_mm=float(length.max()),
        edge_p1_mm=float(np.percentile(length, 1)),
        edge_p99_mm=float(np.percentile(length, 99)),
        edge_ratio=float(length.max() / length.min()),
        min_area_mm2=float(area.min()),
        area_mm2=float(area.sum()),
        volume_mm3=float(mesh.volume),
        watertight=bool(mesh.is_watertight),
        winding_consistent=bool(mesh.is_winding_consistent),
        euler=int(mesh.euler_number),
        bbox_mm=tuple(float(s) for s in verts.max(axis=0) - verts.min(axis=0)),
    )


TET_FACES_OUT = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def tet_boundary(tets: np.ndarray) -> np.ndarray:
    """Faces used by exactly one tet, wound outward."""
    faces = tets[:, TET_FACES_OUT].reshape(-1, 3)
    _, inverse, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.reshape(-1)] == 1]


def volume_report(verts: np.ndarray, tets: np.ndarray) -> dict:
    """Counts and quality of a tet mesh [mm]."""
    import trimesh

    vol = _tet_volumes(verts, tets)
    pairs = np.unique(np.sort(tets[:, [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]].reshape(-1, 2), axis=1), axis=0)
    length = np.linalg.norm(verts[pairs[:, 1]] - verts[pairs[:, 0]], axis=1)
    # dihedral angles: between the outward normals n_a, n_b of two faces, 180 - angle(n_a, n_b)
    p = verts[tets]
    normals = []
    for f in TET_FACES_OUT:
        q = p[:, f]
        normals.append(_unit(np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0])))
    dihedral = []
    for fa in range(4):
        for fb in range(fa + 1, 4):
            cos = np.einsum("ij,ij->i", normals[fa], normals[fb])
            dihedral.append(180.0 - np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    dihedral = np.stack(dihedral, axis=1)
    # normalized shape quality: 6 sqrt(2) V / l_rms^3 (1 for a regular tet, 0 for a flat one)
    elen = np.linalg.norm(p[:, [1, 2, 3, 2, 3, 3]] - p[:, [0, 0, 0, 1, 1, 2]], axis=2)
    l_rms = np.sqrt((elen**2).mean(axis=1))
    shape = 6 * np.sqrt(2) * vol / l_rms**3
    boundary = tet_boundary(tets)
    used = np.unique(boundary)
    surface = trimesh.Trimesh(verts, boundary, process=False)
    return dict(
        vertices=len(verts),
        tets=len(tets),
        edges=len(pairs),
        surface_triangles=len(boundary),
        surface_vertices=len(used),
        min_volume_mm3=float(vol.min()),
        max_volume_mm3=float(vol.max()),
        volume_ratio=float(vol.min() / vol.max()),
        min_dihedral_deg=float(dihedral.min()),
        max_dihedral_deg=float(dihedral.max()),
        min_shape_quality=float(shape.min()),
        edge_min_mm=float(length.min()),
        edge_max_mm=float(length.max()),
        volume_mm3=float(vol.sum()),
        surface_volume_mm3=float(surface.volume),
        watertight=bool(surface.is_watertight),
        euler=int(surface.euler_number),
        bbox_mm=tuple(float(s) for s in verts.max(axis=0) - verts.min(axis=0)),
    )


# ------------------------------------------------------------------------------------------
# files
# ------------------------------------------------------------------------------------------
HEADER = "generated by scripts/make_scenes.py; units: mm; do not edit, rerun the script"


def obj_bytes(verts: np.ndarray, tris: np.ndarray, what: str) -> bytes:
    lines = [
        f"# {what}",
        f"# {HEADER}",
        f"# {len(verts)} vertices, {len(tris)} triangles, closed, wound outward (counter-clockwise seen from outside)",
    ]
    lines += [f"v {x:.{DECIMALS}f} {y:.{DECIMALS}f} {z:.{DECIMALS}f}" for x, y, z in verts]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in tris]
    return ("\n".join(lines) + "\n").encode("ascii")


def vtu_bytes(verts: np.ndarray, tets: np.ndarray, what: str) -> bytes:
    """A VTU (binary, uncompressed: no dependence on the zlib version) written by meshio.

    meshio's comment naming its own version is replaced by ours, so the bytes do not change
    with the meshio version.
    """
    import meshio

    mesh = meshio.Mesh(np.ascontiguousarray(verts, dtype=np.float64), [("tetra", np.ascontiguousarray(tets, dtype=np.int64))])
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "mesh.vtu")
        meshio.write(path, mesh, file_format="vtu", binary=True, compression=None)
        data = Path(path).read_bytes()
    start = data.find(b"<!--")
    end = data.find(b"-->", start)
    if start < 0 or end < 0:
        raise RuntimeError("meshio's VTU has no header comment to replace")
    comment = f"<!-- {what}; {HEADER} -->".encode("ascii")
    return data[:start] + comment + data[end + 3 :]


def build() -> tuple[dict[str, bytes], dict[str, dict]]:
    """({file name: bytes}, {file name: report}) of every generated mesh."""
    s_verts, s_tris, prof = make_stomach()
    l_verts, l_tets = make_liver()
    s_rep = surface_report(s_verts, s_tris)
    s_rep["max_radius_times_curvature"] = prof["max_r_kappa"]
    l_rep = volume_report(l_verts, l_tets)
    _require(s_rep["vertices"] == 1002 and s_rep["triangles"] == 2000, "stomach counts", s_rep)
    _require(s_rep["watertight"] and s_rep["winding_consistent"] and s_rep["euler"] == 2, "stomach closed genus 0", s_rep)
    _require(s_rep["volume_mm3"] > 0, "stomach wound outward", s_rep)
    _require(s_rep["min_angle_deg"] > 20.0, "stomach min angle > 20 deg", s_rep)
    _require(l_rep["min_volume_mm3"] > 0, "liver tets positively oriented", l_rep)
    _require(l_rep["watertight"] and l_rep["euler"] == 2, "liver boundary closed", l_rep)
    _require(abs(l_rep["surface_volume_mm3"] / l_rep["volume_mm3"] - 1) < 1e-9, "liver volumes agree", l_rep)
    files = {
        "stomach.obj": obj_bytes(s_verts, s_tris, "stomach: closed genus-0 surface (geodesic sphere, frequency 10, deformed)"),
        "liver.vtu": vtu_bytes(l_verts, l_tets, "liver: tetrahedral volume (14 x 10 x 5 grid, 5 tets per cell)"),
    }
    return files, {"stomach.obj": s_rep, "liver.vtu": l_rep}


def _require(ok: bool, what: str, report: dict) -> None:
    if not ok:
        raise RuntimeError(f"generated mesh fails check: {what}: {report}")


def write_atomic(path: Path, data: bytes) -> None:
    """Write to a temporary file next to `path`, then rename it over `path`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def format_report(name: str, rep: dict) -> str:
    bb = " x ".join(f"{s:.1f}" for s in rep["bbox_mm"])
    if "tets" in rep:
        return (
            f"{name}: {rep['vertices']} vertices, {rep['tets']} tets, {rep['edges']} edges, "
            f"{rep['surface_triangles']} surface triangles on {rep['surface_vertices']} vertices; "
            f"bbox {bb} mm; volume {rep['volume_mm3'] / 1e3:.1f} cm^3 (surface {rep['surface_volume_mm3'] / 1e3:.1f}); "
            f"tet volume min/max {rep['min_volume_mm3']:.1f}/{rep['max_volume_mm3']:.1f} mm^3 (ratio {rep['volume_ratio']:.3f}); "
            f"dihedral {rep['min_dihedral_deg']:.1f}-{rep['max_dihedral_deg']:.1f} deg; "
            f"min shape quality {rep['min_shape_quality']:.3f}; edges {rep['edge_min_mm']:.2f}-{rep['edge_max_mm']:.2f} mm; "
            f"watertight {rep['watertight']}, Euler {rep['euler']}"
        )
    return (
        f"{name}: {rep['vertices']} vertices, {rep['triangles']} triangles, {rep['edges']} edges; "
        f"bbox {bb} mm; area {rep['area_mm2'] / 1e2:.1f} cm^2, volume {rep['volume_mm3'] / 1e3:.1f} cm^3; "
        f"angles {rep['min_angle_deg']:.1f}-{rep['max_angle_deg']:.1f} deg; "
        f"edges {rep['edge_min_mm']:.2f}/{rep['edge_mean_mm']:.2f}/{rep['edge_max_mm']:.2f} mm min/mean/max "
        f"(ratio {rep['edge_ratio']:.2f}; 98% within {rep['edge_p1_mm']:.2f}-{rep['edge_p99_mm']:.2f}); max R*kappa {rep['max_radius_times_curvature']:.2f}; "
        f"watertight {rep['watertight']}, Euler {rep['euler']}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the files in the output folder differ")
    parser.add_argument("--out", type=Path, default=SCENES, help=f"output folder (default {SCENES})")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    args = parser.parse_args(argv)

    files, reports = build()
    if not args.quiet:
        for name in files:
            print(format_report(name, reports[name]))
    if args.check:
        stale = [name for name, data in files.items() if not (args.out / name).is_file() or (args.out / name).read_bytes() != data]
        for name in stale:
            print(f"{args.out / name}: out of date; run python scripts/make_scenes.py", file=sys.stderr)
        if not stale and not args.quiet:
            print(f"{', '.join(files)} in {args.out}: up to date")
        return 1 if stale else 0
    for name, data in files.items():
        write_atomic(args.out / name, data)
        if not args.quiet:
            print(f"wrote {args.out / name} ({len(data)} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
