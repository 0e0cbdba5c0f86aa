"""The implicit step's rigid sphere on the shipped stomach scene (10 mm sphere, 10 mm presses).

Against independent answers: the same press repeated (a deterministic step from the same state gives
the same force), the explicit integrator's projection, and a static solve of the same springs and
anchors with the sphere as an inequality constraint (scipy's SLSQP on the region, float64), whose
force on the probe is the sum of the energy's gradients over the free vertices.
"""

import numpy as np
import pytest
from scipy.optimize import minimize

from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.region.contact import top_vertex
from almsdm_warp.scene.loader import resolve_scene_or_mesh

DEPTH = 0.01
"""The press [m]: the scene's default."""


@pytest.fixture(scope="module")
def stomach_scene():
    scene = resolve_scene_or_mesh("stomach")
    mesh = scene.load_mesh()
    return scene, mesh, top_vertex(mesh)


def sphere_palpation(stomach_scene, device, integrator, rings):
    scene, mesh, vertex = stomach_scene
    pal = Palpation(mesh, scene.tissue, rings=rings, integrator=integrator, dt=1e-3, device=device,
                    probe_radius=scene.probe_radius)
    pal.touch(vertex, DEPTH)
    return pal


def test_repeated_presses_give_the_same_force(device, stomach_scene):
    # five presses in a row on one palpation: each starts from the last one's residue (recovery
    # error ~1e-6 mm), so each must give the first one's peak and hold; the ramp-to-hold step, where
    # the sphere stops and prescribes the largest normal velocity change, must converge
    pal = sphere_palpation(stomach_scene, device, "implicit", 3)
    stats = []

    def at_the_stop(k, total):
        if 100 <= k <= 102:
            stats.append(pal.solver.cg_stats)

    presses = [pal.press(DEPTH, ramp=0.1, hold=0.2, settle=1.0, record=at_the_stop) for _ in range(5)]
    peaks = np.array([r.peak_force_N for r in presses])
    holds = np.array([r.force[r.release_step - 1] for r in presses])
    np.testing.assert_allclose(peaks, peaks[0], rtol=1e-5)
    np.testing.assert_allclose(holds, holds[0], rtol=1e-5)
    for iterations, residual in stats:
        assert iterations < pal.solver.cg_max_iterations and residual <= pal.solver.cg_tolerance
    # the explicit projection's press at the same step (measured: peak 0.3%, hold 0.002% apart)
    explicit = sphere_palpation(stomach_scene, device, "explicit", 3).press(DEPTH, ramp=0.1, hold=0.2, settle=0.001)
    np.testing.assert_allclose(holds[0], explicit.force[explicit.release_step - 1], rtol=0.01)
    np.testing.assert_allclose(peaks[0], explicit.peak_force_N, rtol=0.01)


def static_sphere_force(pal, centre_mm, radius_mm, inward):
    """The force [N] of the region's springs and anchors at rest against the sphere (float64, mm): the
    minimum of their energy with every free vertex near the sphere kept outside it, and the sum of
    the energy's gradients over the free vertices (zero off the contact, the contact forces on it)."""
    model, mesh = pal.model, pal.model.mesh
    rest = model.particle_q_rest.numpy().astype(np.float64) * 1e3
    free = pal.solver.free_vertex.numpy()[: pal.solver.free_count]
    ke = model.spring_ke.numpy().astype(np.float64)
    rest_length = model.spring_rest_length.numpy().astype(np.float64) * 1e3
    ka = model.anchor_ke.numpy().astype(np.float64)[free] * pal.solver.anchor_scale
    touching = np.isin(mesh.edges, free).any(axis=1)
    edges, ke, rest_length = mesh.edges[touching], ke[touching], rest_length[touching]
    near = np.flatnonzero(np.linalg.norm(rest[free] - centre_mm, axis=1) < radius_mm + 3.0)

    def energy(y):
        x = rest.copy()
        x[free] = y.reshape(-1, 3)
        d = x[edges[:, 1]] - x[edges[:, 0]]
        length = np.linalg.norm(d, axis=1)
        stretch = length - rest_length
        grad = np.zeros_like(x)
        fe = (1e-3 * ke * stretch / length)[:, None] * d  # N/m x mm x 1e-3 = N
        np.add.at(grad, edges[:, 1], fe)
        np.add.at(grad, edges[:, 0], -fe)
        grad[free] += 1e-3 * ka[:, None] * (x[free] - rest[free])
        e = 0.5e-3 * (np.sum(ke * stretch**2) + np.sum(ka[:, None] * (x[free] - rest[free]) ** 2))
        return e, grad[free].ravel()

    def outside(y):
        return np.sum((y.reshape(-1, 3)[near] - centre_mm) ** 2, axis=1) - radius_mm**2

    def outside_jacobian(y):
        x = y.reshape(-1, 3)
        jac = np.zeros((len(near), x.size))
        for k, i in enumerate(near):
            jac[k, 3 * i : 3 * i + 3] = 2.0 * (x[i] - centre_mm)
        return jac

    # start: the rest positions pushed radially out of the sphere (one at its centre: along `inward`, the
    # side the press pushes it to; along the surface normal it would start on the far side of the sphere)
    y0 = rest[free] - centre_mm
    y0[np.linalg.norm(y0, axis=1) == 0.0] = inward
    y0 = centre_mm + y0 * np.maximum(1.0, radius_mm / np.linalg.norm(y0, axis=1))[:, None]
    solution = minimize(energy, y0.ravel(), jac=True, method="SLSQP", options={"ftol": 1e-12, "maxiter": 2000},
                        constraints=[{"type": "ineq", "fun": outside, "jac": outside_jacobian}])
    assert solution.success, solution.message
    return float(np.linalg.norm(energy(solution.x)[1].reshape(-1, 3).sum(axis=0)))


def test_implicit_hold_is_the_static_answer(device, stomach_scene):
    # the hold (0.2 s, 6 damping times 2 / alpha of the scene's Rayleigh alpha) against the static
    # minimum of the same region with the sphere at its press depth (measured: 1.4e-6 apart; 13 vertices
    # touch; the sphere's centre is the contact vertex's rest position, 10 mm deep with a 10 mm radius)
    scene = stomach_scene[0]
    pal = sphere_palpation(stomach_scene, device, "implicit", 1)
    result = pal.press(DEPTH, ramp=0.1, hold=0.2, settle=0.001)
    centre_mm = (pal.rest_position() + pal.inward_normal() * (DEPTH - scene.probe_radius)) * 1e3
    static = static_sphere_force(pal, centre_mm, scene.probe_radius * 1e3, pal.inward_normal())
    np.testing.assert_allclose(result.force[result.release_step - 1], static, rtol=1e-4)
