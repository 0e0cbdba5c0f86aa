"""Meshes made by the project: sizes, orientation, closed surfaces, against closed forms."""

import numpy as np
import pytest

from almsdm_warp.errors import InputError
from almsdm_warp.mesh import primitives
from almsdm_warp.mesh import topology as topo


def _euler_characteristic(triangles):
    v = len(np.unique(triangles))
    e = len(topo.unique_edges(triangles))
    return v - e + len(triangles)


@pytest.mark.parametrize("subdivisions", [0, 1, 3])
def test_icosphere_counts_and_radius(subdivisions):
    mesh = primitives.icosphere(20.0, subdivisions)
    assert mesh.vertex_count == 10 * 4**subdivisions + 2
    assert mesh.triangle_count == 20 * 4**subdivisions
    np.testing.assert_allclose(np.linalg.norm(mesh.vertices_mm, axis=1), 20.0, rtol=1e-12)
    assert _euler_characteristic(mesh.triangles) == 2
    assert not mesh.notes


@pytest.mark.parametrize("edge_mm, refine_top", [(10.0, 1.0), (7.0, 1.0), (12.0, 4.0)])
def test_tet_ball_is_a_closed_positive_ball(edge_mm, refine_top):
    vertices, tets = primitives.tet_ball_arrays(50.0, edge_mm, refine_top=refine_top)
    volumes = topo.tet_signed_volumes(vertices, tets)
    assert volumes.min() > 0.0
    # a polyhedron inscribed in the sphere: a little less than 4/3 pi R^3
    assert 0.97 < volumes.sum() / (4.0 / 3.0 * np.pi * 0.05**3) < 1.0
    surface = topo.tet_surface(tets)
    assert _euler_characteristic(surface) == 2  # one closed surface of genus 0, no inner voids
    np.testing.assert_allclose(np.linalg.norm(vertices[np.unique(surface)], axis=1), 0.05, rtol=1e-12)
    if refine_top == 1.0:
        lengths = topo.edge_lengths(vertices, topo.unique_edges(surface, tets))
        assert 0.7 * edge_mm < np.median(lengths) * 1e3 < 1.4 * edge_mm


def test_tet_ball_refined_at_the_top():
    vertices, tets = primitives.tet_ball_arrays(50.0, 12.0, refine_top=4.0)
    edges = topo.unique_edges(np.zeros((0, 3), np.int32), tets)
    lengths = topo.edge_lengths(vertices, edges)
    to_top = np.linalg.norm(vertices[edges].mean(axis=1) - [0.0, 0.0, 0.05], axis=1)
    # spacing x 1/4 at the pole, growing with the distance from it (x 1.25 at 50 mm)
    assert np.median(lengths[to_top < 0.01]) < 0.4 * np.median(lengths[to_top > 0.05])


def test_tet_ball_mesh_is_valid_and_unrepaired():
    mesh = primitives.tet_ball(30.0, 8.0, seed=3)
    assert mesh.is_volume and not mesh.notes
    assert mesh.vertex_count == len(primitives.tet_ball_arrays(30.0, 8.0, seed=3)[0])


def test_tet_box_volume_and_counts():
    mesh = primitives.tet_box((2.0, 3.0, 4.0), (2, 3, 4))
    assert mesh.tet_count == 6 * 2 * 3 * 4
    assert mesh.vertex_count == 3 * 4 * 5
    assert not mesh.notes
    volumes = topo.tet_signed_volumes(mesh.vertices, mesh.tetrahedra)
    assert volumes.min() > 0.0
    np.testing.assert_allclose(volumes.sum(), 24e-9, rtol=1e-12)
    # the box surface: 2 triangles per cell face
    assert mesh.triangle_count == 4 * (2 * 3 + 3 * 4 + 2 * 4)
    assert _euler_characteristic(mesh.triangles) == 2


def test_graded_grid_keeps_its_coordinates():
    xs = [0.0, 0.5, 1.5, 4.0]
    vertices, tets = primitives.tet_grid_arrays(xs, xs, [-2.0, 0.0])
    np.testing.assert_allclose(np.unique(vertices[:, 0]) * 1e3, xs)
    np.testing.assert_allclose(topo.tet_signed_volumes(vertices, tets).sum(), 4.0 * 4.0 * 2.0 * 1e-9)


@pytest.mark.parametrize(
    "call",
    [
        lambda: primitives.tet_ball(-1.0, 1.0),
        lambda: primitives.tet_ball(10.0, 0.0),
        lambda: primitives.tet_ball(10.0, 2.0, refine_top=0.5),
        lambda: primitives.icosphere(10.0, 1.5),
        lambda: primitives.tet_box(1.0, 0),
        lambda: primitives.tet_grid_arrays([0, 1], [0, 1], [1, 0]),
    ],
)
def test_bad_sizes_are_input_errors(call):
    with pytest.raises(InputError):
        call()
