"""Vertex normals (kernels/region/normals.py, almsdm_warp/sim/normals.py) against independent answers:
trimesh's normals on the rest shape, a float64 NumPy sum on deformed shapes, and the three
strategies against each other, on every device; surface meshes and a tet mesh's surface."""

import numpy as np
import pytest
import trimesh
from test_simulation_press import palpation, scene_and_mesh, top_vertex

from almsdm_warp import TissueMesh
from almsdm_warp.sim.normals import STRATEGIES, SurfaceNormals, benchmark_strategies

SCENES = [pytest.param(None, id="stomach-surface"), pytest.param("liver", id="liver-volume")]


def area_weighted_f64(vertices, triangles):
    """Area-weighted unit vertex normals in float64, a plain loop over faces (zero off the surface)."""
    v = np.asarray(vertices, dtype=np.float64)
    n = np.zeros_like(v)
    for a, b, c in np.asarray(triangles, dtype=np.int64):
        n_f = np.cross(v[b] - v[a], v[c] - v[a])
        n[a] += n_f
        n[b] += n_f
        n[c] += n_f
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def trimesh_area_weighted(mesh):
    """trimesh's own face normals and areas, summed per vertex by its sparse incidence."""
    tm = trimesh.Trimesh(mesh.vertices, mesh.triangles, process=False)
    n = trimesh.geometry.mean_vertex_normals(mesh.vertex_count, tm.faces, tm.face_normals * tm.area_faces[:, None])
    return n


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("strategy", STRATEGIES)
def test_rest_normals_match_trimesh(scene, strategy, device):
    _, mesh = scene_and_mesh(scene)
    normals = SurfaceNormals(mesh, device, strategy)
    normals.update(normals.dmesh.rest_position)  # every vertex, from the rest shape
    got = normals.numpy()
    sv = mesh.surface_vertices
    np.testing.assert_allclose(got[sv], trimesh_area_weighted(mesh)[sv], atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(got[sv], axis=1), 1.0, atol=1e-6)
    inside = np.setdiff1d(np.arange(mesh.vertex_count), sv)
    assert mesh.is_volume == (len(inside) > 0)
    np.testing.assert_array_equal(got[inside], 0.0)  # a tet mesh's interior has no normal


def test_sphere_normals_are_radial_and_match_trimesh_default(device):
    # on a sphere area and angle weighting (trimesh's default) nearly agree (an icosphere's
    # triangles differ in size by ~25%), and both point outward radially: within a degree
    ico = trimesh.creation.icosphere(subdivisions=3, radius=50.0)
    mesh = TissueMesh.from_arrays(ico.vertices, ico.faces)
    got = SurfaceNormals(mesh, device, "precomputed").numpy().astype(np.float64)
    radial = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    within_1_degree = np.cos(np.radians(1.0))
    assert np.einsum("ij,ij->i", got, ico.vertex_normals).min() > within_1_degree
    assert np.einsum("ij,ij->i", got, radial).min() > within_1_degree


def pressed(scene, device, depth=8e-3):
    """A palpation pressed `depth` in (ramp 30 steps, no hold), stopped at the deepest step."""
    pal = palpation(scene, device=device)
    pal.press(depth, ramp=0.03, hold=0.0, settle=0.001)  # one settle step after the release
    return pal


@pytest.mark.parametrize("scene", SCENES)
def test_strategies_agree_on_a_deformed_mesh(scene, device):
    _, mesh = scene_and_mesh(scene)
    pal = pressed(scene, device)
    q = pal.positions()
    moved = np.flatnonzero(np.linalg.norm(q - mesh.vertices, axis=1) > 1e-5)
    assert len(moved) > 5  # the press did deform the region
    expected = area_weighted_f64(q, mesh.triangles)
    results = {}
    for strategy in STRATEGIES:
        normals = SurfaceNormals(mesh, device, strategy)
        normals.update_region(pal.state.particle_q, pal.region)
        results[strategy] = got = normals.numpy()
        np.testing.assert_allclose(got, expected, atol=2e-5, err_msg=strategy)
    # the same faces added in the same order: the strategies agree far below float32 rounding of a sum
    np.testing.assert_allclose(results["search"], results["precomputed"], atol=1e-6)
    np.testing.assert_allclose(results["global"], results["precomputed"], atol=1e-6)
    # the local strategies touched only the region, which holds every vertex whose normal changed
    region = set(pal.region.vertices().tolist())
    rest = area_weighted_f64(mesh.vertices.astype(np.float32), mesh.triangles)  # as the device holds it
    changed = np.flatnonzero(np.abs(expected - rest).max(axis=1) > 0)
    assert len(changed) > 5
    assert set(changed.tolist()) <= region


def test_relocation_restores_the_normals_left_behind(device):
    _, mesh = scene_and_mesh(None)
    pal = pressed(None, device)
    normals = SurfaceNormals(mesh, device, "precomputed")
    normals.update_region(pal.state.particle_q, pal.region)
    old = pal.region.vertices()
    rest = area_weighted_f64(mesh.vertices, mesh.triangles)
    assert np.abs(normals.numpy()[old] - rest[old]).max() > 1e-3
    # the probe moves to the lowest vertex, far away: the old region goes back to rest
    sv = mesh.surface_vertices
    pal.touch(int(sv[np.argmin(mesh.vertices[sv, 2])]))
    assert not set(old.tolist()) & set(pal.region.vertices().tolist())
    normals.update_region(pal.state.particle_q, pal.region)
    np.testing.assert_allclose(normals.numpy(), rest, atol=2e-6)


def test_bad_strategy(device):
    _, mesh = scene_and_mesh(None)
    with pytest.raises(ValueError, match="unknown normals strategy 'fast'.*global, search, precomputed"):
        SurfaceNormals(mesh, device, "fast")


def test_benchmark_reports_each_strategy_over_the_region(device):
    _, mesh = scene_and_mesh(None)
    r = benchmark_strategies(mesh, 2, device, frames=2, blocks=1)
    assert set(r["strategies"]) == set(STRATEGIES)
    # the ring-2 region of the highest vertex, by hops along the mesh's edges (NumPy)
    e = mesh.edges
    seen = {top_vertex(mesh)}
    for _ in range(2):
        seen |= set(e[np.isin(e[:, 0], list(seen)), 1].tolist()) | set(e[np.isin(e[:, 1], list(seen)), 0].tolist())
    assert r["vertices_updated"] == len(seen) == r["surface_vertices_updated"]
    assert r["triangle_count"] == mesh.triangle_count and r["vertex_count"] == mesh.vertex_count
    for s in r["strategies"].values():
        assert s["frame_us_best"] <= s["frame_us_median"] and s["launch_us_median"] > 0
    g = benchmark_strategies(mesh, "global", device, frames=2, blocks=1)
    assert g["vertices_updated"] == mesh.vertex_count
