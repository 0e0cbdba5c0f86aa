"""Fuzzing the mesh loaders (hypothesis): random corruptions of the project's scene meshes and of
the shared organ meshes (copied into a temporary folder), and random arrays. Every case ends in
a valid mesh or an InputError of one line that names the file; nothing else escapes."""

import tempfile
from pathlib import Path

import numpy as np
import pytest
from conftest import MESH_SUFFIXES, scene_mesh_paths, shared_mesh_paths
from fuzzing import corruptions, fuzz_settings, hang_guard, record
from helpers import load_or_record_error
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from almsdm_warp import load_mesh
from almsdm_warp.errors import InputError
from almsdm_warp.mesh.tissue_mesh import TissueMesh

SMALL_SHARED = {"gca_stomach_1002v.obj", "liver.msh", "mor_liverTinyMesh.vtu", "mor_liverVeryCOARSE.vtu", "sofa_liver_tets.vtu",
                "sofa_liver2_tets.vtu", "mor_liverCoarse.vtu", "liver2.msh"}
FILES = [p for p in scene_mesh_paths()] + [p for p in shared_mesh_paths() if p.name in SMALL_SHARED]
_bytes = {}
_converted = {}


def converted_files():
    """The scenes written in the formats no shipped file uses: STL, PLY, OFF (trimesh), an ASCII
    VTK POLYDATA (our own reader), Gmsh 2.2 and 4.1 and a legacy VTK grid (meshio); made once, in
    memory, as {name: bytes} (the mesh content is valid: corruption comes after)."""
    if _converted:
        return _converted
    import meshio
    import trimesh

    from conftest import SCENES

    stomach = load_mesh(SCENES / "stomach.obj")
    liver = load_mesh(SCENES / "liver.vtu")
    v, t = stomach.vertices_mm, stomach.triangles
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        surface = trimesh.Trimesh(v, t, process=False)
        for suffix in (".stl", ".ply", ".off"):
            surface.export(folder / f"stomach{suffix}")
        points = "\n".join(" ".join(f"{x:.6f}" for x in row) for row in v)
        cells = "\n".join("3 " + " ".join(str(i) for i in row) for row in t)
        (folder / "stomach_polydata.vtk").write_text(
            f"# vtk DataFile Version 3.0\nstomach\nASCII\nDATASET POLYDATA\nPOINTS {len(v)} float\n{points}\n"
            f"POLYGONS {len(t)} {4 * len(t)}\n{cells}\n")
        grid = meshio.Mesh(liver.vertices_mm, [("tetra", liver.tetrahedra)])
        meshio.write(folder / "liver_v22.msh", grid, file_format="gmsh22", binary=False)
        meshio.write(folder / "liver_v41.msh", grid, file_format="gmsh", binary=False)
        meshio.write(folder / "liver_grid.vtk", grid, file_format="vtk", binary=False)
        meshio.write(folder / "liver_grid_binary.vtk", grid, file_format="vtk", binary=True)
        cells = np.hstack([np.full((len(t), 1), 3), t]).astype(">i4")
        (folder / "stomach_polydata_binary.vtk").write_bytes(
            b"# vtk DataFile Version 3.0\nstomach\nBINARY\nDATASET POLYDATA\n" + f"POINTS {len(v)} double\n".encode()
            + np.asarray(v, ">f8").tobytes() + f"\nPOLYGONS {len(t)} {cells.size}\n".encode() + cells.tobytes() + b"\n")
        for path in folder.iterdir():
            _converted[path.name] = path.read_bytes()
    return _converted


def file_bytes(path):
    if path not in _bytes:
        _bytes[path] = Path(path).read_bytes()
    return _bytes[path]


def assert_usable(mesh: TissueMesh):
    """What the simulator relies on: finite metres, in-range indices, every vertex with mass,
    every spring with a length."""
    n = mesh.vertex_count
    assert n > 0 and mesh.triangle_count > 0
    assert np.all(np.isfinite(mesh.vertices))
    assert np.all(np.isfinite(mesh.vertices.astype(np.float32)))
    for elements in (mesh.triangles, mesh.tetrahedra):
        assert elements.size == 0 or (elements.min() >= 0 and elements.max() < n)
    assert np.all(mesh.vertex_masses(1000.0, 1e-3) > 0)
    assert np.all(mesh.edge_rest_length.astype(np.float32) > 0)


def load_or_error(path, test, case):
    """load_mesh(path): a usable mesh or a one-line InputError naming the file; the outcome."""
    mesh = load_or_record_error(load_mesh, path, test, case)
    if mesh is None:
        return "error"
    assert_usable(mesh)
    record(test, case, "ok", "; ".join(mesh.notes))
    return "ok"


@pytest.mark.skipif(not FILES, reason="no mesh files")
@fuzz_settings(60)
@given(data=st.data())
def test_corrupted_mesh_files(data):
    """The shipped scenes and small shared meshes (OBJ, VTU, Gmsh v1)."""
    path = data.draw(st.sampled_from(FILES), label="file")
    corrupt_and_load(data, path, file_bytes(path), ".msh v1" if path.suffix == ".msh" else None)


@fuzz_settings(40)
@given(data=st.data())
def test_corrupted_files_in_every_other_format(data):
    """The scenes converted to STL, PLY, OFF, VTK POLYDATA, Gmsh 2.2 / 4.1, legacy VTK grid."""
    files = converted_files()
    name = data.draw(st.sampled_from(sorted(files)), label="file")
    if name not in _loaded_ok:  # the file as written loads: what fails below is the corruption
        with tempfile.TemporaryDirectory() as tmp:
            target = Path(tmp) / name
            target.write_bytes(files[name])
            assert_usable(load_mesh(target))
        _loaded_ok.add(name)
    label = {"stomach_polydata.vtk": ".vtk POLYDATA", "liver_v22.msh": ".msh v2.2", "liver_v41.msh": ".msh v4.1",
             "liver_grid.vtk": ".vtk grid", "liver_grid_binary.vtk": ".vtk binary grid",
             "stomach_polydata_binary.vtk": ".vtk binary POLYDATA"}.get(name, Path(name).suffix)
    corrupt_and_load(data, Path(name), files[name], label)


_loaded_ok = set()


def corrupt_and_load(data, path, content, label=None):
    description, corrupted, suffix = data.draw(corruptions(content, MESH_SUFFIXES), label="corruption")
    with tempfile.TemporaryDirectory() as tmp:
        target = Path(tmp) / (path.stem + (suffix or path.suffix))
        target.write_bytes(corrupted)
        kind = description.split()[0] if not description[0].isdigit() else description.split()[1]
        load_or_error(target, "corrupted_file", f"{label or path.suffix} {kind}")


@fuzz_settings(80)
@given(
    vertices=hnp.arrays(np.float64, st.tuples(st.integers(0, 12), st.sampled_from([3, 3, 3, 2])),
                        elements=st.floats(allow_nan=True, allow_infinity=True, width=64) | st.floats(-10, 10)),
    elements=hnp.arrays(np.int64, st.tuples(st.integers(0, 16), st.sampled_from([3, 4])), elements=st.integers(-2, 14)),
    scale=st.sampled_from([1.0, 1e-3, 10.0, 1e-300, 1e300, float("nan"), 0.0, -1.0]),
)
def test_random_arrays(vertices, elements, scale):
    """TissueMesh.from_arrays on random vertices (NaN, inf, huge, wrong shape) and random
    triangles or tets (out of range, repeated, degenerate)."""
    tri, tet = (elements, None) if elements.shape[1] == 3 else (None, elements)
    try:
        mesh = TissueMesh.from_arrays(vertices, tri, tet, scale=scale)
    except InputError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("<arrays>"), str(exc)
        record("random_arrays", f"{elements.shape[1]}-cells", "error", str(exc)[len("<arrays>"):])
        return
    assert_usable(mesh)
    record("random_arrays", f"{elements.shape[1]}-cells", "ok", "; ".join(mesh.notes))


@fuzz_settings(60)
@given(
    jitter=hnp.arrays(np.float64, (12, 3), elements=st.sampled_from([0.0, 0.0, 1e-12, 1e-7, 1e-3, 0.5, 5.0, -5.0, 1e3])),
    edits=st.lists(st.tuples(st.integers(0, 19), st.integers(0, 2), st.integers(-1, 13)), max_size=3),
    extra=st.integers(0, 3),
    scale=st.sampled_from([1.0, 10.0, 1e-3, 1e3]),
)
def test_perturbed_icosahedron(jitter, edits, extra, scale):
    """A valid closed surface (an icosahedron, 10 mm) with its vertices moved (nothing, slivers,
    coincident points, folds), a few indices changed (repeated, out of range) and unreferenced
    vertices added: mostly meshes that must load usable, some that must fail clearly."""
    import trimesh

    ico = trimesh.creation.icosahedron()
    v = np.vstack([ico.vertices * 10.0 + jitter, np.full((extra, 3), 7.0)])
    f = np.array(ico.faces, dtype=np.int64)
    for face, corner, vertex in edits:
        f[face, corner] = vertex
    try:
        mesh = TissueMesh.from_arrays(v, f, scale=scale)
    except InputError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("<arrays>"), str(exc)
        record("perturbed_icosahedron", "edits" if edits else "moved only", "error", str(exc)[len("<arrays>"):])
        return
    assert_usable(mesh)
    if not edits and np.abs(jitter).max() < 1e-3:  # nothing but noise: all 12 vertices, 20 faces, outward
        assert (mesh.vertex_count, mesh.triangle_count) == (12, 20)
        assert trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False).volume > 0
    record("perturbed_icosahedron", "edits" if edits else "moved only", "ok", "; ".join(mesh.notes))


@fuzz_settings(30)
@given(
    points=hnp.arrays(np.float64, st.tuples(st.integers(4, 30), st.just(3)), elements=st.floats(-50, 50, width=32)),
    seed=st.integers(0, 2**16),
    suffix=st.sampled_from([".obj", ".stl", ".ply", ".off", ".vtu", ".vtk", ".msh"]),
)
def test_random_meshes_written_and_read(points, seed, suffix):
    """A random triangle soup or tet mesh written by trimesh / meshio in each format and read back:
    a usable mesh whose vertices are a subset of the points written, or a clear error."""
    import meshio
    import trimesh

    rng = np.random.default_rng(seed)
    n = len(points)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"random{suffix}"
        if suffix in (".vtu", ".vtk", ".msh"):
            cells = [("tetra", rng.integers(0, n, size=(rng.integers(1, 20), 4)))]
            meshio.write(path, meshio.Mesh(points, cells), **({"file_format": "gmsh22"} if suffix == ".msh" else {}))
        else:
            faces = rng.integers(0, n, size=(rng.integers(1, 30), 3))
            trimesh.Trimesh(points, faces, process=False).export(path)
        outcome = load_or_error(path, "random_mesh", suffix)
        if outcome == "ok":
            mesh = load_mesh(path)
            written = points.astype(np.float32).astype(np.float64) if suffix == ".stl" else points
            d = np.abs(mesh.vertices_mm[:, None, :] - written[None, :, :]).max(axis=2).min(axis=1)
            assert d.max() < 1e-4 * (1 + np.abs(points).max())


# -- regressions found by the fuzzing above ---------------------------------------------------
def tetra_surface(scale=1.0):
    v = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]], dtype=np.float64) * scale
    return v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def test_far_unreferenced_vertex_is_dropped_not_a_crash():
    """An unreferenced vertex at 1.3e154 made scipy's KD-tree overflow (a ValueError, not an
    InputError); it is now left out of the merge and dropped."""
    v, f = tetra_surface()
    mesh = TissueMesh.from_arrays(np.vstack([v, [1.34e154, 0, 0]]), f)
    assert mesh.vertex_count == 4 and any("unreferenced" in n for n in mesh.notes)
    np.testing.assert_allclose(mesh.vertices, v * 1e-3)


@pytest.mark.parametrize(
    "scale, coordinate, match",
    [
        (1.0, 1.34e154, "beyond the 1000 m"),  # used to overflow the KD-tree (ValueError)
        (1e-300, 1.34e154, "beyond"),  # inside +-1 km in metres, but its square overflows
        (1e300, 10.0, "beyond the 1000 m"),  # stomach x 1e300: ArpackError in critical_dt, LAPACK noise
        (1e-300, 10.0, "smaller than"),  # every spring 1e-302 m: zero in float32, no force
        (1.0, 2.0e6, "beyond the 1000 m"),  # 2 km: millimetre springs unresolved in float32
    ],
)
def test_mesh_outside_what_float32_resolves_is_an_input_error(scale, coordinate, match):
    v, f = tetra_surface()
    v[1, 0] = coordinate
    with pytest.raises(InputError, match=match) as info:
        TissueMesh.from_arrays(v, f, scale=scale, path="m.obj")
    assert str(info.value).startswith("m.obj: ") and "\n" not in str(info.value)


def test_spring_shorter_than_float32_resolves_is_an_input_error():
    """A 1 um edge on a 100 m mesh: float32 keeps ~1e-5 m there, so the spring's rest length
    would be noise; a 1e-6 mm edge anywhere is under the kernels' 1e-9 m collapsed-spring guard."""
    v, f = tetra_surface()
    v[1:] = [[0, 0, 1e-3], [1e5, 0, 0], [0, 1e5, 0]]
    with pytest.raises(InputError, match=r"edge between vertices 0 and 1 is 1e-06 m long .* float32"):
        TissueMesh.from_arrays(v, f, path="m.obj")
    v, f = tetra_surface()
    v[1] = v[0] + [0, 0, 1e-6]
    with pytest.raises(InputError, match=r"edge between vertices 0 and 1 is 1e-09 m long .* no direction"):
        TissueMesh.from_arrays(v, f, path="m.obj")


def test_broken_vtu_says_where_the_xml_breaks(tmp_path):
    """meshio raises a bare ReadError for any XML it cannot parse: the message was
    'cannot read as VTU: ReadError'. It now carries the XML parser's line and column."""
    from conftest import SCENES

    data = (SCENES / "liver.vtu").read_bytes()
    cut = tmp_path / "cut.vtu"
    cut.write_bytes(data[:5000])
    with pytest.raises(InputError, match=r"cut\.vtu: cannot read as VTU: broken XML: no element found: line \d+, column \d+$"):
        load_mesh(cut)
    junk = tmp_path / "junk.vtu"
    junk.write_bytes(data[:3000] + b"\x00<<" + data[3003:])
    with pytest.raises(InputError, match=r"junk\.vtu: cannot read as VTU: broken XML: not well-formed \(invalid token\): line"):
        load_mesh(junk)


@pytest.mark.parametrize(
    "suffix, cut, message",
    [
        (".off", "half_the_lines", r"the OFF header announces 1002 vertices and 2000 faces, but the file holds 1002 vertices and \d+ faces"),
        (".off", "delete_face", r"the OFF header announces 1002 vertices and 2000 faces, but the file holds 1002 vertices and 1999"),
        (".ply", "delete_face", r"the PLY header announces 1002 vertices and 2000 faces, but the file holds 1002 vertices and 1999"),
        (".stl", "truncate", r"truncated binary STL: its header announces 2000 triangles \(100084 bytes\), but the file has \d+ bytes"),
    ],
)
def test_truncated_counted_formats_are_errors_not_half_meshes(suffix, cut, message, tmp_path):
    """Found by fuzzing converted files: trimesh read a truncated OFF or ASCII PLY up to where it
    ended (an OFF cut at half its lines loaded as 285 vertices and 496 triangles, with only an
    'open surface' note) and a truncated binary STL as empty ('the mesh is empty'). The counts
    the header announces are now checked."""
    import trimesh

    from conftest import SCENES

    mesh = load_mesh(SCENES / "stomach.obj")
    path = tmp_path / f"stomach{suffix}"
    trimesh.Trimesh(mesh.vertices_mm, mesh.triangles, process=False).export(path, **({"encoding": "ascii"} if suffix == ".ply" else {}))
    data = path.read_bytes()
    assert_usable(load_mesh(path))  # as written, it loads
    if cut == "truncate":
        data = data[: len(data) // 2]
    elif cut == "half_the_lines":
        lines = data.split(b"\n")
        data = b"\n".join(lines[: len(lines) // 2]) + b"\n"
    else:  # the last face line (a face, in both formats)
        lines = data.rstrip(b"\n").split(b"\n")
        data = b"\n".join(lines[:-1]) + b"\n"
    path.write_bytes(data)
    with pytest.raises(InputError, match=message):
        load_mesh(path)


@pytest.mark.parametrize(
    "face, message",
    [
        ("f 1 2 0", r"line \d+: face 'f 1 2 0' references vertex 0, but OBJ indices start at 1"),  # was: silently the last vertex
        ("f 1/1 2/2 5000/3", r"references vertex 5000, but the file has 1002 vertices"),  # was: a bare IndexError
        ("f 1 2 -5000", r"references vertex -5000, but only 1002 vertices precede it"),
    ],
)
def test_obj_face_index_out_of_range_names_the_line(face, message, tmp_path):
    """Found by fuzzing: trimesh read an OBJ face index 0 as the last vertex (a wrong mesh, no
    error) and an index past the end as 'IndexError: index 4999 is out of bounds'."""
    from conftest import SCENES

    lines = (SCENES / "stomach.obj").read_text().split("\n")
    k = next(i for i, line in enumerate(lines) if line.startswith("f "))
    lines[k] = face
    path = tmp_path / "bad.obj"
    path.write_text("\n".join(lines))
    with pytest.raises(InputError, match=message):
        load_mesh(path)


@fuzz_settings(40)
@given(data=st.data())
def test_truncated_anywhere_bad_indices_and_boms(data):
    """Every converted format (binary VTK included) cut at a random byte, given a random BOM, or
    with one index replaced by a negative or out-of-range number: a usable mesh or one clear line;
    a cut file never loads fewer elements than the whole one without an error."""
    files = converted_files()
    name = data.draw(st.sampled_from(sorted(files)), label="file")
    content = files[name]
    kind = data.draw(st.sampled_from(["truncate", "bom", "index"]), label="kind")
    if kind == "truncate":
        content = content[: data.draw(st.integers(0, len(content) - 1), label="cut")]
    elif kind == "bom":
        content = data.draw(st.sampled_from([b"\xef\xbb\xbf", b"\xff\xfe", b"\xfe\xff"]), label="bom") + content
    else:
        content = _replace_an_index(data, name, content)
    with tempfile.TemporaryDirectory() as tmp:
        target = Path(tmp) / name
        target.write_bytes(content)
        outcome = load_or_error(target, "truncated_bom_index", f"{Path(name).suffix} {kind}")
        if outcome == "ok" and kind == "truncate":
            whole = Path(tmp) / ("whole_" + name)
            whole.write_bytes(files[name])
            full, cut = load_mesh(whole), load_mesh(target)
            assert (cut.triangle_count, cut.tet_count) == (full.triangle_count, full.tet_count)
        if kind == "bom" and content.startswith(b"\xef\xbb\xbf") and not name.endswith(".ply"):
            assert outcome == "ok" or name.endswith("binary.vtk"), name


def _replace_an_index(data, name, content):
    """One element index in the file replaced by -4, 0 or a number past the last vertex."""
    bad = data.draw(st.sampled_from([b"-4", b"-1", b"0", b"99999"]), label="index")
    lines = content.split(b"\n")
    markers = (b"f ", b"3 ") if not name.endswith(".msh") else (b"",)
    rows = [i for i, line in enumerate(lines) if line.startswith(markers) and len(line.split()) >= 4
            and all(w.isdigit() for w in line.split()[1:])]
    if not rows or name.endswith((".stl", "binary.vtk")):
        return content
    i = data.draw(st.sampled_from(rows), label="line")
    words = lines[i].split()
    words[-1] = bad
    lines[i] = b" ".join(words)
    return b"\n".join(lines)


@pytest.mark.skipif(not hasattr(__import__("os"), "mkfifo"), reason="no FIFOs here")
def test_special_files_for_every_suffix(tmp_path):
    """Each suffix linked to /dev/zero, /dev/urandom and a FIFO: refused at once, never read."""
    import os

    os.mkfifo(tmp_path / "pipe")
    targets = [t for t in ("/dev/zero", "/dev/urandom") if os.path.exists(t)] + [str(tmp_path / "pipe")]
    for suffix in sorted(MESH_SUFFIXES):
        for k, target in enumerate(targets):
            link = tmp_path / f"m{k}{suffix}"
            link.symlink_to(target)
            with hang_guard(10), pytest.raises(InputError, match=r"not a regular file"):
                load_mesh(link)
