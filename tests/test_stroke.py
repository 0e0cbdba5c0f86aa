"""A probe that moves: spheres driven along a path, the local region following the contact.

Against independent answers: a sphere sliding over a bed of anchors (Winkler's foundation: the
quadrature of test_probe_sphere, which a frictionless slide must not change), the global model
(every vertex free) over the same stroke for continuity, superposition for two probes on that bed.
"""

import math

import numpy as np
import pytest

from almsdm_warp.mesh import primitives
from almsdm_warp.protocol.stroke import ProbeStroke, builtin_stroke
from almsdm_warp.tissue.params import TissueParams
from test_probe_sphere import KAPPA, anchor_references, flat_grid

R, DEPTH = 0.01, 0.0005
"""The sphere [m] and its press [m] on the anchor bed: contact radius 3.1 mm, about 120 vertices touch."""


@pytest.fixture(scope="module")
def bed():
    """A 20 mm square (spacing 0.5 mm) whose vertices hold only anchors KAPPA x area, critically damped."""
    mesh = flat_grid(41, 20.0)
    density, thickness = 1000.0, 0.025
    area = mesh.vertex_masses(density, thickness) / (density * thickness)
    tissue = TissueParams(density=density, thickness=thickness, edge_stiffness=1e-6, edge_damping=0.0,
                          anchor_stiffness=KAPPA, anchor_damping=2.0 * math.sqrt(KAPPA * density * thickness))
    return mesh, tissue, area


def vertex_at(mesh, x_mm, y_mm):
    return int(np.argmin(np.linalg.norm(mesh.vertices[:, :2] - np.array([x_mm, y_mm]) * 1e-3, axis=1)))


@pytest.mark.parametrize("integrator, substeps", [("explicit", "auto"), ("explicit", 4), ("implicit", "auto")])
def test_sliding_on_anchors_keeps_winklers_force(device, bed, integrator, substeps):
    # with 4 substeps a frame, a sphere that took the whole frame's move at the first substep pushed
    # 14% off Winkler's force while sliding: the first-order hold spreads the move (measured 0.3%)
    mesh, tissue, area = bed
    path = builtin_stroke(mesh, R, depth=DEPTH, length=8e-3, speed=10e-3, vertex=vertex_at(mesh, -4, 0), hold=0.05)
    stroke = ProbeStroke(mesh, tissue, probe_radius=R, rings=2, device=device, anchor_scale=area, integrator=integrator,
                         substeps=substeps)
    force = np.array([stroke.step(c) for c in path.centre])
    _, radial = anchor_references(R, DEPTH)
    held = force[np.flatnonzero(path.phase == 0)[-1], 2]
    # pressed and held: the grid's sum of anchors against the quadrature (a midpoint rule: measured 0.09%)
    np.testing.assert_allclose(held, radial, rtol=0.005)
    # sliding: a frictionless sphere over a foundation pushes as it does at rest (measured within 0.31%;
    # the grid passing under the sphere and the anchors' dampers are what is left; their drag: 1%), with
    # either integrator (an implicit step that lets the trailing vertices relax inside the sphere read
    # a force short of the static one)
    slide = force[path.phase == 1][50:]
    np.testing.assert_allclose(slide[:, 2], held, rtol=0.015)
    assert np.abs(slide[:, :2]).max() < 0.03 * held
    assert stroke.relocations >= 2  # the region moved with the sphere (the bed is 16 spacings across the slide)
    # lifted: no vertex touches, no force
    assert stroke.touching[0] == 0 and np.all(force[-1] == 0.0)


def test_two_probes_superpose_on_anchors(device, bed):
    mesh, tissue, area = bed
    one = builtin_stroke(mesh, R, depth=DEPTH, length=2e-3, speed=10e-3, vertex=vertex_at(mesh, -4.5, 0), hold=0.05)
    two = builtin_stroke(mesh, R, depth=DEPTH, length=2e-3, speed=10e-3, vertex=vertex_at(mesh, 4.5, 0), hold=0.05,
                         direction=(-1.0, 0.0, 0.0))
    pair = ProbeStroke(mesh, tissue, probe_radius=R, rings=2, device=device, anchor_scale=area, probes=2)
    single = ProbeStroke(mesh, tissue, probe_radius=R, rings=2, device=device, anchor_scale=area)
    for a, b in zip(one.centre, two.centre):
        f2 = pair.step(np.stack([a, b]))
        f1 = single.step(a)
    # the bed's vertices do not touch each other (springs 1e-6 N/m): each sphere feels only its own
    # anchors, as it would alone, and the two mirror each other
    np.testing.assert_allclose(f2[0], f1, rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(f2[1] * [-1, 1, 1], f2[0], rtol=1e-3, atol=1e-6)
    assert f1[2] > 0.5 * anchor_references(R, DEPTH)[1] or np.all(f1 == 0)
    assert set(pair.touching.tolist()) == {0}  # both lifted at the end


def test_stroke_follows_the_global_model_and_recontacts(device):
    # a stroke over a sphere of the paper's tissue, a lift, and a touch-down elsewhere: the local model
    # against the global one (every vertex free), step by step
    mesh = primitives.icosphere(40.0, 3)
    path = builtin_stroke(mesh, R, depth=8e-3, length=30e-3, speed=40e-3, settle=0.05)
    far = int(np.argmax(mesh.vertices[:, 1]))  # on the equator, 90 degrees from the stroke
    again = builtin_stroke(mesh, R, depth=5e-3, length=1e-3, speed=40e-3, vertex=far, direction=(0.0, 0.0, 1.0))
    centres = np.concatenate([path.centre, again.centre])
    runs = {}
    for rings in (3, "global"):
        stroke = ProbeStroke(mesh, probe_radius=R, rings=rings, device=device)
        force, move, relocated = np.zeros((len(centres), 3)), np.zeros(len(centres)), []
        q0 = stroke.positions()
        for k, c in enumerate(centres):
            before = stroke.relocations
            force[k] = stroke.step(c)
            q = stroke.positions()
            move[k] = np.linalg.norm(q - q0, axis=1).max()
            q0 = q
            if stroke.relocations != before:
                relocated.append(k)
        runs[rings] = force, move, relocated, stroke
    f, move, relocated, stroke = runs[3]
    g, move_g, _, _ = runs["global"]
    assert len(relocated) >= 3 and relocated[-1] >= len(path.t)  # moved while sliding, and to the new touch
    rms = np.sqrt(np.mean(np.sum((f - g) ** 2, axis=1)) / np.mean(np.sum(g**2, axis=1)))
    assert rms < 0.02
    for k in relocated[:-1]:  # no jump of the force where the region moved while pressing
        assert np.linalg.norm(f[k] - f[k - 1]) < 0.05 * np.linalg.norm(f[k])
        assert np.linalg.norm(f[k + 1] - f[k]) < 0.05 * np.linalg.norm(f[k + 1])
    assert move.max() < 1e-4 and move.max() < move_g.max() + 1e-5  # no vertex pops, at a relocation or elsewhere
    lifted = np.flatnonzero(path.phase == 2)[-1]
    assert np.all(f[lifted] == 0.0) and np.all(g[lifted] == 0.0)
    pressed = len(path.t) + np.flatnonzero(again.phase == 1)[-1]  # the new touch, pressed 5 mm
    np.testing.assert_allclose(np.linalg.norm(f[pressed]), np.linalg.norm(g[pressed]), rtol=0.02)
    assert np.linalg.norm(f[pressed]) > 0.5


def test_bad_input_names_the_value(bed):
    mesh, tissue, area = bed
    with pytest.raises(ValueError, match="probe_radius"):
        ProbeStroke(mesh, tissue, probe_radius=0.0)
    with pytest.raises(ValueError, match="probes"):
        ProbeStroke(mesh, tissue, probe_radius=R, probes=0)
    with pytest.raises(ValueError, match="rings"):
        ProbeStroke(mesh, tissue, probe_radius=R, rings="global-free")
    with pytest.raises(ValueError, match="implicit integrator holds one sphere"):
        ProbeStroke(mesh, tissue, probe_radius=R, probes=2, integrator="implicit")
    stroke = ProbeStroke(mesh, tissue, probe_radius=R, probes=2, device="cpu")
    with pytest.raises(ValueError, match=r"shape \(2, 3\)"):
        stroke.step([0.0, 0.0, 0.01])
    with pytest.raises(ValueError, match="finite"):
        stroke.step([[0.0, 0.0, math.nan], [0.0, 0.0, 0.01]])
    with pytest.raises(ValueError, match="speed"):
        builtin_stroke(mesh, R, speed=0.0)


def test_relocations_replay_the_frames_captured_at_the_start(device, monkeypatch):
    # the explicit frame reads the region's counts from device arrays: the graphs captured at the
    # first step (one per region buffer and state) must step every later region as an uncaptured run
    # does, bit for bit (a graph that kept the first region's counts would integrate the wrong vertices)
    mesh = primitives.icosphere(40.0, 3)
    path = builtin_stroke(mesh, R, depth=6e-3, length=20e-3, speed=40e-3)
    captures = []
    capture = ProbeStroke._capture
    monkeypatch.setattr(ProbeStroke, "_capture", lambda self, frame: captures.append(self.relocations) or capture(self, frame))
    runs = []
    for captured in (True, False):
        stroke = ProbeStroke(mesh, probe_radius=R, rings=3, device=device, capture=captured)
        runs.append((np.array([stroke.step(c) for c in path.centre]), stroke.positions(), stroke.relocations))
    (f, q, moved), (f0, q0, moved0) = runs
    assert moved == moved0 >= 2
    assert captures == [0, 0, 0, 0]  # two buffers x two states, before the region first moved
    np.testing.assert_array_equal(f, f0)
    np.testing.assert_array_equal(q, q0)
    assert np.linalg.norm(f[path.phase == 1], axis=1).min() > 0.1  # pressed all along the slide


def test_a_build_spread_over_steps_is_the_same_region(device):
    # ring 1 without its local indices and springs, then the other rings: the region one build makes
    from almsdm_warp.region.region import Region

    mesh = primitives.icosphere(40.0, 3)
    seeds = np.array([0, 5, 17, 40])
    spread = Region(mesh, device).build_seeds(seeds, 1, contact=5, index=False).expand(3)
    whole = Region(mesh, device).build_seeds(seeds, 4, contact=5)
    np.testing.assert_array_equal(spread.vertices(), whole.vertices())
    np.testing.assert_array_equal(spread.vertex_local.numpy(), whole.vertex_local.numpy())
    np.testing.assert_array_equal(spread.boundary(), whole.boundary())
    np.testing.assert_array_equal(np.sort(spread.springs()), np.sort(whole.springs()))
    assert spread.free_count == whole.free_count and spread.spring_count == whole.spring_count


def test_a_jump_of_a_radius_while_touching_or_into_the_organ_is_refused(bed):
    # the travel check: a sphere that moves its radius or more in one step while it touches the organ,
    # or onto it, would pass through vertices; a lifted sphere may jump clear of the organ
    mesh, tissue, area = bed
    c = np.array([0.0, 0.0, R - 1e-4])  # the bed lies in z = 0: 0.1 mm in, less than the guard (a quarter mm)
    for jump in (0.99, 1.001):
        stroke = ProbeStroke(mesh, tissue, probe_radius=R, rings=2, device="cpu", anchor_scale=area)
        stroke.step([0.0, 0.0, R + 1e-3])  # 1 mm clear of it
        stroke.step(c)
        assert stroke.touching[0] > 0  # touching, not inside
        if jump < 1.0:
            stroke.step(c + [jump * R, 0.0, 0.0])  # under a radius: a step, however fast
            continue
        with pytest.raises(ValueError, match=r"would move 10(\.\d+)? mm in one step of 1 ms while it touches the organ"):
            stroke.step(c + [jump * R, 0.0, 0.0])

    lifted = ProbeStroke(mesh, tissue, probe_radius=R, rings=2, device="cpu", anchor_scale=area)
    above = np.array([0.0, 0.0, 3.0 * R])  # the bed lies in z = 0: the sphere is 2 R clear of it
    lifted.step(above)
    lifted.step(above + [3.0 * R, 0.0, 0.0])  # a jump of 3 R, clear of the organ: allowed
    assert lifted.touching[0] == 0
    with pytest.raises(ValueError, match="into the organ"):
        lifted.step(above + [3.0 * R, 0.0, -2.5 * R])  # 2.5 R down, its centre 0.5 R above the bed: inside
    with pytest.raises(ValueError, match="starts .* inside the organ"):
        ProbeStroke(mesh, tissue, probe_radius=R, rings=2, device="cpu", anchor_scale=area).step([0.0, 0.0, 0.5 * R])


@pytest.mark.parametrize("bad", ["nan", "far"])
def test_a_state_that_ran_away_is_found_within_the_check_period(device, bed, bad):
    # a vertex outside the region, which no force reads, made not finite (or put three mesh sizes away):
    # the state check finds it within CHECK_EVERY steps, whichever step it starts at
    from almsdm_warp.protocol.stroke import CHECK_EVERY
    from almsdm_warp.solvers.stepper import SimulationDiverged

    mesh, tissue, area = bed
    path = builtin_stroke(mesh, R, depth=DEPTH, length=2e-3, speed=10e-3, vertex=vertex_at(mesh, 0, 0), hold=0.2)
    held = np.flatnonzero(path.phase == 0)
    for start in (held[-CHECK_EVERY - 5], held[-CHECK_EVERY - 5] + CHECK_EVERY // 2):
        stroke = ProbeStroke(mesh, tissue, probe_radius=R, rings=2, device=device, anchor_scale=area)
        for c in path.centre[:start]:
            stroke.step(c)
        outside = np.setdiff1d(np.arange(len(mesh.vertices)), stroke.region_vertex_ids())
        v = int(outside[len(outside) // 2])
        for state in stroke.states:
            q = state.particle_q.numpy()
            q[v] = math.nan if bad == "nan" else q[v] + [0.0, 0.0, 3.0 * np.ptp(mesh.vertices, axis=0).max()]
            state.particle_q.assign(q)
        steps = 0
        with pytest.raises(SimulationDiverged, match="ran away|diverged"):
            for c in path.centre[start : start + CHECK_EVERY]:
                steps += 1
                stroke.step(c)
        assert 1 <= steps <= CHECK_EVERY


def test_the_seeds_are_the_surface_near_each_centre_and_the_wake(device):
    # brute force over every surface vertex: those within radius + lead of a centre (or a centre's nearest where
    # none is), and the region's free vertices still moving (off rest by more than tol, or faster than tol / WAKE_TIME)
    from almsdm_warp.protocol.stroke import WAKE_TIME

    mesh = primitives.icosphere(40.0, 3)
    path = builtin_stroke(mesh, R, depth=6e-3, length=20e-3, speed=40e-3)
    stroke = ProbeStroke(mesh, probe_radius=R, rings=3, device=device, probes=2)
    surface = mesh.surface_vertices
    far = np.array([0.0, 0.0, 0.2])  # the second sphere 0.2 m up: no surface vertex within its reach
    checked = 0
    for k, c in enumerate(path.centre):
        centres = np.stack([c, far])
        stroke.step(centres)
        if k % 15:
            continue
        got = stroke.seeds(centres)
        dist = np.linalg.norm(mesh.vertices[surface][None] - centres[:, None], axis=2)  # [centre, surface vertex]
        want = set(surface[np.flatnonzero((dist <= stroke.radius + stroke.lead).any(axis=0))])
        want |= {int(surface[np.argmin(d)]) for d in dist if not (d <= stroke.radius + stroke.lead).any()}
        free = stroke.region.vertices()[: stroke.region.free_count]
        q, qd = stroke.positions()[free], stroke.state.particle_qd.numpy()[free]
        off = np.linalg.norm(q - mesh.vertices[free], axis=1) > stroke.tol
        want |= set(free[off | (np.linalg.norm(qd, axis=1) * WAKE_TIME > stroke.tol)].tolist())
        assert set(got.tolist()) == want and len(got) == len(want)
        checked += 1
    assert checked >= 5


def test_a_hovering_sphere_moves_the_region_where_the_nearest_vertex_query_would(bed):
    """A lifted sphere's check (_needs_move) keeps a bound of its clearance from the surface outside the
    region's inner rings instead of a k-d tree query each step: along a hovering path of small steps
    and jumps, over the region and past it, it answers as the query of the nearest surface vertex does."""
    mesh, tissue, area = bed
    stroke = ProbeStroke(mesh, tissue, probe_radius=R, rings=3, device="cpu", anchor_scale=area)
    stroke.step([0.0, 0.0, R + 1e-3])
    stroke.step([0.0, 0.0, R - DEPTH])  # a region around the centre
    rng = np.random.default_rng(7)
    steps = rng.normal(scale=5e-5, size=(3000, 3))
    steps[::250] += rng.normal(scale=2e-3, size=(12, 3))  # some jumps
    path = np.cumsum(steps, axis=0) + [0.0, 0.0, R + 4e-4]
    path[:, :2] = np.clip(path[:, :2], -0.012, 0.012)
    path[:, 2] = np.clip(path[:, 2], R - 2e-4, R + 2e-3)  # hovering, sometimes within reach of the surface
    stroke._touching[:] = 0
    stroke._near[:] = 0
    reach = stroke.radius + stroke.guard

    def nearest_query(c):  # the check before the bound: the nearest surface vertex, if outside the inner rings
        d, k = stroke._tree.query(c)
        ring = stroke._ring_of[stroke._surface[k]]
        if d < reach and (ring < 0 or ring >= stroke._near_ring):
            return "now" if d < stroke.radius else "soon"
        return None

    got = [stroke._needs_move(c[None, :]) for c in path]
    want = [nearest_query(c) for c in path]
    assert got == want
    assert {"now", "soon", None} <= set(want)  # the path reaches the surface outside the inner rings, near it and clear of it
