"""Loading and validating meshes (almsdm_warp.mesh.io, almsdm_warp.mesh.validate): CPU only, no Warp kernels.

Every format is written here in tmp_path and read back; counts, coordinates (file mm -> m) and
the surface of a tet mesh are checked against independent answers (trimesh, closed forms).
"""

import itertools
import os

import meshio
import numpy as np
import pytest
import trimesh

from almsdm_warp.errors import InputError
from almsdm_warp.mesh.io import KNOWN_FORMATS, load_mesh
from almsdm_warp.mesh.tissue_mesh import TissueMesh

from conftest import SHARED_MESHES as MESHES  # noqa: E402

build_mesh = TissueMesh.from_arrays  # validate and repair raw arrays, as load_mesh does
EXTENT_MM = np.array([20.0, 30.0, 10.0])  # the test box
GRID = (2, 3, 1)  # cells per axis of the tetrahedralized box


def box_tets(grid=GRID, extent=EXTENT_MM):
    """A box cut into cubes, each cut into 6 tets (Kuhn), positively oriented by an independent det."""
    nx, ny, nz = grid
    ax = [np.linspace(0.0, e, k + 1) for e, k in zip(extent, grid)]
    vertices = np.stack(np.meshgrid(*ax, indexing="ij"), axis=-1).reshape(-1, 3)
    index = np.arange(len(vertices)).reshape(nx + 1, ny + 1, nz + 1)
    tets = []
    for i, j, k in itertools.product(range(nx), range(ny), range(nz)):
        for perm in itertools.permutations(range(3)):
            corner, path = np.array([i, j, k]), []
            path.append(index[tuple(corner)])
            for axis in perm:
                corner[axis] += 1
                path.append(index[tuple(corner)])
            tets.append(path)
    tets = np.array(tets)
    p = vertices[tets]
    det = np.linalg.det(np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=1))
    tets[det < 0] = tets[det < 0][:, [0, 1, 3, 2]]
    return vertices, tets


def tet_volumes(vertices, tets):
    p = vertices[tets]
    return np.linalg.det(np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=1)) / 6.0


def tet_set(vertices, tets, decimals=9):
    """Each tet as the set of its corners' coordinates: compares meshes numbered differently."""
    corners = np.round(vertices[tets], decimals)
    return {frozenset(map(tuple, c)) for c in corners}


def box_surface():
    box = trimesh.creation.box(extents=EXTENT_MM)
    return np.array(box.vertices), np.array(box.faces)


def sorted_rows(a):
    a = np.asarray(a)
    return a[np.lexsort(a.T[::-1])]


def check_surface_outward(mesh, volume_m3):
    """Watertight, wound consistently, enclosing `volume_m3` (signed, so outward) per trimesh."""
    t = trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False)
    assert t.is_watertight and t.is_winding_consistent
    np.testing.assert_allclose(t.volume, volume_m3, rtol=1e-12)
    centre = mesh.vertices.mean(axis=0)  # the box is convex: outward = away from the centre
    assert (np.einsum("ij,ij->i", t.face_normals, t.triangles_center - centre) > 0).all()


# -- every format --------------------------------------------------------------------------------
def write_gmsh_v1(path, vertices, tets):
    labels = 10 * np.arange(len(vertices)) + 7  # arbitrary labels, written in shuffled order
    order = np.random.default_rng(0).permutation(len(vertices))
    lines = ["$NOD", str(len(vertices))]
    lines += [f"{labels[i]} {x:.17g} {y:.17g} {z:.17g}" for i, (x, y, z) in zip(order, vertices[order])]
    lines += ["$ENDNOD", "$ELM", str(len(tets) + 2), f"1 1 1 1 2 {labels[0]} {labels[1]}",
              f"2 2 1 1 3 {labels[0]} {labels[1]} {labels[2]}"]
    lines += [f"{e + 3} 4 1 1 4 " + " ".join(str(labels[v]) for v in t) for e, t in enumerate(tets)]
    path.write_text("\n".join(lines + ["$ENDELM", ""]))


@pytest.mark.parametrize("fmt", ["vtu", "vtk", "gmsh22", "gmsh41", "gmsh_v1"])
def test_tet_formats(tmp_path, fmt):
    v, tets = box_tets()
    path = tmp_path / f"box.{ {'vtu': 'vtu', 'vtk': 'vtk'}.get(fmt, 'msh') }"
    if fmt == "gmsh_v1":
        write_gmsh_v1(path, v, tets)
    else:
        # meshio writes Gmsh 4.1 with one cell type only (several need entity data)
        cells = [("tetra", tets)] + ([] if fmt == "gmsh41" else [("triangle", tets[:2, :3])])
        kw = {"file_format": {"gmsh41": "gmsh"}.get(fmt, fmt), "binary": False}
        meshio.write(path, meshio.Mesh(v, cells), **kw)
    mesh = load_mesh(path)
    assert (mesh.vertex_count, mesh.tet_count) == (len(v), len(tets))
    # the same tets, by the coordinates of their corners (whatever the vertex numbering)
    assert tet_set(mesh.vertices * 1e3, mesh.tetrahedra) == tet_set(v, tets)
    if fmt != "gmsh41":
        count = "1 triangle:" if fmt == "gmsh_v1" else "2 triangles:"
        assert any(n.startswith("ignored the file's " + count) for n in mesh.notes)
    if fmt == "gmsh_v1":
        assert "ignored 1 line elements (Gmsh type 1)" in mesh.notes


def test_tet_surface_matches_independent_answer():
    v, tets = box_tets()
    mesh = build_mesh(v, tetrahedra=tets, path="box.vtu")
    nx, ny, nz = GRID
    assert mesh.triangle_count == 4 * (nx * ny + ny * nz + nx * nz)  # 2 triangles per cube face
    vol = np.prod(EXTENT_MM) * 1e-9
    np.testing.assert_allclose(tet_volumes(mesh.vertices, mesh.tetrahedra).sum(), vol, rtol=1e-12)
    assert (tet_volumes(mesh.vertices, mesh.tetrahedra) > 0).all()
    check_surface_outward(mesh, vol)
    assert mesh.notes == ()


@pytest.mark.parametrize("suffix", [".obj", ".stl", ".ply", ".off", ".OBJ"])
def test_surface_formats(tmp_path, suffix):
    v, f = box_surface()
    path = tmp_path / f"box{suffix}"
    trimesh.Trimesh(v, f, process=False).export(path, file_type=suffix[1:].lower())
    mesh = load_mesh(path, scale=10.0)  # a file in cm
    assert (mesh.vertex_count, mesh.triangle_count, mesh.tet_count) == (8, 12, 0)
    np.testing.assert_allclose(sorted_rows(mesh.vertices), sorted_rows(v * 1e-2), atol=1e-12)
    check_surface_outward(mesh, np.prod(EXTENT_MM) * 1e-6)
    if suffix == ".stl":  # STL repeats each corner per triangle
        assert any(n.startswith("merged 28 duplicate vertices") for n in mesh.notes)


def test_obj_with_several_objects_is_concatenated(tmp_path):
    tet = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
    faces = "f {a} {c} {b}\nf {a} {b} {d}\nf {a} {d} {c}\nf {b} {c} {d}\n"
    text = "o first\n" + tet + faces.format(a=1, b=2, c=3, d=4)
    text += "o second\nv 5 0 0\nv 6 0 0\nv 5 1 0\nv 5 0 1\n" + faces.format(a=5, b=6, c=7, d=8)
    (tmp_path / "two.obj").write_text(text)
    mesh = load_mesh(tmp_path / "two.obj")
    assert (mesh.vertex_count, mesh.triangle_count) == (8, 8)
    assert "2 connected components (vertices in each: 4, 4)" in mesh.notes


PYRAMID_PTS = "POINTS 5 float\n0 0 0 10 0 0 10 10 0\n0 10 0 5 5 6\n"


@pytest.mark.parametrize("cells", [
    "POLYGONS 5 21\n4 0 3 2 1\n3 0 1 4\n3 1 2 4\n3 2 3 4\n3 3 0 4\n",
    "METADATA\nINFORMATION 0\n\nPOLYGONS 6 16\nOFFSETS vtktypeint64\n0 4 7 10 13 16\n"
    "CONNECTIVITY vtktypeint64\n0 3 2 1 0 1 4 1 2 4 2 3 4 3 0 4\nCELL_DATA 5\n",
])
def test_vtk_polydata_pyramid(tmp_path, cells):
    path = tmp_path / "pyramid.vtk"
    path.write_text("# vtk DataFile Version 3.0\npyramid\nASCII\nDATASET POLYDATA\n" + PYRAMID_PTS + cells)
    mesh = load_mesh(path)
    assert (mesh.vertex_count, mesh.triangle_count) == (5, 6)  # the quad base becomes 2 triangles
    t = trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False)
    assert t.is_watertight
    np.testing.assert_allclose(t.volume, 10 * 10 * 6 / 3 * 1e-9, rtol=1e-12)  # base x height / 3, outward
    assert mesh.notes == ()


def test_vtk_polydata_triangle_strip_keeps_one_winding(tmp_path):
    path = tmp_path / "strip.vtk"
    path.write_text("# vtk DataFile Version 3.0\nstrip\nASCII\nDATASET POLYDATA\nPOINTS 5 float\n"
                    "0 0 0 0 1 0 1 0 0 1 1 0 2 0 0\nLINES 1 3\n2 0 1\nTRIANGLE_STRIPS 1 6\n5 0 1 2 3 4\n")
    mesh = load_mesh(path)
    assert mesh.triangle_count == 3
    t = trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False)
    assert (np.abs(t.face_normals[:, 2]) == 1).all() and len(set(t.face_normals[:, 2])) == 1
    assert "ignored 1 LINES cells" in mesh.notes
    assert "open surface: 5 boundary edges; winding kept as in the file" in mesh.notes


def test_meshio_line_cells_ignored_and_higher_order_rejected(tmp_path):
    v, tets = box_tets()
    meshio.write(tmp_path / "lines.vtu", meshio.Mesh(v, [("tetra", tets), ("line", tets[:3, :2])]))
    assert "ignored 3 line cells" in load_mesh(tmp_path / "lines.vtu").notes
    quad = meshio.Mesh(v, [("tetra", tets), ("hexahedron", np.arange(8)[None])])
    meshio.write(tmp_path / "hex.vtu", quad)
    with pytest.raises(InputError, match=r"hex\.vtu: unsupported cell type 'hexahedron' \(1 cells\)"):
        load_mesh(tmp_path / "hex.vtu")
    t10 = meshio.Mesh(np.zeros((10, 3)), [("tetra10", np.arange(10)[None])])
    meshio.write(tmp_path / "t10.vtu", t10)
    with pytest.raises(InputError, match=r"t10\.vtu: unsupported cell type 'tetra10'"):
        load_mesh(tmp_path / "t10.vtu")


def test_known_formats_lists_every_suffix():
    assert set(KNOWN_FORMATS) == {".obj", ".stl", ".ply", ".off", ".vtu", ".vtk", ".msh"}


# -- repairs, each reported in notes ------------------------------------------------------------
def note(mesh, start):
    hits = [n for n in mesh.notes if n.startswith(start)]
    assert hits, f"no note starting {start!r} in {mesh.notes}"
    return hits[0]


def test_duplicate_vertices_merged():
    v, f = box_surface()
    v2 = np.vstack([v, v[0] + 1e-12, v[3]])  # 8: within 1e-9 x diag of vertex 0; 9: exactly vertex 3
    f2 = f.copy()
    f2[f2 == 0] = np.where(np.arange((f2 == 0).sum()) % 2, 8, 0)
    f2[f2 == 3] = 9
    mesh = build_mesh(v2, f2, path="dup.obj")
    assert "merged 2 duplicate vertices (first: vertex 8 onto vertex 0" in note(mesh, "merged")
    assert mesh.vertex_count == 8
    np.testing.assert_allclose(mesh.vertices, v * 1e-3)
    check_surface_outward(mesh, np.prod(EXTENT_MM) * 1e-9)


def _pairs_within(points, reach):
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
    return int(np.triu(d <= reach, 1).sum())


@pytest.mark.parametrize("seed", range(6))
def test_the_duplicate_pre_check_never_misses_a_pair(seed):
    """The merge's pre-check (one grid sort before any k-d tree) against brute-force distances: pairs
    planted across its cells' faces, on them and inside a cell are each found; clouds without one pass."""
    from almsdm_warp.mesh.validate import MERGE_CELL, _may_have_duplicates

    rng = np.random.default_rng(seed)
    reach = 1e-6
    cell = MERGE_CELL * reach
    across = 0  # the planted pairs that lie in two cells
    for trial in range(40):
        points = rng.uniform(0.0, 50 * cell, (60, 3))
        points[0] = 0.0  # the grid's origin: its faces at whole cells
        if trial % 4:  # plant a pair: across a face (in 1-3 axes), on one, or inside a cell
            a = rng.uniform(cell, 49 * cell, 3)
            axes = rng.random(3) < 0.5
            a[axes] = np.round(a[axes] / cell) * cell + rng.choice([-1, 0, 1]) * rng.uniform(0, 0.5) * reach
            offset = rng.normal(size=3)
            b = a + offset / np.linalg.norm(offset) * reach * rng.uniform(0.0, 0.999)
            if trial % 4 == 1 and axes.any():  # across the faces of those axes, 0.87 x reach apart at most
                a[axes] = np.round(a[axes] / cell) * cell - 0.25 * reach
                b = a + np.where(axes, 0.5, rng.uniform(-0.5, 0.5, 3)) * reach
            points = np.vstack([points, a, b])
        truth = _pairs_within(points, reach)
        assert _may_have_duplicates(points, reach) or truth == 0, (seed, trial)
        across += truth > 0 and len(np.unique(np.floor(points / cell), axis=0)) == len(points)
    assert across >= 5
    lattice = np.stack(np.meshgrid(*[np.arange(4) * 3.3 * cell + 0.5 * cell] * 3), -1).reshape(-1, 3)
    assert _pairs_within(lattice, reach) == 0 and not _may_have_duplicates(lattice, reach)


def test_a_mesh_without_duplicates_loads_without_the_kd_tree():
    """The stomach's OBJ, with no two vertices within the merge distance, is read without importing
    scipy.spatial (0.4-0.7 s of a sweep's start-up); a subprocess, so that nothing imported before counts."""
    code = ("import sys; from almsdm_warp.mesh.io import load_mesh; m = load_mesh(sys.argv[1]); "
            "print(m.vertex_count, 'scipy.spatial' in sys.modules)")
    from pathlib import Path
    import subprocess
    import sys

    obj = Path(__file__).resolve().parent.parent / "scenes" / "stomach.obj"
    out = subprocess.run([sys.executable, "-c", code, str(obj)], capture_output=True, text=True, check=True).stdout.split()
    assert out[1] == "False" and int(out[0]) > 1000


def test_degenerate_and_duplicate_triangles_dropped():
    v, f = box_surface()
    v2 = np.vstack([v, (v[0] + v[1]) / 2])  # 8: midpoint of an edge, used only by a flat triangle
    extra = [[0, 0, 1], [0, 1, 8], f[3], f[3][::-1]]
    mesh = build_mesh(v2, np.vstack([f, extra]), path="bad.obj")
    assert note(mesh, "dropped 2 degenerate triangles").startswith(
        "dropped 2 degenerate triangles (first: triangle 12, vertices (0, 0, 1), area")
    assert note(mesh, "dropped 2 duplicate") == "dropped 2 duplicate triangles (first: triangle 14, same vertices as triangle 3)"
    assert note(mesh, "dropped 1 unreferenced") == "dropped 1 unreferenced vertex (first: vertex 8)"
    assert (mesh.vertex_count, mesh.triangle_count) == (8, 12)
    check_surface_outward(mesh, np.prod(EXTENT_MM) * 1e-9)


def test_zero_volume_duplicate_and_inverted_tets_repaired():
    v, tets = box_tets()
    flat = [0, 4, 8, 12]  # four vertices of the z=0 face: coplanar
    t2 = tets.copy()
    t2[[1, 5]] = t2[[1, 5]][:, [1, 0, 2, 3]]  # inverted
    t2 = np.vstack([t2, [flat, [0, 0, 1, 2], tets[7][::-1]]])
    mesh = build_mesh(v, tetrahedra=t2, path="bad.vtu")
    n = len(tets)
    assert note(mesh, "dropped 2 zero-volume").startswith(f"dropped 2 zero-volume tetrahedra (first: tetrahedron {n}, ")
    assert note(mesh, "dropped 1 duplicate") == f"dropped 1 duplicate tetrahedron (first: tetrahedron {n + 2}, same vertices as tetrahedron 7)"
    assert note(mesh, "reoriented").startswith(f"reoriented 2 of {n} inverted tetrahedra by swapping two corners (first: tetrahedron 1,")
    assert mesh.tet_count == n and (tet_volumes(mesh.vertices, mesh.tetrahedra) > 0).all()
    check_surface_outward(mesh, np.prod(EXTENT_MM) * 1e-9)


def test_closed_surface_winding_made_outward():
    v, f = box_surface()
    some = f.copy()
    some[[2, 5]] = some[[2, 5], ::-1]
    mesh = build_mesh(v, some, path="s.obj")
    assert note(mesh, "flipped").startswith("flipped 2 of 12 triangles")
    check_surface_outward(mesh, np.prod(EXTENT_MM) * 1e-9)
    mesh = build_mesh(v, f[:, ::-1], path="s.obj")
    assert "reversed the winding of all 12 triangles: the closed surface was wound inward" in mesh.notes
    check_surface_outward(mesh, np.prod(EXTENT_MM) * 1e-9)


def test_open_surface_keeps_winding():
    v, f = box_surface()
    f2 = f[:11][:, ::-1].copy()  # inward, one triangle missing: not to be "fixed"
    mesh = build_mesh(v, f2, path="open.obj")
    assert "open surface: 3 boundary edges; winding kept as in the file" in mesh.notes
    np.testing.assert_array_equal(mesh.triangles, f2)


def test_unreferenced_vertex_dropped_and_indices_remapped():
    v, f = box_surface()
    v2 = np.vstack([[1e6, 1e6, 1e6], v])  # vertex 0 far away, used by nothing
    mesh = build_mesh(v2, f + 1, path="u.obj", scale=2.0)
    assert "dropped 1 unreferenced vertex (first: vertex 0)" in mesh.notes
    np.testing.assert_allclose(mesh.vertices, v * 2e-3)
    np.testing.assert_array_equal(mesh.triangles, f)


def test_non_manifold_edge_and_components_reported():
    v = np.array([[0, 0, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [5, 5, 5], [6, 5, 5], [5, 6, 5]], float)
    tri = [[0, 1, 2], [0, 1, 3], [1, 0, 4], [5, 6, 7]]  # three triangles on edge 0-1; one apart
    mesh = build_mesh(v, tri, path="nm.obj")
    assert note(mesh, "1 non-manifold") == ("1 non-manifold edge (shared by more than 2 triangles; "
                                            "first: edge between vertices 0 and 1, 3 triangles)")
    assert "2 connected components (vertices in each: 5, 3)" in mesh.notes
    assert mesh.triangle_count == 4


def test_tet_mesh_ignores_file_triangles():
    v, tets = box_tets()
    mesh = build_mesh(v, [[0, 1, 2]], tets, path="t.vtu")
    assert "ignored the file's 1 triangle: the surface is recomputed from the tetrahedra" in mesh.notes
    assert mesh.triangle_count == 4 * (6 + 3 + 2)


# -- bad input: one InputError, one line, naming file, element and value -------------------------
def bad(match, *args, **kw):
    kw.setdefault("path", "bad.vtu")
    with pytest.raises(InputError, match=match) as info:
        build_mesh(*args, **kw)
    assert "\n" not in str(info.value)


def test_bad_arrays():
    v, f = box_surface()
    _, tets = box_tets()
    bad(r"bad\.vtu: the mesh is empty \(0 vertices", np.zeros((0, 3)), f)
    bad(r"bad\.vtu: the mesh is empty \(8 vertices, 0 triangles, 0 tetrahedra\)", v)
    bad(r"bad\.vtu: vertices must have shape \(n, 3\), got \(8, 2\)", v[:, :2], f)
    bad(r"bad\.vtu: triangles must have shape \(m, 3\), got \(12, 4\)", v, np.hstack([f, f[:, :1]]))
    bad(r"bad\.vtu: triangle 0 has a non-integer vertex index 0\.5", v, np.vstack([[0.5, 1, 2], f]).astype(float))
    bad(r"bad\.vtu: triangles must hold integer vertex indices, got dtype <U1", v, [["a", "b", "c"]])
    bad(r"vertex coordinates must be numbers", [["x", "y", "z"]], f)
    v2 = v.copy()
    v2[5, 1] = np.nan
    bad(r"bad\.vtu: vertex 5 has a non-finite coordinate \(10\.0, nan, 5\.0\)", v2, f)
    v2[5, 1] = -np.inf
    bad(r"bad\.vtu: vertex 5 has a non-finite coordinate \(10\.0, -inf, 5\.0\)", v2, f)
    f2 = f.copy()
    f2[7, 2] = 8
    bad(r"bad\.vtu: triangle 7 references vertex 8, but the mesh has 8 vertices \(0\.\.7\)$", v, f2)
    f2[9, 0] = -1
    bad(r"triangle 7 references vertex 8, .* \(1 more triangles out of range\)", v, f2)
    vt, _ = box_tets()
    t2 = tets.copy()
    t2[3, 1] = 100
    bad(rf"bad\.vtu: tetrahedron 3 references vertex 100, but the mesh has {len(vt)} vertices \(0\.\.{len(vt) - 1}\)", vt, None, t2)
    bad(r"bad\.vtu: no triangles left: all 2 are degenerate", v, [[0, 0, 1], [2, 3, 3]])
    bad(r"bad\.vtu: no tetrahedra left: all 1 are degenerate", vt, None, [[0, 4, 8, 12]])


@pytest.mark.parametrize("scale", [0.0, -1.0, float("nan"), float("inf"), "10", True])
def test_bad_scale(scale):
    v, f = box_surface()
    bad(r"bad\.vtu: scale must be a positive", v, f, scale=scale)


def test_file_errors(tmp_path):
    with pytest.raises(InputError, match=r"nothere\.obj: no such file$"):
        load_mesh(tmp_path / "nothere.obj")
    (tmp_path / "dir.obj").mkdir()
    with pytest.raises(InputError, match=r"dir\.obj: is a directory"):
        load_mesh(tmp_path / "dir.obj")
    (tmp_path / "mesh.xyz").write_text("1 2 3\n")
    with pytest.raises(InputError, match=r"mesh\.xyz: unknown mesh format '\.xyz'; known: \.obj, \.stl, .*\.msh"):
        load_mesh(tmp_path / "mesh.xyz")
    (tmp_path / "empty.stl").write_bytes(b"")
    with pytest.raises(InputError, match=r"empty\.stl: empty file \(0 bytes\)"):
        load_mesh(tmp_path / "empty.stl")
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\n")
    with pytest.raises(InputError, match=r"points\.obj: the mesh is empty \(\d+ vertices, 0 triangles, 0 tetrahedra\)"):
        load_mesh(tmp_path / "points.obj")


def test_unreadable_file(tmp_path, monkeypatch):
    path = tmp_path / "locked.obj"
    path.write_text("v 0 0 0\n")
    path.chmod(0)
    if os.access(path, os.R_OK):  # root reads it anyway: make opening it refuse, as the OS would
        real_open = os.open

        def refuse(name, *args, **kwargs):
            if os.fspath(name) == os.fspath(path):
                raise PermissionError(13, "Permission denied", str(path))
            return real_open(name, *args, **kwargs)

        monkeypatch.setattr(os, "open", refuse)
    with pytest.raises(InputError, match=r"locked\.obj: permission denied"):
        load_mesh(path)


@pytest.mark.parametrize("name, text, match", [
    ("g.ply", "ply\nformat ascii 1.0\nelement vertex 3\n", r"g\.ply: cannot read as PLY: "),
    ("g.off", "OFF\n3 1 0\n0 0 0\n", r"g\.off: cannot read as OFF: "),
    ("g.vtu", "<VTKFile type='UnstructuredGrid'><oops", r"g\.vtu: cannot read as VTU: "),
    ("g.vtk", "# vtk DataFile Version 4.2\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n0 0 0\n",
     r"g\.vtk: truncated VTK file: POINTS \(line 5\) announces 12 numbers, but the file ends at line 6"),
    ("g.msh", "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0\n", r"g\.msh: cannot read as Gmsh: "),
    ("b.vtk", "# vtk DataFile Version 3.0\nx\nBINARY\nDATASET POLYDATA\nPOINTS 3 float\n",
     r"b\.vtk: truncated VTK file: POINTS \(line 5\) announces 9 values \(36 bytes\), but the file ends 0 bytes later"),
    ("t.vtk", "# vtk DataFile Version 3.0\nx\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n0 0 0 1 0 0\n",
     r"t\.vtk: truncated VTK file: POINTS \(line 5\) announces 9 numbers, but the file ends at line 6"),
    ("r.vtk", "# vtk DataFile Version 3.0\nx\nASCII\nDATASET POLYDATA\n" + PYRAMID_PTS +
     "POLYGONS 2 8\n3 0 1 2\n3 0 2 9\n", r"r\.vtk: line 8: POLYGONS cell 1 references point 9, but POINTS has 5 points \(0\.\.4\)"),
    ("n.vtk", "# vtk DataFile Version 3.0\nx\nASCII\nDATASET POLYDATA\nPOINTS 1 float\n0 zero 0\n",
     r"n\.vtk: line 6: expected a number in POINTS, got 'zero'"),
])
def test_garbled_files(tmp_path, name, text, match):
    (tmp_path / name).write_text(text)
    with pytest.raises(InputError, match=match) as info:
        load_mesh(tmp_path / name)
    assert "\n" not in str(info.value)


V1_NODES = "$NOD\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$ENDNOD\n"


@pytest.mark.parametrize("text, match", [
    (V1_NODES[:25], r"truncated Gmsh v1 file: \$NOD announced 4 nodes, but the file ends at line 5"),
    ("$NOD\n4\n1 0 0 0\n2 1 0 0\n$ENDNOD\n", r"line 5: \$NOD announced 4 nodes, but only 2 precede \$ENDNOD"),
    ("$NOD\nfour\n", r"line 2: expected the node count after \$NOD, got 'four'"),
    ("$NOD\n2\n1 0 0 0\n2 1 x 0\n$ENDNOD\n", r"line 4: expected node coordinates \(float64\), got '1 x 0'"),
    ("$NOD\n2\n1 0 0 0\n1 1 0 0\n$ENDNOD\n", r"line 4: node id 1 is defined twice"),
    (V1_NODES + "$ELM\n1\n1 4 1 1 4 1 2 3 99\n$ENDELM\n", r"line 10: element 1 references node 99, which \$NOD does not define"),
    (V1_NODES + "$ELM\n1\n1 4 1 1 3 1 2 3\n$ENDELM\n", r"line 10: element 1 is a tetrahedron \(type 4\) with 3 nodes, expected 4"),
    (V1_NODES + "$ELM\n1\n1 4 1 1 4 1 2 3\n$ENDELM\n", r"line 10: element 1 says 4 nodes but lists 3"),
    (V1_NODES + "$ELM\n2\n1 4 1 1 4 1 2 3 4\n2 3 1 1 4 1 2 3 4\n$ENDELM\n",
     r"line 11: element 2 has type 3 \(quadrangle; 1 such elements\), which is not supported"),
    (V1_NODES + "$ELM\n1\n1 4 1 1 4 1 2 3 4\n", r"truncated Gmsh v1 file: ended at line 10, expected \$ENDELM"),
])
def test_gmsh_v1_errors_name_the_line(tmp_path, text, match):
    (tmp_path / "v1.msh").write_text(text)
    with pytest.raises(InputError, match=r"v1\.msh: " + match) as info:
        load_mesh(tmp_path / "v1.msh")
    assert "\n" not in str(info.value)


# -- the shared organ meshes -------------------------------------------------------------------
# (vertices, surface triangles or None, tets) from ../shared/meshes/README.md
README_COUNTS = {
    "gca_stomach_1002v.obj": (1002, 2000, 0), "gca_stomach_5587v.obj": (5587, 11170, 0),
    "liver-smooth.obj": (2194, 4384, 0), "liver.msh": (181, None, 596), "liver2.msh": (507, None, 1493),
    "sofa_liver_tets.vtu": (181, None, 596), "sofa_liver2_tets.vtu": (507, None, 1493),
    "mor_liverTinyMesh.vtu": (42, None, 86), "mor_liverVeryCOARSE.vtu": (80, None, 225),
    "mor_liverCoarse.vtu": (357, None, 1369), "mor_liverSemiFine.vtu": (1375, None, 6444),
    "mor_liverFine.vtu": (4293, None, 22019),
}


def shared(name):
    if not MESHES.is_dir():
        pytest.skip(f"no shared meshes at {MESHES}")
    return MESHES / name


@pytest.mark.parametrize("name", sorted(README_COUNTS))
def test_shared_mesh_counts(name):
    mesh = load_mesh(shared(name))
    vertices, triangles, tets = README_COUNTS[name]
    assert (mesh.vertex_count, mesh.tet_count) == (vertices, tets)
    if triangles is not None:
        assert mesh.triangle_count == triangles
    t = trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False)
    assert t.is_watertight and t.is_winding_consistent and t.volume > 0
    if tets:
        np.testing.assert_allclose(t.volume, tet_volumes(mesh.vertices, mesh.tetrahedra).sum(), rtol=1e-9)


def test_every_shared_mesh_loads_and_is_listed():
    folder = shared("")
    files = sorted(p.name for p in folder.iterdir() if p.suffix.lower() in KNOWN_FORMATS)
    assert set(README_COUNTS) <= set(files)
    for name in set(files) - set(README_COUNTS):  # a mesh added later: it must load at least
        assert load_mesh(folder / name).vertex_count > 0


def test_liver2_gmsh_v1_equals_its_vtu_conversion():
    a, b = load_mesh(shared("liver2.msh")), load_mesh(shared("sofa_liver2_tets.vtu"))
    assert (a.vertex_count, a.tet_count) == (b.vertex_count, b.tet_count) == (507, 1493)
    np.testing.assert_allclose(sorted_rows(a.vertices), sorted_rows(b.vertices), rtol=1e-6)
    assert tet_set(a.vertices * 1e3, a.tetrahedra, 5) == tet_set(b.vertices * 1e3, b.tetrahedra, 5)


# -- readers that trust nothing: declared imports, strict counts, binary VTK, BOMs, special files --
def test_two_bodies_oriented_without_networkx(monkeypatch):
    """Two closed boxes, one wound inward and one with random triangles reversed: each body ends
    consistent and outward (scipy only: importing networkx fails here)."""
    monkeypatch.setitem(__import__("sys").modules, "networkx", None)
    v, f = box_surface()
    rng = np.random.default_rng(3)
    other = f.copy()
    flip = rng.random(len(f)) < 0.5
    other[flip] = other[flip][:, ::-1]
    mesh = build_mesh(np.vstack([v, v + [100.0, 0, 0]]), np.vstack([f[:, ::-1], other + len(v)]), path="two.obj")
    t = trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False)
    assert t.is_winding_consistent
    for body in t.split(only_watertight=True):
        np.testing.assert_allclose(body.volume, np.prod(EXTENT_MM) * 1e-9, rtol=1e-12)


def stomach_surface():
    from conftest import SCENES

    return load_mesh(SCENES / "stomach.obj")


def write_binary_vtk_polydata(path, v, tri, strips=None):
    """Big-endian binary POLYDATA as VTK writes it: POINTS float, POLYGONS and TRIANGLE_STRIPS int."""
    parts = [b"# vtk DataFile Version 3.0\nslicer\nBINARY\nDATASET POLYDATA\n",
             f"POINTS {len(v)} float\n".encode(), np.asarray(v, ">f4").tobytes(), b"\n"]
    cells = np.hstack([np.full((len(tri), 1), 3), tri]).astype(">i4")
    parts += [f"POLYGONS {len(tri)} {cells.size}\n".encode(), cells.tobytes(), b"\n"]
    if strips is not None:
        flat = np.concatenate([[len(s), *s] for s in strips]).astype(">i4")
        parts += [f"TRIANGLE_STRIPS {len(strips)} {flat.size}\n".encode(), flat.tobytes(), b"\n"]
    parts.append(b"POINT_DATA 3\nNORMALS Normals float\n")
    path.write_bytes(b"".join(parts))


def test_binary_vtk_polydata_reads_like_the_obj(tmp_path):
    """3D Slicer's usual output (binary POLYDATA) used to fail with a UnicodeDecodeError."""
    stomach = stomach_surface()
    v32 = stomach.vertices_mm.astype(np.float32)
    write_binary_vtk_polydata(tmp_path / "s.vtk", v32, stomach.triangles)
    mesh = load_mesh(tmp_path / "s.vtk")
    np.testing.assert_array_equal(mesh.triangles, stomach.triangles)
    np.testing.assert_allclose(mesh.vertices, v32.astype(np.float64) * 1e-3)


def test_binary_vtk_triangle_strips_and_grid(tmp_path):
    v = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0], [2, 0, 0]], float)
    write_binary_vtk_polydata(tmp_path / "strip.vtk", v, np.zeros((0, 3), int), strips=[[0, 1, 2, 3, 4]])
    mesh = load_mesh(tmp_path / "strip.vtk")
    np.testing.assert_array_equal(mesh.triangles, [[0, 1, 2], [2, 1, 3], [2, 3, 4]])  # alternating winding
    vt, tets = box_tets()
    meshio.write(tmp_path / "grid.vtk", meshio.Mesh(vt, [("tetra", tets)]), binary=True)
    assert tet_set(load_mesh(tmp_path / "grid.vtk").vertices_mm, load_mesh(tmp_path / "grid.vtk").tetrahedra) == \
        tet_set(vt, tets)


def test_vtk_grid_cut_inside_cell_types_is_an_error(tmp_path):
    """meshio loaded the tets whose types it had read and dropped the rest, with no error."""
    vt, tets = box_tets()
    meshio.write(tmp_path / "grid.vtk", meshio.Mesh(vt, [("tetra", tets)]), binary=False)
    text = (tmp_path / "grid.vtk").read_text()
    cut = text.index("CELL_TYPES") + len(f"CELL_TYPES {len(tets)}\n") + 2 * (len(tets) // 2)
    (tmp_path / "cut.vtk").write_text(text[:cut])
    with pytest.raises(InputError, match=rf"cut\.vtk: truncated VTK file: CELL_TYPES \(line \d+\) announces {len(tets)} "
                                         r"numbers, but the file ends at line \d+$"):
        load_mesh(tmp_path / "cut.vtk")


@pytest.mark.parametrize("bad", ["-4", "0", "99"])
@pytest.mark.parametrize("fmt", ["gmsh22", "gmsh"])  # 2.2 and 4.1
def test_gmsh_node_tag_not_defined_is_an_error(tmp_path, fmt, bad):
    """A node tag of -4 in an element became index -5 in meshio: another vertex, no error."""
    vt, tets = box_tets()
    meshio.write(tmp_path / "box.msh", meshio.Mesh(vt, [("tetra", tets)]), file_format=fmt, binary=False)
    lines = (tmp_path / "box.msh").read_text().split("\n")
    k = lines.index("$EndElements") - 1  # the last element: its last node tag
    lines[k] = " ".join(lines[k].split()[:-1] + [bad])
    (tmp_path / "bad.msh").write_text("\n".join(lines))
    with pytest.raises(InputError, match=rf"bad\.msh: line {k + 1}: element \d+ references node {bad}, which \$Nodes does not define"):
        load_mesh(tmp_path / "bad.msh")


@pytest.mark.parametrize("suffix", [".obj", ".off", ".ply", ".msh", ".vtk", ".stl"])
def test_byte_order_mark_accepted(tmp_path, suffix):
    """An OBJ saved with a UTF-8 BOM (Windows editors) was rejected; every text format accepts one."""
    stomach = stomach_surface()
    plain = tmp_path / f"plain{suffix}"
    if suffix == ".msh":
        vt, tets = box_tets()
        write_gmsh_v1(plain, vt, tets)
    elif suffix == ".vtk":
        v, t = stomach.vertices_mm, stomach.triangles
        plain.write_text("# vtk DataFile Version 3.0\ns\nASCII\nDATASET POLYDATA\n"
                         f"POINTS {len(v)} double\n" + "\n".join(" ".join(f"{x:.17g}" for x in r) for r in v) +
                         f"\nPOLYGONS {len(t)} {4 * len(t)}\n" + "\n".join("3 " + " ".join(map(str, r)) for r in t) + "\n")
    else:
        trimesh.Trimesh(stomach.vertices_mm, stomach.triangles, process=False).export(
            plain, **({"file_type": "stl_ascii"} if suffix == ".stl" else {"encoding": "ascii"} if suffix == ".ply" else {}))
    bom = tmp_path / f"bom{suffix}"
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = load_mesh(plain), load_mesh(bom)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.triangles, b.triangles)
    np.testing.assert_array_equal(a.tetrahedra, b.tetrahedra)
    if suffix == ".obj":  # UTF-16 with its BOM too
        utf16 = tmp_path / "utf16.obj"
        utf16.write_bytes(b"\xff\xfe" + plain.read_bytes().decode("ascii").encode("utf-16-le"))
        np.testing.assert_array_equal(load_mesh(utf16).triangles, a.triangles)


def test_ascii_stl_with_latin1_name_and_truncated_stl(tmp_path):
    """trimesh needed charset_normalizer (not a dependency) for an ASCII STL that is not UTF-8."""
    stomach = stomach_surface()
    path = tmp_path / "s.stl"
    trimesh.Trimesh(stomach.vertices_mm, stomach.triangles, process=False).export(path, file_type="stl_ascii")
    data = path.read_bytes().replace(b"solid", "solid estómago".encode("latin-1"), 1)
    path.write_bytes(data)
    assert load_mesh(path).triangle_count == stomach.triangle_count
    cut = data[: data.rindex(b"endfacet")]
    path.write_bytes(cut)
    with pytest.raises(InputError, match=r"s\.stl: truncated ASCII STL: it does not end with 'endsolid'"):
        load_mesh(path)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
@pytest.mark.parametrize("special", ["/dev/zero", "/dev/urandom", "fifo"])
def test_special_files_refused_before_reading(tmp_path, special):
    """A mesh path linked to an endless stream grew memory without bound (and a FIFO blocked)."""
    if special == "fifo":
        os.mkfifo(tmp_path / "pipe")
        target, kind = tmp_path / "pipe", "FIFO"
    else:
        if not os.path.exists(special):
            pytest.skip(f"no {special}")
        target, kind = special, "character device"
    link = tmp_path / "mesh.obj"
    link.symlink_to(target)
    with pytest.raises(InputError, match=rf"mesh\.obj: is a {kind}.*not a regular file"):
        load_mesh(link)


def test_file_over_the_size_limit_refused(tmp_path, monkeypatch):
    import almsdm_warp.mesh.io as mesh_io

    path = tmp_path / "big.obj"
    path.write_bytes(b"v 0 0 0\n" * 200)
    monkeypatch.setattr(mesh_io, "MAX_FILE_BYTES", 1000)
    with pytest.raises(InputError, match=r"big\.obj: the file has 1600 bytes, more than the 1000 bytes"):
        load_mesh(path)
