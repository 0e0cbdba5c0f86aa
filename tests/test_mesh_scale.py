"""Work that grows with the points pressed, not with the mesh: CSR rows, the springs' matrices of a few
vertices, the critical step of disjoint pieces, a batch's substeps certified by a piece, sphere patches
from a k-d tree; each against a brute-force answer."""

import math

import numpy as np
import pytest
from helpers import spring_stiffness_matrix

from almsdm_warp.checks import substeps_for
from almsdm_warp.mesh.primitives import icosphere
from almsdm_warp.mesh.topology import csr_entries
from almsdm_warp.sim.model import Model
from almsdm_warp.tissue.laws import springs_matrices
from almsdm_warp.tissue.material import Material

MATERIAL = Material(youngs_modulus=5e3, thickness=0.003, foundation=1e6, damping_ratio=0.5)


@pytest.fixture(scope="module")
def model():
    """A material on a 642-vertex icosphere of radius 40 mm, on the CPU."""
    return Model(icosphere(40.0, 3), MATERIAL, "cpu")


def test_csr_entries_are_the_rows_positions(model):
    offsets = model.mesh.adjacency[0]
    rows = np.array([5, 0, 641, 5, 17])
    expected = np.concatenate([np.arange(offsets[r], offsets[r + 1]) for r in rows])
    np.testing.assert_array_equal(csr_entries(offsets, rows), expected)
    assert len(csr_entries(offsets, np.zeros(0, dtype=np.int64))) == 0


@pytest.mark.parametrize("anchors", [True, False])
def test_springs_matrices_whole_and_of_some_vertices(model, anchors):
    mesh = model.mesh
    length = mesh.edge_rest_length
    scale = 1.0 if anchors else 0.0
    K = spring_stiffness_matrix(mesh.vertices, mesh.edges, model.spring_ke_host, length, model.anchor_ke_host * scale).toarray()
    C = spring_stiffness_matrix(mesh.vertices, mesh.edges, model.spring_kd_host, length, model.anchor_kd_host * scale).toarray()
    whole = springs_matrices(model, anchors)
    for got, want in zip(whole, (K, C)):
        np.testing.assert_allclose(got.toarray(), want, rtol=0, atol=1e-12 * abs(want).max())
    some = np.sort(np.random.default_rng(1).choice(mesh.vertex_count, 50, replace=False))
    dof = (3 * some[:, None] + np.arange(3)).ravel()
    for got, want in zip(springs_matrices(model, anchors, some), (K, C)):
        np.testing.assert_allclose(got.toarray(), want[np.ix_(dof, dof)], rtol=0, atol=1e-12 * abs(want).max())


def dense_critical_dt(model, free) -> float:
    """stable_step's formula from a dense eigendecomposition of the free vertices' M^-1/2 K M^-1/2."""
    mesh = model.mesh
    K = spring_stiffness_matrix(mesh.vertices, mesh.edges, model.spring_ke_host, mesh.edge_rest_length, model.anchor_ke_host)
    C = spring_stiffness_matrix(mesh.vertices, mesh.edges, model.spring_kd_host, mesh.edge_rest_length, model.anchor_kd_host)
    dof = (3 * free[:, None] + np.arange(3)).ravel()
    w = np.repeat(1.0 / np.sqrt(model.particle_mass_host), 3)[dof]
    Kf = w[:, None] * K.toarray()[np.ix_(dof, dof)] * w[None, :]
    Cf = w[:, None] * C.toarray()[np.ix_(dof, dof)] * w[None, :]
    vals, vecs = np.linalg.eigh(Kf)
    lam, v = vals[-1], vecs[:, -1]
    g = v @ Cf @ v
    return (-g + math.sqrt(g * g + 4 * lam)) / lam


def rings_around(model, seed: int, rings: int) -> set:
    offsets, neighbour, _ = model.mesh.adjacency
    inside = {seed}
    for _ in range(rings):
        inside |= {int(u) for v in inside for u in neighbour[offsets[v]:offsets[v + 1]]}
    return inside


def test_critical_step_of_disjoint_pieces_is_the_wholes(model):
    # two patches far apart (opposite poles) and a third: pieces that share no spring
    z = model.mesh.vertices[:, 2]
    far = [int(np.argmax(z)), int(np.argmin(z)), int(np.argmax(model.mesh.vertices[:, 0]))]
    free = np.array(sorted(set().union(*(rings_around(model, v, 3) for v in far))))
    assert len(free) * 3 > 60  # the pieces' path, not the small dense one
    np.testing.assert_allclose(model.critical_dt(free), dense_critical_dt(model, free), rtol=1e-6)


def test_certified_substeps_are_the_free_sets(model):
    from almsdm_warp.batch.critical_step import certified_critical_dt

    bound = model.critical_dt()
    free = np.array(sorted(rings_around(model, 0, 6)))
    exact = model.critical_dt(free)
    certified = 0
    for frame in bound * np.array([0.5, 0.95, 1.3, 2.7, 3.05, 5.5]):  # one substep and several
        got = certified_critical_dt(model, free, frame, bound, {})
        if got is not None:
            certified += 1
            assert substeps_for(frame, got) == substeps_for(frame, exact)
    assert certified >= 4
    # a frame just past a substep boundary for the whole mesh but not for the free set: not certified
    frame = 0.9 * 2 * (bound + exact) / 2
    if substeps_for(frame, bound) != substeps_for(frame, exact):
        assert certified_critical_dt(model, free, frame, bound, {}) is None


def brute_force_patches(model, vertices, radius, depth):
    """The sphere patch rule over every vertex pair (a B x V distance matrix)."""
    mesh = model.mesh
    n = model.vertex_normal_rest
    reach = math.sqrt(2 * radius * depth) + mesh.edge_rest_length.max()
    out = []
    for v in vertices:
        near = np.linalg.norm(mesh.vertices - mesh.vertices[v], axis=1) <= reach
        facing = n @ n[v] > 0
        mask = near & facing
        mask[v] = True
        out.append(np.flatnonzero(mask))
    return out


@pytest.mark.parametrize("radius, depth", [(0.01, 0.01), (0.004, 0.002)])
def test_sphere_patches_from_the_tree(model, radius, depth):
    from almsdm_warp.region.patch import sphere_patches

    vertices = np.arange(0, model.mesh.vertex_count, 7)
    offsets, ids = sphere_patches(model, vertices, radius, depth, chunk=16)
    want = brute_force_patches(model, vertices, radius, depth)
    assert len(offsets) == len(vertices) + 1
    for b, patch in enumerate(want):
        np.testing.assert_array_equal(ids[offsets[b]:offsets[b + 1]], patch)


OBJ_CASES = {
    "plain": (b"# a comment\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1e-3 -2.5E+2 .5\n\nf 1 2 3\nf 3 2 4\n", True),
    "crlf": (b"v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 3\r\n", True),
    "unused vertex": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nf 1 2 3\n", False),
    "quad": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n", False),
    "texture indices": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\n", False),
    "colours": (b"v 0 0 0 1 0 0\nv 1 0 0 1 0 0\nv 0 1 0 1 0 0\nf 1 2 3\n", False),
    "object": (b"o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", False),
    "index past the end": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", False),
}


@pytest.mark.parametrize("case", list(OBJ_CASES))
def test_plain_obj_reads_as_trimesh_does(case):
    """read_plain_obj takes only v/f files whose every vertex a face uses, and reads them as trimesh does."""
    import io

    import trimesh

    from almsdm_warp.mesh.io import read_plain_obj

    data, plain = OBJ_CASES[case]
    got = read_plain_obj(data)
    assert (got is not None) == plain
    if plain:
        want = trimesh.load_mesh(io.StringIO(data.decode()), file_type="obj", process=False)
        np.testing.assert_array_equal(got[0], want.vertices)
        np.testing.assert_array_equal(got[1], want.faces)


def test_shipped_obj_reads_as_trimesh_does():
    import trimesh

    from almsdm_warp.mesh.io import read_plain_obj
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "scenes" / "stomach.obj"
    got = read_plain_obj(path.read_bytes())
    want = trimesh.load(path, process=False)
    np.testing.assert_array_equal(got[0], want.vertices)
    np.testing.assert_array_equal(got[1], want.faces)
