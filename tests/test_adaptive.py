"""The adaptive region (issue 7) against independent answers: the ring-motion kernel against a
float64 NumPy re-implementation, the fixed-ring estimate against the closed-form anchored chain,
the chosen region against the global anchored reference and every fixed ring count (the fewest
rings meeting the same tolerance), retirement, and `almsdm palpate --rings auto --tol-mm`.

Accuracy runs the short protocol of almsdm_warp.evaluation.adaptive_accuracy (10 mm, ramp 0.1 s, hold 0.2 s,
implicit, dt 5 ms: 60 steps, quasi-static at the end of the hold)."""

import json
import math

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import shortest_path
from test_simulation_press import scene_and_mesh, top_vertex

from almsdm_warp.protocol.adaptive import AdaptivePalpation, fixed_ring_estimate, hold_press
from almsdm_warp.mesh import primitives
from almsdm_warp.mesh.io import load_mesh
from almsdm_warp.tissue.material import Material
from conftest import SCENES
from almsdm_warp.evaluation.adaptive_accuracy import auto_point, fixed_point, global_reference
from almsdm_warp.cli.main import main
from almsdm_warp.kernels.region.ring_motion import eval_region_motion
from almsdm_warp.sim.model import PROBE_DISPLACEMENT
from almsdm_warp.protocol.palpation import Palpation

_references = {}


def reference(name, device):
    """The global anchored reference of a scene at its top vertex, once per session and device."""
    key = (name, device)
    if key not in _references:
        scene, mesh = scene_and_mesh(name)
        _references[key] = global_reference(mesh, scene.tissue, device)
    return _references[key]


def hops_from(mesh, seed):
    n = mesh.vertex_count
    e = mesh.edges.astype(np.int64)
    a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    return shortest_path(a, unweighted=True, directed=False, indices=seed)


def test_ring_motion_matches_numpy(device):
    """Per-ring maxima of |q - q_rest| and the fixed ring's Jacobi estimate, against float64 NumPy
    on a 3-ring stomach region after 30 steps of a press (a deformed, non-trivial state)."""
    scene, mesh = scene_and_mesh()
    v = top_vertex(mesh)
    p = Palpation(mesh, scene.tissue, rings=3, integrator="implicit", dt=5e-3, device=device)
    p.touch(v)
    rest, n = p.rest_position(), p.inward_normal()
    for s in range(30):
        p.set_probe(PROBE_DISPLACEMENT, rest + n * 0.01 * min((s + 1) / 20, 1.0))
        p.step()
    import warp as wp

    motion = wp.zeros(8, dtype=wp.float32, device=device)
    eval_region_motion(p.model, p.region, p.state, motion)
    got = motion.numpy()

    q = p.positions()
    q0 = mesh.vertices.astype(np.float32).astype(np.float64)
    hops = hops_from(mesh, v)
    disp = np.linalg.norm(q - q0, axis=1)
    expect_rings = [disp[hops == r].max() for r in range(3)]
    np.testing.assert_allclose(got[1:4], expect_rings, rtol=1e-5)
    assert np.all(got[4:-1] == 0.0) and expect_rings[2] > 1e-6  # the fixed ring and beyond: 0
    # Jacobi step at each fixed vertex, in float64
    t = scene.tissue
    e = mesh.edges.astype(np.int64)
    L0 = np.linalg.norm(q0[e[:, 1]] - q0[e[:, 0]], axis=1)
    best = energy = 0.0
    for f in np.flatnonzero(hops == 3):
        force = -t.anchor_stiffness * (q[f] - q0[f])
        D = t.anchor_stiffness * np.eye(3)
        for k in np.flatnonzero((e[:, 0] == f) | (e[:, 1] == f)):
            j = e[k, 1] if e[k, 0] == f else e[k, 0]
            r = q[j] - q[f]
            length = np.linalg.norm(r)
            d = r / length
            force += t.edge_stiffness * (length - L0[k]) * d
            D += t.edge_stiffness * np.outer(d, d)
        u_J = np.linalg.solve(D, force)
        best = max(best, np.linalg.norm(u_J))
        energy += force @ u_J
    assert best > 1e-7 and energy > 0.0
    np.testing.assert_allclose(got[0], best, rtol=1e-3)
    np.testing.assert_allclose(got[-1], energy, rtol=1e-3)  # sum of f . u_J over the fixed ring


@pytest.mark.parametrize("ka_over_k", [0.5, 2.0, 8.0])
def test_fixed_ring_estimate_is_exact_on_an_anchored_chain(ka_over_k):
    """A chain of springs k with anchors k_a, its end driven to 1: u_r = lambda^r with
    lambda / (1 + lambda^2) = k / (k_a + 2k). Truncated at N (u_N = 0), the Jacobi step at N and
    u_(N-1) give back the untruncated u_N up to the truncated chain's own normalization
    1 / (1 - lambda^(2N)) (it has u_r = (lambda^r - lambda^(2N-r)) / (1 - lambda^(2N))): a slight,
    conservative overestimate that vanishes with N (float64 linear solves)."""
    k, ka, length = 1.0, ka_over_k, 60
    lam = ((ka + 2 * k) - math.sqrt((ka + 2 * k) ** 2 - 4 * k * k)) / (2 * k)

    def solve(n_free):  # u_0 = 1 driven, u_1..u_(n_free) free, u_(n_free+1) = 0
        A = np.diag(np.full(n_free, ka + 2 * k)) - k * np.eye(n_free, k=1) - k * np.eye(n_free, k=-1)
        b = np.zeros(n_free)
        b[0] = k
        return np.concatenate([[1.0], np.linalg.solve(A, b), [0.0]])

    far = solve(length)  # effectively unbounded
    np.testing.assert_allclose(far[1:6], lam ** np.arange(1, 6), rtol=1e-9)
    for N in (2, 3, 5):
        u = solve(N - 1)
        jacobi = k * u[N - 1] / (ka + 2 * k)
        est, got_lam = fixed_ring_estimate(jacobi, u[N - 1])
        np.testing.assert_allclose(got_lam, lam, rtol=1e-9)
        np.testing.assert_allclose(est, far[N] / (1 - lam ** (2 * N)), rtol=1e-6)
        assert est >= far[N]
        assert u[N - 1] < far[N - 1]  # the truncated chain moves less: a plain read would underestimate
    assert fixed_ring_estimate(0.6, 1.0) == (math.inf, 1.0)  # no decay: grow
    assert fixed_ring_estimate(0.0, 0.0) == (0.0, 0.0)


@pytest.mark.parametrize("name", [None, "liver"], ids=["stomach", "liver"])
@pytest.mark.parametrize("tol_mm", [0.03, 0.3])
def test_auto_meets_tolerance_with_the_fewest_rings(device, name, tol_mm):
    """Against the global anchored model: peak-force error <= 1% and displacement error (all
    vertices, end of hold) <= tol, with no more vertices than the fewest fixed rings that meet the
    same tolerance; and one ring fewer than auto would not meet it (the comparison can fail)."""
    scene, mesh = scene_and_mesh(name)
    ref = reference(name, device)
    tol = tol_mm * 1e-3
    auto = auto_point(mesh, scene.tissue, tol, device, reference=ref)
    assert auto["force_error"] <= 0.01, auto
    assert auto["displacement_error_mm"] <= tol_mm, auto
    fixed = {}
    for rings in range(1, auto["rings"] + 1):
        fixed[rings] = fixed_point(mesh, scene.tissue, rings, device, reference=ref)
    meets = [r for r, f in fixed.items() if f["force_error"] <= 0.01 and f["displacement_error_mm"] <= tol_mm]
    assert meets, fixed
    assert auto["region_vertices"] <= fixed[min(meets)]["region_vertices"], (auto, fixed)
    below = fixed[auto["rings"] - 1]
    assert below["force_error"] > 0.01 or below["displacement_error_mm"] > tol_mm, below
    # the same model as the fixed ring count it chose, so the same quasi-static force
    np.testing.assert_allclose(auto["peak_force_N"], fixed[auto["rings"]]["peak_force_N"], rtol=2e-3)


def test_tighter_tolerance_grows_more_rings(device):
    """Rings grow as the tolerance tightens; the chart point also times a step (a positive median)."""
    scene, mesh = scene_and_mesh()
    ref = reference(None, device)
    points = [auto_point(mesh, scene.tissue, t * 1e-3, device, reference=ref, time_steps=(t == 0.1)) for t in (1.0, 0.1, 0.01)]
    rings = [p["rings"] for p in points]
    assert rings[0] < rings[1] < rings[2], rings
    sizes = [p["region_vertices"] for p in points]
    assert sizes[0] < sizes[1] < sizes[2], sizes
    assert math.isfinite(points[1]["step_us"]) and points[1]["step_us"] > 0
    assert "step_us" not in points[0]


@pytest.mark.parametrize("integrator", ["explicit", "implicit"])
def test_force_controlled_press_grows_like_a_displacement_press(device, integrator):
    """A force-controlled press (2.4 N) also grows the region, to the rings at which a fixed-ring
    force press reaches the same depth (within 0.5%)."""
    scene, mesh = scene_and_mesh()
    auto = AdaptivePalpation(mesh, scene.tissue, tol=5e-5, integrator=integrator, dt=1e-3, device=device)
    auto.touch(top_vertex(mesh))
    got = auto.press_force(2.4, ramp=0.1, hold=0.1, settle=0.2)
    rings = auto.press_log[0]["rings"]
    assert rings >= 3 and auto.retired
    fixed = Palpation(mesh, scene.tissue, rings=rings, integrator=integrator, dt=1e-3, device=device)
    fixed.touch(top_vertex(mesh))
    expected = fixed.press_force(2.4, ramp=0.1, hold=0.1, settle=0.2)
    np.testing.assert_allclose(got.depth, expected.depth, rtol=5e-3)
    assert 5e-3 < got.depth < 20e-3


@pytest.mark.parametrize("integrator", ["explicit", "implicit"])
def test_retired_at_rest_and_rebuilt_by_the_next_press(device, integrator):
    """After release the region relaxes within tol and is retired: every vertex exactly at rest,
    steps integrate nothing; the next press rebuilds it and is bit-identical to the first."""
    scene, mesh = scene_and_mesh()
    p = AdaptivePalpation(mesh, scene.tissue, tol=1e-4, integrator=integrator, dt=1e-3, device=device)
    p.touch(top_vertex(mesh))
    first = p.press(0.01, ramp=0.05, hold=0.05, settle=0.2)
    assert p.retired and p.region.vertex_count == 0
    assert [e["event"] for e in p.events][-1] == "retired"
    grown = p.press_log[0]["rings"]
    assert grown >= 2
    rest = p.model.particle_q_rest.numpy()
    for state in p.states:
        np.testing.assert_array_equal(state.particle_q.numpy(), rest)
        assert not state.particle_qd.numpy().any()
    np.testing.assert_array_equal(p.step(), 0.0)
    np.testing.assert_array_equal(p.states[0].particle_q.numpy(), rest)
    second = p.press(0.01, ramp=0.05, hold=0.05, settle=0.2)
    assert p.press_log[1]["rings"] == grown
    np.testing.assert_array_equal(second.force, first.force)
    # released, the retired region came back within tol (the residual it was retired at)
    moved = p.press_log[1]["events"][-1]["estimate_mm"]
    assert 0 < moved <= 0.1


def test_a_region_that_grows_plans_its_substeps_and_is_not_pressed_again(device, tmp_path, capsys):
    """A frame between 0.9 of the first region's critical step and 0.9 of the grown region's: the press
    starts at one substep, the grown region plans two for itself (it held: diverged_at is empty), and
    the command line says nothing of a divergence (it used to read any rise as one)."""
    scene, mesh = scene_and_mesh()
    probe = AdaptivePalpation(mesh, scene.tissue, tol=5e-5, dt=1e-3, device=device)
    probe.touch(top_vertex(mesh))
    first = probe.region_critical_dt()
    probe.press(0.01, ramp=0.1, hold=0.1, settle=0.2)
    grown = Palpation(mesh, scene.tissue, rings=probe.press_log[0]["rings"], dt=1e-3, device=device)
    grown.touch(top_vertex(mesh))
    dt = 0.9 * math.sqrt(first * grown.region_critical_dt())
    assert 0.9 * grown.region_critical_dt() < dt < 0.9 * first
    p = AdaptivePalpation(mesh, scene.tissue, tol=5e-5, dt=dt, device=device)
    p.touch(top_vertex(mesh))
    assert p.substeps == 1
    result = p.press(0.01, ramp=0.1, hold=0.1, settle=0.2)
    assert result.substeps == 2 and result.diverged_at == ()
    if device == "cpu":
        out = tmp_path / "auto.json"
        capsys.readouterr()
        assert main(["paper_stomach", "--rings", "auto", "--tol-mm", "0.05", "--dt-ms", f"{dt * 1e3!r}", "--ramp-s", "0.1",
                     "--hold-s", "0.1", "--settle-s", "0.2", "--json", str(out)]) == 0
        (press,) = json.loads(out.read_text())["presses"]
        assert press["substeps"] == 2 and press["pressed_again"] == 0
        assert "diverged" not in capsys.readouterr().out


def test_no_retirement_while_pressed_or_when_disabled(device):
    scene, mesh = scene_and_mesh()
    p = AdaptivePalpation(mesh, scene.tissue, tol=1e-4, integrator="implicit", dt=5e-3, device=device, retire=False)
    p.touch(top_vertex(mesh))
    p.press(0.01, ramp=0.05, hold=0.05, settle=0.3)
    assert not p.retired and p.region.vertex_count > 7


def test_auto_command_line(tmp_path):
    """--rings auto --tol-mm: the ring count and its reason in the summary line and the JSON, the
    count of each press; bad combinations exit 2 with nothing written."""
    out = tmp_path / "auto.json"
    assert main(["paper_stomach", "--rings", "auto", "--tol-mm", "0.05", "--presses", "2", "--settle-s", "0.3", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    model = data["model"]
    assert model["rings"] == "auto" and model["tol_mm"] == pytest.approx(0.05)
    assert isinstance(model["rings_chosen"], int) and model["rings_chosen"] >= 2
    assert "would move" in model["auto_reason"]
    assert [p["rings_chosen"] for p in data["presses"]] == [model["rings_chosen"]] * 2
    assert model["region_vertices"] > 7  # the region as grown, not as started
    assert model["auto_events"][0][-1]["event"] == "retired"
    for bad in (["--rings", "3", "--tol-mm", "0.1"], ["--rings", "auto", "--tol-mm", "0"], ["--rings", "autox"]):
        target = tmp_path / "bad.json"
        assert main([*bad, "--json", str(target)]) == 2
        assert not target.exists()


def test_auto_command_line_with_a_sphere(tmp_path):
    """--rings auto with --probe-radius-mm: the region grown from the sphere's patch (88 vertices at one
    ring, where the paper's one-vertex seed has 7), its peak force within 2% of the global model's (the
    static force is the same to 4 digits at 1 ring; the peak, at the ramp's end, 1.4% over: dampers
    near the fixed ring, which the static criterion does not see: docs/adaptive.md)."""
    out = {}
    for rings in ("auto", "global"):
        out[rings] = tmp_path / f"{rings}.json"
        extra = ["--tol-mm", "0.1"] if rings == "auto" else []
        assert main(["--rings", rings, *extra, "--probe-radius-mm", "10", "--depth-mm", "5", "--integrator", "implicit",
                     "--dt-ms", "5", "--settle-s", "0.05", "--json", str(out[rings])]) == 0
    auto, glob = (json.loads(out[r].read_text()) for r in ("auto", "global"))
    assert auto["model"]["probe_radius_mm"] == 10 and auto["model"]["rings_chosen"] >= 1
    assert auto["model"]["region_vertices"] > 7 * auto["model"]["rings_chosen"]
    force, reference = auto["presses"][0]["peak_force_N"], glob["presses"][0]["peak_force_N"]
    assert abs(force / reference - 1.0) <= 0.02, (force, reference)


def test_uncaptured_steps_and_checks_are_the_same(device):
    """capture=False (every launch from Python) grows the same region and gives the same bits."""
    scene, mesh = scene_and_mesh()
    results = []
    for capture in (True, False):
        p = AdaptivePalpation(mesh, scene.tissue, tol=3e-5, integrator="implicit", dt=5e-3, device=device, capture=capture)
        p.touch(top_vertex(mesh))
        results.append((p.press(0.01, ramp=0.1, hold=0.1, settle=0.2), p.press_log[0]))
    (a, log_a), (b, log_b) = results
    assert log_a == log_b and log_a["rings"] >= 3
    np.testing.assert_array_equal(a.force, b.force)
    np.testing.assert_array_equal(a.displacement, b.displacement)


# -- the material model: no anchors, supports; the sphere probe ------------------------------------
SOLID = Material(10e3, 0.45, 1000.0, rayleigh_beta=0.01)
"""E 10 kPa, nu 0.45, Rayleigh d = 0.01 s x k: tets whose only support is the fixed plane."""


def material_press(mesh, rings, device, radius, depth, fixed_below, tol=1e-4, law=None):
    """(|force| at the end of the hold [N], the palpation) of a quasi-static press (implicit, dt 5 ms, ramp
    0.1 s, hold 0.2 s): the force of the region as grown (the peak, at the ramp's end, can precede growth);
    law: the tissue law (None: the default, neo-Hookean tets on these meshes)."""
    kw = dict(integrator="implicit", dt=5e-3, device=device, fixed_below=fixed_below, probe_radius=radius, law=law)
    if rings == "auto":
        pal = AdaptivePalpation(mesh, SOLID, tol=tol, retire=False, **kw)
    else:
        pal = Palpation(mesh, SOLID, rings=rings, **kw)
    pal.touch(top_vertex(mesh))
    hold_press(pal, depth, 0.1, 0.2)
    return float(np.linalg.norm(pal.feedback_force)), pal


def test_sphere_auto_meets_the_force_tolerance_on_a_supported_liver(device):
    """The liver scene's tets with the material model and no anchors, held below z = -25 mm, a sphere of
    10 mm pressed 5 mm: the adaptive region's force within 1% of the global model's (every vertex free),
    where 2 fixed rings are 5% over; the region grew from the sphere's patch and kept it as ring 0."""
    mesh = load_mesh(SCENES / "liver.vtu")
    reference, _ = material_press(mesh, "global", device, 0.01, 0.005, -0.025)
    two, _ = material_press(mesh, 2, device, 0.01, 0.005, -0.025)
    assert two / reference - 1.0 > 0.03  # the comparison can fail: a small region is too stiff
    force, auto = material_press(mesh, "auto", device, 0.01, 0.005, -0.025)
    assert abs(force / reference - 1.0) <= 0.01, (force, reference, auto.auto_reason)
    assert auto.rings_chosen > 2 and not auto.whole
    ring = auto.region.vertex_ring.numpy()
    patch = auto.sphere_patch(auto.vertex, 0.005)
    np.testing.assert_array_equal(np.flatnonzero(ring == 0), patch)


def test_auto_frees_the_whole_ball_when_no_fixed_ring_is_enough(device):
    """A tet ball held below z = -40 mm pressed 2 mm at its top by the paper's probe (R = 0): even a
    region of the whole ball with its last ring fixed is over 1% stiff; auto grows to the whole ball,
    frees it and gives the global model's force."""
    mesh = primitives.tet_ball(50.0, 12.0, refine_top=4.0)
    reference, _ = material_press(mesh, "global", device, 0.0, 0.002, -0.04, law="springs")
    last, fixed = material_press(mesh, 64, device, 0.0, 0.002, -0.04, law="springs")
    assert fixed.region.vertex_count == mesh.vertex_count and last / reference - 1.0 > 0.01
    force, auto = material_press(mesh, "auto", device, 0.0, 0.002, -0.04, law="springs")
    assert auto.whole and "all of it free" in auto.auto_reason
    np.testing.assert_allclose(force, reference, rtol=5e-3)  # 0.2%: freed late in the ramp, settling in the hold
