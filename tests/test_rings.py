"""Ring regions on the device against independent answers: scipy BFS and brute-force edge sets."""

import numpy as np
import pytest
from conftest import SCENES, load_cached, mesh_params
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import shortest_path

from almsdm_warp import Region, TissueMesh, ring_distances


def bfs_hops(mesh, seeds):
    """Unweighted shortest-path hop counts from each seed, by scipy (inf where unreachable)."""
    e = mesh.edges
    n = mesh.vertex_count
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    return shortest_path(graph, directed=False, unweighted=True, indices=seeds)


def spread_seeds(mesh, count=4):
    """Surface vertices spread over the mesh: extremes along x, y, z and the first one."""
    sv = mesh.surface_vertices
    p = mesh.vertices[sv]
    picks = [sv[0], sv[np.argmin(p[:, 0])], sv[np.argmax(p[:, 1])], sv[np.argmax(p[:, 2])]]
    return list(dict.fromkeys(int(v) for v in picks))[:count]


def expected_region_edges(mesh, inside):
    e = mesh.edges
    return np.flatnonzero(inside[e[:, 0]] & inside[e[:, 1]])


def check_region(region, mesh, dist, rings):
    """Every invariant of a built region against the hop counts `dist` from its seed."""
    expected = np.where(dist <= rings, dist, -1).astype(np.int64)
    np.testing.assert_array_equal(region.vertex_ring.numpy(), expected)
    inside = expected >= 0
    verts = region.vertices()
    # ring after ring, each ring sorted by vertex id, each vertex once
    assert len(verts) == inside.sum() == region.vertex_count
    assert len(np.unique(verts)) == len(verts)
    np.testing.assert_array_equal(expected[verts], np.sort(expected[verts]))
    for r in range(len(region.ring_offsets) - 1):
        ring = verts[region.ring_offsets[r] : region.ring_offsets[r + 1]]
        np.testing.assert_array_equal(ring, np.sort(ring))
        assert np.all(expected[ring] == r)
    # local indices
    local = region.vertex_local.numpy()
    np.testing.assert_array_equal(local[verts], np.arange(len(verts)))
    assert np.all(local[~inside] == -1)
    # springs: each edge with both ends inside, once (brute force over all edges)
    springs = region.springs()
    assert len(springs) == region.spring_count
    np.testing.assert_array_equal(np.sort(springs), expected_region_edges(mesh, inside))
    ends = region.region_edge_local.numpy()[: region.spring_count]
    np.testing.assert_array_equal(np.sort(verts[ends], axis=1), mesh.edges[springs])
    # the fixed boundary is the outermost non-empty ring
    outer = int(expected.max())
    boundary = np.flatnonzero(expected == outer) if outer > 0 else np.zeros(0, int)
    np.testing.assert_array_equal(np.sort(region.boundary()), boundary)
    assert region.boundary_count == len(boundary)


@pytest.mark.parametrize("path", mesh_params())
def test_rings_match_scipy_bfs(path, device):
    mesh = load_cached(path)
    seeds = spread_seeds(mesh)
    hops = bfs_hops(mesh, seeds)
    region = Region(mesh, device)
    for seed, dist in zip(seeds, hops):
        finite = np.isfinite(dist)
        dist = np.where(finite, dist, np.iinfo(np.int32).max).astype(np.int64)
        diameter = int(dist[finite].max())
        for rings in list(range(1, 9)) + [diameter + 3]:
            region.build(seed, rings)
            check_region(region, mesh, dist, rings)


@pytest.mark.parametrize("path", mesh_params()[:2])
def test_expand_in_place_equals_fresh_build(path, device):
    mesh = load_cached(path)
    seed = spread_seeds(mesh)[1]
    grown = Region(mesh, device).build(seed, 1)
    before = grown.vertices()
    for rings in range(2, 7):
        grown.expand(1)
        fresh = Region(mesh, device).build(seed, rings)
        np.testing.assert_array_equal(grown.vertex_ring.numpy(), fresh.vertex_ring.numpy())
        np.testing.assert_array_equal(grown.vertices(), fresh.vertices())  # same deterministic order
        np.testing.assert_array_equal(np.sort(grown.springs()), np.sort(fresh.springs()))
        np.testing.assert_array_equal(grown.boundary(), fresh.boundary())
        # the vertices that were inside keep their local indices
        np.testing.assert_array_equal(grown.vertices()[: len(before)], before)
        before = grown.vertices()


@pytest.mark.parametrize("path", mesh_params()[:2])
def test_relocation_clears_the_old_region(path, device):
    mesh = load_cached(path)
    a, b = spread_seeds(mesh)[1:3]
    region = Region(mesh, device).build(a, 4)
    old = set(region.springs().tolist())
    region.build(b, 3)
    fresh = Region(mesh, device).build(b, 3)
    np.testing.assert_array_equal(region.vertex_ring.numpy(), fresh.vertex_ring.numpy())
    np.testing.assert_array_equal(region.vertex_local.numpy(), fresh.vertex_local.numpy())
    np.testing.assert_array_equal(region.springs(), fresh.springs())
    # nothing of the old region survives unless the new one holds it too
    new = set(region.springs().tolist())
    e = mesh.edges
    ring = region.vertex_ring.numpy()
    for s in old - new:
        assert ring[e[s, 0]] < 0 or ring[e[s, 1]] < 0


def two_tetrahedra_components():
    """Two separate tetrahedron surfaces: rings never cross to the other component."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return TissueMesh(np.vstack([v, v + 5]) * 1e-3, np.vstack([f, f + 4]))


def test_components_and_rings_past_the_diameter(device):
    mesh = two_tetrahedra_components()
    dist = ring_distances(mesh, 0, 50, device=device)
    np.testing.assert_array_equal(dist, [0, 1, 1, 1, -1, -1, -1, -1])
    region = Region(mesh, device).build(5, 0)
    assert region.vertex_count == 1 and region.spring_count == 0 and region.boundary_count == 0
    region.build(5, 1)
    assert region.vertex_count == 4 and region.spring_count == 6 and region.outer_ring == 1
    region.expand(3)  # nothing more to reach: the outer ring stays ring 1
    assert region.vertex_count == 4 and region.outer_ring == 1 and region.rings == 4


def test_bad_arguments(device):
    mesh = two_tetrahedra_components()
    with pytest.raises(ValueError, match=r"seed vertex 8 is outside the mesh, which has 8 vertices \(0..7\)"):
        ring_distances(mesh, 8, 1, device=device)
    with pytest.raises(ValueError, match="rings must be >= 0, got -1"):
        ring_distances(mesh, 0, -1, device=device)
    with pytest.raises(TypeError, match="rings must be an int"):
        ring_distances(mesh, 0, 1.5, device=device)
    with pytest.raises(RuntimeError, match="build"):
        Region(mesh, device).expand(1)


def test_astronomical_ring_counts_stop_at_the_component(device):
    """Region.build(v, 10**20) and Palpation(rings=10**20) raised OverflowError (a list of every empty
    ring): growth now stops where the region covers its component; `rings` still says what was asked."""
    from almsdm_warp.protocol.palpation import Palpation

    stomach = load_cached(SCENES / "stomach.obj")
    dist = bfs_hops(stomach, [0])[0]
    dist = np.where(np.isfinite(dist), dist, -1).astype(np.int64)
    region = Region(stomach, device).build(0, 10**20)
    check_region(region, stomach, dist, int(dist.max()))
    assert region.rings == 10**20 and region.outer_ring == dist.max() and region.vertex_count == (dist >= 0).sum()
    region.expand(10**20)
    assert region.rings == 2 * 10**20 and region.vertex_count == (dist >= 0).sum()
    mesh = two_tetrahedra_components()  # a component of 4: the other 4 vertices stay out
    check_region(Region(mesh, device).build(5, 10**20), mesh, np.array([-1, -1, -1, -1, 1, 0, 1, 1]), 10**20)
    pal = Palpation(stomach, rings=10**20, device=device, dt=1e-3)
    pal.touch(0)
    assert pal.region_vertices == (dist >= 0).sum() and pal.region.outer_ring == dist.max()
    np.testing.assert_array_equal(np.sort(pal.region.boundary()), np.flatnonzero(dist == dist.max()))
