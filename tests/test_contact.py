"""Contact on the device against exhaustive searches: closest point over every triangle, nearest vertex."""

import numpy as np
import pytest
import trimesh
from conftest import load_cached, mesh_params

from almsdm_warp import ContactQuery, find_contacts


def brute_closest_points(mesh, probes):
    """Closest surface point of each probe by an exhaustive search over every triangle.

    (trimesh.proximity.closest_point prunes candidates with an r-tree and can miss the closest face;
    trimesh's absolute tolerances need millimetres, not metres, for millimetre-sized triangles.)
    """
    tri = mesh.vertices_mm[mesh.triangles]
    points = np.empty_like(probes)
    for i, p in enumerate(probes * 1e3):
        on_tri = trimesh.triangles.closest_point(tri, np.broadcast_to(p, (len(tri), 3)))
        points[i] = on_tri[np.argmin(np.linalg.norm(on_tri - p, axis=1))]
    points *= 1e-3
    return points, np.linalg.norm(points - probes, axis=1)


def probes_around(mesh, count, seed=0):
    """Probe positions near, on, inside and far from the surface."""
    rng = np.random.default_rng(seed)
    size = np.ptp(mesh.vertices, axis=0).max()
    sv = mesh.surface_vertices
    near = mesh.vertices[rng.choice(sv, count)] + rng.normal(scale=0.05 * size, size=(count, 3))
    far = mesh.vertices.mean(axis=0) + rng.normal(size=(4, 3)) * 10 * size
    return np.vstack([near, far, mesh.vertices[sv[:3]]])


@pytest.mark.parametrize("path", mesh_params())
def test_contacts_match_brute_force(path, device):
    mesh = load_cached(path)
    probes = probes_around(mesh, 64)
    got = ContactQuery(mesh, device)(probes)
    point, distance = brute_closest_points(mesh, probes)
    scale = np.ptp(mesh.vertices, axis=0).max()
    np.testing.assert_allclose(got.distance, distance, atol=1e-6 * scale + 1e-9)
    # the point is unique only up to ties; it must lie on its face, at the least distance
    unique = np.abs(np.linalg.norm(point - got.point, axis=1)) < 1e-5 * scale
    assert unique.mean() > 0.9
    tri = mesh.vertices_mm[mesh.triangles[got.face]]
    on_face = trimesh.triangles.closest_point(tri, got.point * 1e3) * 1e-3
    np.testing.assert_allclose(on_face, got.point, atol=1e-6 * scale)
    # nearest surface vertex to the contact point, brute force over every surface vertex
    sv = mesh.surface_vertices
    d = np.linalg.norm(mesh.vertices[sv][None, :, :] - got.point[:, None, :], axis=2)
    best = sv[np.argmin(d, axis=1)]
    got_d = np.linalg.norm(mesh.vertices[got.vertex] - got.point, axis=1)
    np.testing.assert_allclose(got_d, d.min(axis=1), atol=1e-6 * scale)
    clear = np.sort(d, axis=1)[:, 1] - d.min(axis=1) > 1e-5 * scale  # no near tie in float32
    np.testing.assert_array_equal(got.vertex[clear], best[clear])
    assert np.isin(got.vertex, sv).all()


def test_single_probe_and_reuse(device):
    from conftest import scene_mesh_paths

    paths = scene_mesh_paths()
    if not paths:
        pytest.skip("no scene meshes")
    mesh = load_cached(paths[0])
    query = ContactQuery(mesh, device)
    v = int(mesh.surface_vertices[5])
    # a probe exactly on a vertex touches that vertex
    one = query(mesh.vertices[v])
    assert one.vertex == v and one.distance < 1e-7
    probes = probes_around(mesh, 100, seed=1)
    big = query(probes)
    small = query(probes[:10])  # buffers sized for 100 are reused for 10
    np.testing.assert_array_equal(small.vertex, big.vertex[:10])
    np.testing.assert_array_equal(small.point, big.point[:10])
    with pytest.raises(ValueError, match="probe 1 has a non-finite position"):
        find_contacts(mesh, [[0, 0, 0], [np.nan, 0, 0]], device=device)
