"""Host topology against independent answers: scipy sparse graphs, trimesh, closed-form volumes."""

import numpy as np
import pytest
import trimesh
from conftest import load_cached, mesh_params
from scipy.sparse import coo_matrix

from almsdm_warp.mesh import topology as topo
from almsdm_warp.mesh.tissue_mesh import TissueMesh


def box_tets(n=3, size=1.0):
    """A cube of n^3 cells, six tets each (Kuhn split: conforming, all positively oriented)."""
    g = np.linspace(0, size, n + 1)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    pts = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)
    tets = []
    paths = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    for i in range(n):
        for j in range(n):
            for k in range(n):
                for order in paths:
                    c = np.array([i, j, k])
                    corners = [idx[tuple(c)]]
                    for axis in order:
                        c = c.copy()
                        c[axis] += 1
                        corners.append(idx[tuple(c)])
                    tets.append(corners)
    tets = np.array(tets)
    vol = topo.tet_signed_volumes(pts, tets)
    tets[vol < 0] = tets[vol < 0][:, [0, 2, 1, 3]]
    return pts, tets


def test_csr_adjacency_matches_scipy():
    rng = np.random.default_rng(3)
    tris = rng.integers(0, 40, size=(120, 3))
    tris = tris[(tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])]
    edges = topo.unique_edges(tris)
    assert np.all(edges[:, 0] < edges[:, 1])
    assert len(np.unique(edges, axis=0)) == len(edges)
    offsets, nbr, eid = topo.csr_adjacency(edges, 40)
    pairs = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    dense = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(40, 40)).toarray()
    dense = (dense + dense.T) > 0
    for v in range(40):
        row = nbr[offsets[v] : offsets[v + 1]]
        np.testing.assert_array_equal(row, np.flatnonzero(dense[v]))
        # each entry's edge id joins v and that neighbour
        np.testing.assert_array_equal(np.sort(edges[eid[offsets[v] : offsets[v + 1]]], axis=1), np.sort(np.stack([np.full(len(row), v), row], 1), axis=1))


def test_incidence_lists_each_face_at_its_corners():
    tris = np.array([[0, 1, 2], [0, 2, 3], [3, 2, 4]])
    offsets, faces = topo.csr_incidence(tris, 6)
    expect = {0: [0, 1], 1: [0], 2: [0, 1, 2], 3: [1, 2], 4: [2], 5: []}
    for v, fs in expect.items():
        assert faces[offsets[v] : offsets[v + 1]].tolist() == fs


def test_tet_box_surface_edges_and_masses():
    pts, tets = box_tets(3, size=2.0)
    surf = topo.tet_surface(tets)
    tm = trimesh.Trimesh(pts, surf, process=False)
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.volume == pytest.approx(8.0)  # positive: wound outward
    assert len(surf) == 6 * 9 * 2
    assert topo.tet_signed_volumes(pts, tets).sum() == pytest.approx(8.0)
    edges = topo.unique_edges(surf, tets)
    # Kuhn split edges: axis (3*4*4*3=144), face diagonals (3*3*3*4=108), body diagonals (27)
    assert len(edges) == 144 + 108 + 27
    m = topo.lumped_masses(pts, surf, tets, density=1000.0, thickness=0.0)
    assert m.sum() == pytest.approx(8.0 * 1000.0)
    # a corner vertex of the box (0,0,0) touches only the tets of one cell at that corner
    assert m[0] > 0


def test_surface_masses_closed_form():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    mesh = TissueMesh(sphere.vertices, sphere.faces)
    m = mesh.vertex_masses(density=1000.0, thickness=0.002)
    assert m.sum() == pytest.approx(sphere.area * 0.002 * 1000.0)
    np.testing.assert_allclose(mesh.edge_rest_length, np.linalg.norm(sphere.vertices[mesh.edges[:, 0]] - sphere.vertices[mesh.edges[:, 1]], axis=1))
    assert mesh.edge_count == len(sphere.edges_unique)


@pytest.mark.parametrize("path", mesh_params())
def test_mesh_topology_invariants(path):
    mesh = load_cached(path)
    tm = trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False)
    if mesh.is_volume:
        assert tm.is_watertight and tm.volume > 0
        assert tm.volume == pytest.approx(topo.tet_signed_volumes(mesh.vertices, mesh.tetrahedra).sum(), rel=1e-9)
    else:
        tri_edges = np.unique(np.sort(tm.edges, axis=1), axis=0)
        np.testing.assert_array_equal(mesh.edges, tri_edges)
    offsets, nbr, eid = mesh.adjacency
    assert offsets[-1] == 2 * mesh.edge_count
    degree = np.bincount(mesh.edges.ravel(), minlength=mesh.vertex_count)
    np.testing.assert_array_equal(np.diff(offsets), degree)


def test_vertex_sums_are_np_add_at_bit_for_bit():
    """The per-vertex sums of a large mesh's set-up (used vertices, masses, areas, normals, each edge's
    element measure) by counting (np.bincount) give np.unique's ids and np.add.at's sums bit for bit:
    the same additions in the same order, 5-20x sooner on a 500,000-vertex organ."""
    from almsdm_warp.sim.model import vertex_normals
    from almsdm_warp.tissue.material import edge_element_measure, vertex_areas

    rng = np.random.default_rng(7)
    pts, tets = box_tets(4, 0.02)
    pts = pts + rng.normal(scale=1e-4, size=pts.shape)  # no two sums alike
    tri = topo.tet_surface(tets)
    n = len(pts) + 5  # five vertices no element uses
    pts = np.concatenate([pts, rng.normal(size=(5, 3))])
    for elements in (tets, tri, tets[:0]):
        np.testing.assert_array_equal(topo.used_vertices(elements, n), np.unique(elements).astype(np.int64))

    def add_at(index, values, shape):
        out = np.zeros(shape)
        np.add.at(out, index, values)
        return out

    vol = np.abs(topo.tet_signed_volumes(pts, tets))
    masses = topo.lumped_masses(pts, tri, tets, 1000.0, 0.0)
    assert masses.tobytes() == add_at(tets.reshape(-1), np.repeat(vol * 1000.0 / 4.0, 4), n).tobytes()
    area = topo.triangle_areas(pts, tri)
    assert vertex_areas(pts, tri).tobytes() == add_at(tri.reshape(-1), np.repeat(area / 3.0, 3), n).tobytes()
    face = np.cross(pts[tri[:, 1]] - pts[tri[:, 0]], pts[tri[:, 2]] - pts[tri[:, 0]])
    want = np.zeros((n, 3))
    for c in range(3):
        np.add.at(want, tri[:, c], face)
    length = np.linalg.norm(want, axis=1, keepdims=True)
    assert vertex_normals(pts, tri).tobytes() == np.divide(want, length, out=np.zeros_like(want), where=length > 0).tobytes()
    edges = topo.unique_edges(tri, tets)
    key = {(int(i), int(j)): k for k, (i, j) in enumerate(edges)}
    local = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    idx = [key[tuple(sorted((int(t[a]), int(t[b]))))] for t in tets for a, b in local]
    got = edge_element_measure(pts, edges, tri, tets)
    assert got.tobytes() == add_at(np.array(idx), np.repeat(vol, 6), len(edges)).tobytes()
