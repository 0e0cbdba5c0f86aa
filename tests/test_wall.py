"""A hollow organ's wall as a layer of tets (tissue/wall.py), against independent answers: the closed-form volume
of a spherical shell, the slab's own tet grid (evaluation/depth_layers.py, Kuhn's split), a watertight boundary
(conforming prisms), and the neo-Hookean law's press on the wall against the P1 neo-Hookean FEM of the same tets."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from almsdm_warp.errors import InputError
from almsdm_warp.evaluation import depth_layers as dl
from almsdm_warp.mesh import topology as topo
from almsdm_warp.mesh.tissue_mesh import TissueMesh
from almsdm_warp.tissue.wall import extrude_wall, layer_count

R = 50.0  # the ball's radius [mm]


def ball(subdivisions: int, radius: float = R) -> TissueMesh:
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return TissueMesh.from_arrays(s.vertices, s.faces)


def patch(h: float, z: float = 10.0) -> TissueMesh:
    """The slab's top face (30 x 30 mm at height z, dl.graded's coordinates), two triangles a cell, wound upward."""
    xs = dl.graded(h, 15.0)
    n = len(xs)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    points = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    cells = [(i * n + j, (i + 1) * n + j, i * n + j + 1, (i + 1) * n + j + 1) for i in range(n - 1) for j in range(n - 1)]
    return TissueMesh.from_arrays(points, np.array([t for a, b, c, d in cells for t in ((a, b, d), (a, d, c))]))


def test_shell_volume_converges_to_the_closed_form():
    """4/3 pi (R^3 - (R - t)^3): the error falls about 4x a subdivision (the polyhedron's, second order)."""
    t = 5.0
    exact = 4.0 / 3.0 * np.pi * (R**3 - (R - t) ** 3) * 1e-9
    errors = []
    for sub in (2, 3, 4):
        wall = extrude_wall(ball(sub), t * 1e-3, edge=4e-3)
        volume = topo.tet_signed_volumes(wall.vertices, wall.tetrahedra)
        assert volume.min() > 0.0
        errors.append(abs(volume.sum() / exact - 1.0))
    assert errors[0] > 3.0 * errors[1] > 9.0 * errors[2], errors
    assert errors[2] < 0.005, errors


def test_prisms_conform_and_the_outer_layer_is_the_surface():
    """A conforming split leaves no inner face unmatched: the tets' boundary is the outer and the inner surface,
    one face each per triangle, closed and wound outward; the outer layer keeps the surface's vertex ids."""
    surface = ball(2, 15.0)
    wall = extrude_wall(surface, 4e-3, edge=1.5e-3)
    layers = layer_count(4e-3, 1.5e-3)
    assert layers == 3 and wall.tet_count == 3 * surface.triangle_count * layers
    boundary = topo.tet_surface(wall.tetrahedra)
    assert len(boundary) == 2 * surface.triangle_count
    shell = trimesh.Trimesh(wall.vertices, boundary, process=False)
    assert shell.is_watertight and shell.is_winding_consistent and shell.volume > 0
    np.testing.assert_allclose(wall.vertices[: surface.vertex_count], surface.vertices, rtol=0, atol=1e-12)
    depth = 15e-3 - np.linalg.norm(wall.vertices, axis=1)  # each layer's distance in from the sphere
    assert depth.max() == pytest.approx(4e-3, rel=0.02)


@pytest.mark.parametrize("h", [2.0, 5.0])
def test_a_flat_patch_extruded_is_the_slabs_tet_grid(h):
    """The slab on bone (depth_layers.slab_case: a grid of cubes, six Kuhn tets each) is what the patch on its top,
    extruded 10 mm down in layers of h, gives: the same tets, so the same FEM references."""
    wall = extrude_wall(patch(h), 10e-3, edge=h * 1e-3)
    slab = dl.slab_case(h).mesh

    def tets(mesh):
        x = np.round(mesh.vertices * 1e6).astype(np.int64)
        return {tuple(sorted(map(tuple, x[t]))) for t in mesh.tetrahedra}

    assert wall.tet_count == slab.tet_count and tets(wall) == tets(slab)


def test_neo_hookean_on_the_wall_against_the_fem_of_its_tets():
    """The wall of a patch (4 mm edges, 3 layers) on a rigid base, a 5 mm sphere pressed 2 mm: the law's hold force
    within 15% of the P1 neo-Hookean FEM of the same tets (measured 0.86, as the slab's own grid gives 0.90 at this
    coarseness: tests/test_depth_layers.py), no tet inverted."""
    wall = extrude_wall(patch(4.0), 10e-3, edge=4e-3)
    top = int(np.argmin(np.linalg.norm(wall.vertices - [0.0, 0.0, 0.01], axis=1)))
    case = dl.Case("slab", "wall", wall, top, 1e-5, 5e-3, 2e-3, poisson=0.2)
    fem = dl.fem_force(case)["fem_N"]
    press = dl.law_press(case, "neo-hookean")
    assert 0.05 < fem < 0.2
    assert abs(press["force_N"] / fem - 1.0) < 0.15 and press["inverted_tets"] == 0


def test_a_wall_thicker_than_the_curvature_allows_is_refused():
    with pytest.raises(InputError, match=r"a wall 14 mm thick folds at vertex \d+, where the surface curves with a radius of 1\d\.?\d* mm"):
        extrude_wall(ball(2, 15.0), 14e-3)
    with pytest.raises(InputError, match="thickness > 0"):
        extrude_wall(ball(2, 15.0), 0.0)
    with pytest.raises(InputError, match="already a tetrahedral mesh"):
        extrude_wall(extrude_wall(ball(1, 15.0), 2e-3), 1e-3)
    with pytest.raises(InputError, match=r"the tets would be about 3,840 .* more than 1,000"):
        extrude_wall(ball(2, 15.0), 4e-3, edge=1e-3, max_tets=1000)
