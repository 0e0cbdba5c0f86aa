"""A probe of real size: a rigid sphere in frictionless one-sided contact with the surface vertices.

Against independent answers: a sphere on a bed of anchors (a Winkler foundation, closed form and
the quadrature of the same isotropic anchors), the P2 finite elements of a tet ball
(almsdm_warp.evaluation.fem, docs/calibration.md), breadth-first rings from the patch
(scipy.sparse.csgraph), and the paper's driven vertex, which a sphere must leave untouched.
"""

import json
import math

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.integrate import quad
from scipy.sparse.csgraph import shortest_path

from almsdm_warp.mesh import primitives
from almsdm_warp.mesh.tissue_mesh import TissueMesh
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.region.region import Region
from almsdm_warp.sim.model import PROBE_DISPLACEMENT, PROBE_SPHERE, Model
from almsdm_warp.solvers import make_solver
from almsdm_warp.tissue.material import Material, springs_for_mesh
from almsdm_warp.tissue.params import TissueParams

KAPPA = 1.0e6
"""Foundation modulus [N/m^3]: anchors k_i = KAPPA x A_i."""
R, DEPTH = 0.02, 0.0005
"""The sphere [m] and its press [m] on the anchor bed: contact radius 4.4 mm, ~630 vertices touch."""


def flat_grid(n: int, size_mm: float) -> TissueMesh:
    """A square of n x n vertices in the plane z = 0 (outward normal +z), split into triangles."""
    xs = np.linspace(-size_mm / 2, size_mm / 2, n)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    v = np.stack([X.ravel(), Y.ravel(), np.zeros(n * n)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return TissueMesh.from_arrays(v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]))


@pytest.fixture(scope="module")
def anchor_bed():
    """A grid (spacing 0.3 mm) whose vertices hold only anchors KAPPA x area (springs 1e-6 N/m), critically damped."""
    mesh = flat_grid(47, 13.8)
    density, thickness = 1000.0, 0.025
    area = mesh.vertex_masses(density, thickness) / (density * thickness)
    damping = 2.0 * math.sqrt(KAPPA * density * thickness)  # per area: critical for each vertex
    tissue = TissueParams(density=density, thickness=thickness, edge_stiffness=1e-6, edge_damping=0.0,
                          anchor_stiffness=KAPPA, anchor_damping=damping)
    centre = int(np.argmin(np.linalg.norm(mesh.vertices, axis=1)))
    return mesh, tissue, area, centre


def anchor_references(radius, depth):
    """(Winkler's closed form, the same bed of isotropic anchors by quadrature) [N]: the vertical push
    kappa pi d^2 (R - d/3); and, as frictionless contact lets each vertex settle where its anchor is
    normal to the sphere (the radial projection of its rest point), kappa x the integral of the radial
    overlap R - rho times its vertical part h / rho, rho the rest point's distance from the centre."""
    h = radius - depth
    a = math.sqrt(radius**2 - h**2)
    winkler = KAPPA * math.pi * depth**2 * (radius - depth / 3.0)
    radial, _ = quad(lambda r: KAPPA * (radius - math.hypot(r, h)) * h / math.hypot(r, h) * 2.0 * math.pi * r, 0.0, a)
    return winkler, radial


@pytest.mark.parametrize("integrator", ["explicit", "implicit"])
def test_sphere_on_anchors_is_winklers_foundation(device, anchor_bed, integrator):
    mesh, tissue, area, centre = anchor_bed
    pal = Palpation(mesh, tissue, rings=2, integrator=integrator, dt=1e-3, device=device, anchor_scale=area, probe_radius=R)
    pal.touch(centre, DEPTH)
    result = pal.press(DEPTH, ramp=0.05, hold=0.1, settle=0.002)
    hold = result.force[result.release_step - 1]
    winkler, radial = anchor_references(R, DEPTH)
    # the grid sums the anchors' overlap as a midpoint rule: measured 0.02% off the quadrature
    np.testing.assert_allclose(hold, radial, rtol=2e-3)
    # and Winkler's vertical push differs from it by O(d / R) (1.7% at d / R = 1/40)
    np.testing.assert_allclose(hold, winkler, rtol=0.03)

    # (c) held again after the press: every contact vertex on the sphere, none inside, the reaction along the press
    c = pal.rest_position() - pal.inward_normal() * (R - DEPTH)
    pal.set_probe(PROBE_SPHERE, c)
    for _ in range(100):
        pal.step()
    state_q = pal.positions()
    contact = pal.control.probe_contact.numpy()
    touching = np.flatnonzero(np.linalg.norm(contact, axis=1) > 0)
    assert len(touching) > 400
    distance = np.linalg.norm(state_q - c, axis=1)
    np.testing.assert_allclose(distance[touching], R, atol=2e-8)  # float32 at 20 mm: ulp 1.9e-9 m
    free = pal.region.vertices()[: pal.region.free_count]
    assert distance[free].min() > R - 2e-8
    reaction = pal.feedback_force.astype(np.float64)
    assert np.linalg.norm(reaction - np.dot(reaction, pal.inward_normal()) * pal.inward_normal()) < 1e-6 * np.linalg.norm(reaction)
    assert np.dot(reaction, pal.inward_normal()) < 0  # the tissue pushes the probe back
    np.testing.assert_allclose(contact[free].sum(axis=0), reaction, rtol=1e-5, atol=1e-9)


def test_zero_radius_is_the_driven_vertex_bit_for_bit(device):
    # a Control with a sphere, driven in displacement mode, gives the same bits as one without:
    # the sphere's code leaves the paper's probe alone (the sum of contacts is not launched in use)
    mesh = primitives.icosphere(40.0, 3)
    top = int(np.argmax(mesh.vertices[:, 2]))
    model = Model(mesh, device=device)
    region = Region(model.dmesh).build(top, 3)
    for integrator in ("explicit", "implicit"):
        runs = []
        for sphere in (False, True):
            solver = make_solver(model, integrator)
            solver.set_region(region)
            states = [model.state(), model.state()]
            control = model.control()
            if sphere:
                control.set_sphere(0.01)
            rest = mesh.vertices[top].astype(np.float32).astype(np.float64)
            control.set(vertex=top, mode=PROBE_DISPLACEMENT)
            for s in range(40):
                control.set(target=rest - np.array([0.0, 0.0, 1e-4]) * min(s + 1, 20))
                solver.step(states[s % 2], states[1 - s % 2], control, 1e-3)
            runs.append((states[0].particle_q.numpy(), control.probe_reaction.numpy()))
        np.testing.assert_array_equal(runs[0][0], runs[1][0])
        np.testing.assert_array_equal(runs[0][1], runs[1][1])
    # and Palpation's probe_radius=0 is the default probe
    a = Palpation(mesh, device=device, rings=3)
    b = Palpation(mesh, device=device, rings=3, probe_radius=0.0)
    forces = []
    for pal in (a, b):
        pal.touch(top)
        forces.append(pal.press(0.005, ramp=0.02, hold=0.02, settle=0.02).force)
    np.testing.assert_array_equal(forces[0], forces[1])


def test_region_grows_from_the_patch(device):
    mesh = flat_grid(31, 15.0)
    pal = Palpation(mesh, device=device, rings=2, probe_radius=0.01)
    centre = int(np.argmin(np.linalg.norm(mesh.vertices, axis=1)))
    pal.touch(centre, 0.002)
    # ring 0: the surface vertices within sqrt(2 R d) + the longest edge (brute force)
    reach = math.sqrt(2 * 0.01 * 0.002) + mesh.edge_rest_length.max()
    patch = np.flatnonzero(np.linalg.norm(mesh.vertices - mesh.vertices[centre], axis=1) <= reach)
    offsets = pal.region.ring_offsets
    np.testing.assert_array_equal(np.sort(pal.region.vertices()[: offsets[1]]), patch)
    # ring r: r hops from the nearest patch vertex (breadth-first, scipy)
    e = mesh.edges
    graph = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(mesh.vertex_count,) * 2)
    hops = shortest_path(graph, directed=False, unweighted=True, indices=patch).min(axis=0)
    ring = pal.region.vertex_ring.numpy()
    np.testing.assert_array_equal(ring, np.where(hops <= 2, hops, -1).astype(np.int32))
    assert pal.region.seed == centre


@pytest.fixture(scope="module")
def tet_ball():
    """The issue's ball: R 50 mm, edges 8 mm (2 mm at the top), E 10 kPa, nu 0.45, springs by the
    `indentation` law; nodes below z = -40 mm held by anchors 1e9 N/m, the others 1e-9 N/m."""
    mesh = primitives.tet_ball(50.0, 8.0, refine_top=4.0)
    springs = springs_for_mesh(mesh, Material(youngs_modulus=10e3, poisson_ratio=0.45))
    held = np.where(mesh.vertices[:, 2] < -0.04, 1e9, 1e-9)
    return mesh, springs.edge_stiffness, held


BALL_P2_N = 0.2141
"""P2 finite elements on the same mesh (edge 8 mm, graded x 4), sphere R 50 mm pressed 2 mm:
docs/calibration.md's table, from evaluation/fem.sphere_press (30 s on 2 cores, so not redone here)."""


def test_sphere_on_tet_ball_matches_p2_fem(device, tet_ball):
    mesh, k_edge, held = tet_ball
    # Rayleigh damping d_ij = 0.01 s x k_ij: the slowest mode (~150 rad/s) near critical
    tissue = TissueParams(density=1000.0, edge_stiffness=1.0, edge_damping=0.01, anchor_stiffness=1.0, anchor_damping=1e-3)
    pal = Palpation(mesh, tissue, rings="global", integrator="implicit", dt=2e-3, device=device,
                    edge_scale=k_edge, anchor_scale=held, probe_radius=0.05)
    top = int(np.argmax(mesh.vertices[:, 2]))
    pal.touch(top)
    result = pal.press(0.002, ramp=0.1, hold=0.3, settle=0.002)
    hold = result.force[result.release_step - 1]
    # measured 0.971 of P2: the large-strain springs under a radial contact (calibration: 0.95-0.98)
    assert hold == pytest.approx(BALL_P2_N, rel=0.05)
    # only surface vertices touch: a tet mesh's interior never does
    touching = np.flatnonzero(np.linalg.norm(pal.control.probe_contact.numpy(), axis=1) > 0)
    assert len(touching) > 10
    assert np.isin(touching, mesh.surface_vertices).all()
    interior = np.setdiff1d(np.arange(mesh.vertex_count), mesh.surface_vertices)
    assert len(interior) and not pal.control.probe_surface.numpy()[interior].any()


def test_bad_radius_and_uses_are_clear_errors():
    mesh = flat_grid(5, 4.0)
    for bad in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="probe_radius"):
            Palpation(mesh, probe_radius=bad)
    with pytest.raises(TypeError, match="probe_radius"):
        Palpation(mesh, probe_radius="1")
    pal = Palpation(mesh, rings=1, probe_radius=1e-4)
    pal.touch(12, 0.001)
    with pytest.raises(ValueError, match="radius"):
        pal.press(0.001, ramp=0.001, hold=0.001, settle=0.001)  # 1 mm a step through a 0.1 mm sphere
    with pytest.raises(ValueError, match="press_force"):
        pal.press_force(0.1)


def test_cli_probe_radius(tmp_path):
    from almsdm_warp.cli.main import main

    out = tmp_path / "run.json"
    args = ["palpate", "--probe-radius-mm", "10", "--hold-s", "0.05", "--settle-s", "0.05", "--json", str(out)]
    assert main(args) == 0
    record = json.loads(out.read_text())
    assert record["model"]["probe_radius_mm"] == 10.0
    assert record["presses"][0]["peak_force_N"] > 0
    scene = tmp_path / "s.toml"
    mesh = tmp_path / "grid.obj"
    grid = flat_grid(15, 20.0)
    mesh.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in grid.vertices * 1e3)
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in grid.triangles))
    scene.write_text(f'[mesh]\npath = "{mesh.name}"\n[probe]\nradius_mm = 5.0\n[press]\ndepth_mm = 1.0\nhold_s = 0.02\nsettle_s = 0.02\n')
    centre = int(np.argmin(np.linalg.norm(grid.vertices - grid.vertices.mean(axis=0), axis=1)))
    assert main(["palpate", str(scene), "--vertex", str(centre), "--integrator", "implicit", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["model"]["probe_radius_mm"] == 5.0
    # auto rings grow from the sphere's patch (the adaptive region holds it; tests/test_adaptive.py checks the force)
    assert main(["palpate", str(scene), "--vertex", str(centre), "--rings", "auto", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["model"]["probe_radius_mm"] == 5.0


def test_implicit_hold_force_is_the_explicit_one(device):
    # a 10 mm sphere pressed 10 mm into the stomach (springs and anchors), dt 0.2 ms: the filtered
    # CG's hold force against the explicit projection's (measured: 2e-6 apart)
    from almsdm_warp import load_mesh
    from almsdm_warp.region.contact import top_vertex

    from conftest import SCENES

    mesh = load_mesh(SCENES / "stomach.obj")
    holds = []
    for integrator in ("explicit", "implicit"):
        pal = Palpation(mesh, rings=4, integrator=integrator, dt=2e-4, device=device, probe_radius=0.01)
        pal.touch(top_vertex(mesh), 0.01)
        result = pal.press(0.01, ramp=0.1, hold=0.3, settle=0.0002)
        holds.append(result.force[result.release_step - 1])
    assert holds[0] > 4.0  # more than the paper's one driven vertex (2.5 N): several vertices touch
    np.testing.assert_allclose(holds[1], holds[0], rtol=0.01)
