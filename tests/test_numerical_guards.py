"""Numerical guards: springs of zero length (at rest and collapsed during a press), tetrahedra
inverted by a deep press, and stiffness ratios of 1e6, with no NaN; implicit everywhere,
explicit where its step is below the critical one. The answers to compare with are float64
NumPy: a Newton solve of the static equilibrium (test_simulation_press.static_reaction) and
signed tet volumes written out here.
"""

import numpy as np
import pytest
from helpers import spring_stiffness_matrix
from test_simulation_press import DEPTH, internal_forces, scene_and_mesh, static_reaction

from almsdm_warp.mesh.tissue_mesh import TissueMesh
from almsdm_warp.sim.model import PROBE_DISPLACEMENT, PROBE_OFF
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.region.region import Region
from almsdm_warp.tissue.params import TissueParams


def signed_volumes(x, tets):
    """The signed volume of each tet, (b - a) . ((c - a) x (d - a)) / 6, float64."""
    a, b, c, d = (x[tets[:, k]] for k in range(4))
    return np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a)) / 6.0


def finite_states(p):
    return all(np.all(np.isfinite(s.particle_q.numpy())) and np.all(np.isfinite(s.particle_qd.numpy())) for s in p.states)


def hold(p, depth, steps, ramp_steps):
    rest, n = p.rest_position(), p.inward_normal()
    forces = []
    for s in range(steps):
        p.set_probe(PROBE_DISPLACEMENT, rest + n * depth * min((s + 1) / ramp_steps, 1.0))
        forces.append(np.array(p.step()))
    return np.array(forces)


def release(p, steps):
    p.set_probe(PROBE_OFF)
    for _ in range(steps):
        p.step()


# -- zero-length springs ----------------------------------------------------------------------
def doubled_vertex_mesh():
    """A closed octahedron-like surface with vertex 6 exactly on vertex 0 and an edge between them:
    a spring of rest length 0 (TissueMesh built directly: load_mesh would merge the two)."""
    v = np.array([[0, 0, 10], [10, 0, 0], [0, 10, 0], [-10, 0, 0], [0, -10, 0], [0, 0, -10], [0, 0, 10]], dtype=np.float64) * 1e-3
    tri = np.array([[0, 1, 2], [6, 2, 3], [0, 3, 4], [6, 4, 1], [5, 2, 1], [5, 3, 2], [5, 4, 3], [5, 1, 4], [0, 6, 1]])
    mesh = TissueMesh(vertices=v, triangles=tri)
    assert mesh.edge_rest_length.min() == 0.0
    return mesh


@pytest.mark.parametrize("integrator", ["explicit", "implicit"])
def test_spring_of_zero_rest_length(device, integrator):
    """A spring whose two ends coincide at rest has no direction: the guard gives it no force
    there (no 1/0), and once the probe pulls them apart it pulls back with k_ij l along the edge.
    The whole press stays finite and the held reaction matches the float64 sum of forces."""
    mesh = doubled_vertex_mesh()
    tissue = TissueParams(thickness=5e-3)
    p = Palpation(mesh, tissue, rings="global", integrator=integrator, dt=2e-4, device=device)
    p.touch(0)
    forces = hold(p, 2e-3, 400, 100)
    assert np.all(np.isfinite(forces)) and finite_states(p)
    # the reaction the step reports is the internal force at its input state: recompute it there
    q = p.positions()
    assert np.linalg.norm(q[6] - q[0]) > 1e-5  # the zero-length spring is stretched now
    want = internal_forces(mesh, tissue, q)[0]
    v_rel = p.state.particle_qd.numpy()
    assert np.abs(v_rel).max() < 1e-4  # settled: damping forces negligible
    np.testing.assert_allclose(np.array(p.step()), want, rtol=2e-3, atol=1e-4)
    release(p, 3000)
    assert finite_states(p)
    assert np.abs(p.positions() - mesh.vertices).max() < 1e-5


# -- inverted tets ------------------------------------------------------------------------------
@pytest.mark.parametrize("integrator, dt", [("implicit", 5e-3), ("explicit", 5e-4)])
def test_deep_press_inverts_tets_without_nan(device, integrator, dt):
    """A 40 mm press into the 89 mm thick liver (4 rings) turns some tets inside out (the model has
    springs on tet edges, no volume term); nothing becomes NaN, the held force equals the float64
    static equilibrium's, and after release every tet has its rest orientation again."""
    scene, mesh = scene_and_mesh("liver")
    sv = mesh.surface_vertices
    top = int(sv[np.argmax(mesh.vertices[sv, 2])])
    depth = 4 * DEPTH
    p = Palpation(mesh, scene.tissue, rings=4, integrator=integrator, dt=dt, device=device)
    p.touch(top)
    steps = int(round(0.6 / dt))
    forces = hold(p, depth, steps, steps // 3)
    assert np.all(np.isfinite(forces)) and finite_states(p)
    inverted = signed_volumes(p.positions(), mesh.tetrahedra) < 0
    assert inverted.sum() >= 2, inverted.sum()  # not vacuous: the press does invert tets
    assert np.all(signed_volumes(mesh.vertices, mesh.tetrahedra) > 0)
    target = (p.rest_position() + p.inward_normal() * depth).astype(np.float32).astype(np.float64)
    free = p.region.vertices()[: p.region.free_count]
    reference = static_reaction(mesh, scene.tissue, top, target, free)
    np.testing.assert_allclose(np.linalg.norm(forces[-1]), np.linalg.norm(reference), rtol=2e-3)
    release(p, int(round(1.0 / dt)))
    assert finite_states(p)
    assert np.abs(p.positions() - mesh.vertices).max() < 1e-5
    assert np.all(signed_volumes(p.positions(), mesh.tetrahedra) > 0)


# -- stiffness ratios of 1e6 ---------------------------------------------------------------------
def static_reaction_per_edge(mesh, ke, ka, vertex, target, free):
    """float64 Newton solve of the static equilibrium with a stiffness per edge `ke` and per vertex
    `ka`: the force on `vertex` held at `target`, the other `free` vertices in equilibrium."""
    from scipy.sparse.linalg import spsolve

    e = mesh.edges.astype(np.int64)
    L0 = mesh.edge_rest_length

    def forces(x):
        r = x[e[:, 1]] - x[e[:, 0]]
        length = np.linalg.norm(r, axis=1)
        fe = (ke * (length - L0) / length)[:, None] * r
        f = -ka[:, None] * (x - mesh.vertices)
        np.add.at(f, e[:, 0], fe)
        np.add.at(f, e[:, 1], -fe)
        return f

    unknown = np.setdiff1d(np.asarray(free, dtype=np.int64), [vertex])
    dof = (3 * unknown[:, None] + np.arange(3)).ravel()

    def residual(x):
        return forces(x).ravel()[dof]

    def stiffness(x):
        K = spring_stiffness_matrix(x, e, ke, L0, ka)
        return K[dof][:, dof].tocsc()

    # load stepping (the probe moved in 20 increments) and Newton with backtracking at each
    x = mesh.vertices.copy()
    rest = mesh.vertices[vertex].copy()
    tolerance = 1e-9 * max(1.0, float(np.abs(ke).max()) * 1e-3)
    for frac in np.linspace(0.05, 1.0, 20):
        x[vertex] = rest + frac * (np.asarray(target) - rest)
        for _ in range(60):
            g = residual(x)
            if np.linalg.norm(g) < tolerance:
                break
            step = spsolve(stiffness(x), g)
            t = 1.0
            while t > 1e-4:
                trial = x.copy()
                trial.ravel()[dof] += t * step
                if np.linalg.norm(residual(trial)) < np.linalg.norm(g):
                    break
                t *= 0.5
            x = trial
        else:
            raise AssertionError(f"Newton did not converge at {frac:.2f} of the press")
    return forces(x)[vertex]


def stiff_inclusion(mesh, ratio, centre_vertex, radius):
    """Per-edge scale: springs with both ends within `radius` [m] of `centre_vertex` `ratio` times
    stiffer (stiffness and damping), a hard lesion."""
    e = mesh.edges
    centre = mesh.vertices[centre_vertex]
    near = np.linalg.norm(mesh.vertices - centre, axis=1) < radius
    scale = np.where(near[e[:, 0]] & near[e[:, 1]], ratio, 1.0)
    assert (scale > 1).sum() >= 3
    return scale


def lesion_palpation(integrator, dt, device, rings=4):
    """The liver pressed from the top, with the springs within 30 mm of a ring-1 vertex 1e6 times
    stiffer: a hard lesion under the probe (the driven vertex is in it)."""
    scene, mesh = scene_and_mesh("liver")
    sv = mesh.surface_vertices
    top = int(sv[np.argmax(mesh.vertices[sv, 2])])
    ring1 = Region(mesh, device).build(top, 1)
    centre = int(ring1.vertices()[ring1.ring_offsets[1]])
    scale = stiff_inclusion(mesh, 1e6, centre, 0.03)
    p = Palpation(mesh, scene.tissue, rings=rings, integrator=integrator, dt=dt, device=device, edge_scale=scale)
    p.touch(top)
    return p, scene, mesh, scene.tissue.edge_stiffness * scale


def test_stiff_lesion_1e6_implicit(device):
    """Springs 1e6 times stiffer than the rest (a hard lesion under the probe), implicit at 5 ms
    (quasi-static): no NaN, and the held force equals the float64 static equilibrium (Newton with
    load steps) to 1e-3; the lesion makes it ~20x the uniform tissue's."""
    p, scene, mesh, ke = lesion_palpation("implicit", 5e-3, device)
    top = p.vertex
    forces = hold(p, DEPTH, 160, 20)
    assert np.all(np.isfinite(forces)) and finite_states(p)
    free = p.region.vertices()[: p.region.free_count]
    target = (p.rest_position() + p.inward_normal() * DEPTH).astype(np.float32).astype(np.float64)
    ka = np.full(mesh.vertex_count, scene.tissue.anchor_stiffness)
    want = np.linalg.norm(static_reaction_per_edge(mesh, ke, ka, top, target, free))
    uniform = np.linalg.norm(static_reaction(mesh, scene.tissue, top, target, free))
    assert want > 10 * uniform  # not vacuous: the lesion is felt
    np.testing.assert_allclose(np.linalg.norm(forces[-1]), want, rtol=1e-3)
    release(p, 300)
    assert finite_states(p)
    assert np.abs(p.positions() - mesh.vertices).max() < 1e-4


def test_stiff_lesion_1e6_explicit_below_its_critical_step(device):
    """The same lesion with 2 rings, explicit: the lesion reaches the fixed ring, so 1e6-stiff
    springs tie the driven vertex to fixed ones and the critical step drops from 1.4 ms to about
    40 ns. At 0.8 x that step a short, fast press (0.2 mm in 0.05 ms, ~1600 steps; ~8e4 N) stays
    finite, and its reaction agrees with the implicit run's at the same dt to 2%. (At 1 ms it
    diverges with a clear error: test_simulation_press's divergence test.)"""
    p, *_ = lesion_palpation("explicit", 1e-3, device, rings=2)
    crit = p.model.critical_dt(p.region.vertices()[: p.region.free_count])
    assert crit < 1e-6
    dt = 0.8 * crit
    steps = int(5e-5 / dt)
    q, *_ = lesion_palpation("explicit", dt, device, rings=2)
    forces = hold(q, 2e-4, steps, steps)
    assert np.all(np.isfinite(forces)) and finite_states(q)
    r, *_ = lesion_palpation("implicit", dt, device, rings=2)
    reference = hold(r, 2e-4, steps, steps)
    f, g = np.linalg.norm(forces, axis=1), np.linalg.norm(reference, axis=1)
    assert g[-1] > 1e3  # the stiff springs carry it
    np.testing.assert_allclose(f[-1], g[-1], rtol=2e-2)


def test_edge_to_anchor_ratio_1e6(device):
    """Anchors 1e6 times softer than the edges (k_ij = 62 N/m, k_i = 6.2e-5 N/m), implicit: finite,
    and the held force equals the float64 static equilibrium within 1%."""
    scene, mesh = scene_and_mesh()
    tissue = TissueParams(edge_stiffness=62.0, anchor_stiffness=62e-6, edge_damping=0.02, anchor_damping=0.1)
    sv = mesh.surface_vertices
    top = int(sv[np.argmax(mesh.vertices[sv, 2])])
    p = Palpation(mesh, tissue, rings=4, integrator="implicit", dt=5e-3, device=device)
    p.touch(top)
    forces = hold(p, DEPTH, 300, 40)
    assert np.all(np.isfinite(forces)) and finite_states(p)
    free = p.region.vertices()[: p.region.free_count]
    target = (p.rest_position() + p.inward_normal() * DEPTH).astype(np.float32).astype(np.float64)
    want = np.linalg.norm(static_reaction(mesh, tissue, top, target, free))
    np.testing.assert_allclose(np.linalg.norm(forces[-1]), want, rtol=1e-2)


@pytest.mark.parametrize("integrator", ["explicit", "implicit"])
def test_runaway_under_the_critical_step_is_not_blamed_on_dt(device, integrator):
    """A press 0.5 m deep into the 0.13 m stomach through the Python API (the command line refuses
    it): the state runs away, and the error said 'dt = 1 ms exceeds the critical step of about
    1.609 ms', which is false (and meaningless for the implicit integrator). It now says what
    happened."""
    from almsdm_warp.solvers.stepper import SimulationDiverged

    scene, mesh = scene_and_mesh()
    p = Palpation(mesh, scene.tissue, rings=4, integrator=integrator, dt=1e-3, device=device)
    sv = mesh.surface_vertices
    p.touch(int(sv[np.argmax(mesh.vertices[sv, 2])]))
    crit = p.model.critical_dt(p.region.vertices()[: p.region.free_count])
    assert p.dt < crit
    with pytest.raises(SimulationDiverged) as info:
        p.press(0.5, ramp=0.05, hold=0.01, settle=0.01)
    message = str(info.value)
    assert "exceeds the critical step" not in message, message
    assert "ran away" in message and "--dt-ms" in message and "shallower --depth-mm" in message and f"{crit * 1e3:.4g} ms" in message
    assert ("--integrator implicit" in message) == (integrator == "explicit")  # the remedies, not blame on the depth
