"""Determinism: the same inputs give the same bits, run to run, on every device; and the CPU and
a CUDA device agree within 1e-5 relative.

test_simulation_press.py already checks one fresh press twice (bit-identical) and the peak
force and force trace of one stomach press on CPU against CUDA. Here: a whole session (press,
expansion mid-hold, relocation, force control, relocation back) twice; region building and
contact queries (integer compare-and-swap and atomic appends on CUDA, in thread order) against
their defined order; two separate processes with different hash seeds; and CPU against CUDA for
the volume scene, the global model, every vertex's position and the integer outputs.
"""

import hashlib
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import ROOT
from scipy.sparse.csgraph import breadth_first_order, shortest_path
from test_simulation_press import scene_and_mesh

from almsdm_warp import Region, find_contacts
from almsdm_warp.sim.model import PROBE_DISPLACEMENT
from almsdm_warp.protocol.palpation import Palpation

DEPTH = 8.0e-3


def far_apart(mesh):
    """Two surface vertices: the highest, and the one farthest from it."""
    sv = mesh.surface_vertices
    a = int(sv[np.argmax(mesh.vertices[sv, 2])])
    b = int(sv[np.argmax(np.linalg.norm(mesh.vertices[sv] - mesh.vertices[a], axis=1))])
    return a, b


def session(name, integrator, device, rings=3, dt=1e-3):
    """A session as a trainer drives one: press at a, expand mid-hold, release; relocate to b,
    force-controlled press; relocate back to a, press. Everything the host sees, as one array,
    and the final states."""
    scene, mesh = scene_and_mesh(name)
    a, b = far_apart(mesh)
    p = Palpation(mesh, scene.tissue, rings=rings, integrator=integrator, dt=dt, device=device)
    trace = []
    p.touch(a)
    rest, n = p.rest_position(), p.inward_normal()
    for s in range(60):
        p.set_probe(PROBE_DISPLACEMENT, rest + n * DEPTH * min((s + 1) / 40, 1.0))
        trace.append(np.array(p.step()))
        if s == 45:
            p.expand(1)
    trace.append(p.press(DEPTH, 0.02, 0.01, 0.03).force[:, None].repeat(3, axis=1))
    p.touch(b)
    r = p.press_force(1.5, 0.03, 0.02, 0.03)
    trace.append(np.stack([r.force, r.displacement, r.displacement], axis=1))
    p.touch(a)
    r = p.press(DEPTH, 0.03, 0.02, 0.03)
    trace.append(np.stack([r.force, r.displacement, r.displacement], axis=1))
    trace = np.vstack([np.atleast_2d(t) for t in trace]).astype(np.float64)
    states = [np.concatenate([st.particle_q.numpy(), st.particle_qd.numpy()]) for st in p.states]
    return trace, states, p


@pytest.mark.parametrize("name, integrator", [(None, "explicit"), ("liver", "implicit")], ids=["stomach-explicit", "liver-implicit"])
def test_a_whole_session_twice_is_bit_identical(device, name, integrator):
    first_trace, first_states, p = session(name, integrator, device)
    assert np.all(np.isfinite(first_trace)) and first_trace[:, 0].max() > 0.5  # not vacuous: it pressed
    second_trace, second_states, _ = session(name, integrator, device)
    np.testing.assert_array_equal(first_trace, second_trace)
    for x, y in zip(first_states, second_states):
        np.testing.assert_array_equal(x, y)


def bfs_rings(mesh, seed, rings):
    """Ring of every vertex by scipy's breadth-first search (-1 beyond `rings`)."""
    e = mesh.edges
    n = mesh.vertex_count
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    hops = shortest_path(g, directed=False, unweighted=True, indices=seed)
    ring = np.where(np.isfinite(hops) & (hops <= rings), hops, -1).astype(np.int64)
    assert len(breadth_first_order(g, seed, directed=False, return_predecessors=False)) > 1
    return ring


@pytest.mark.parametrize("name", [None, "liver"], ids=["stomach", "liver"])
def test_region_order_is_defined_not_thread_order(device, name):
    """Rings are claimed by compare-and-swap and appended by atomic counters (thread order on
    CUDA), then sorted: the region's vertices are ring after ring, each by vertex id, and its
    springs in owner order: the same arrays on every build, whatever was built before."""
    _, mesh = scene_and_mesh(name)
    region = Region(mesh, device)
    seeds = mesh.surface_vertices[:: max(len(mesh.surface_vertices) // 12, 1)][:12]
    first = {}
    for rep in range(2):
        for seed in (seeds if rep == 0 else seeds[::-1]):
            region.build(int(seed), 5)
            got = (region.vertices(), region.springs(), region.region_edge_local.numpy()[: region.spring_count].copy(),
                   region.vertex_local.numpy().copy())
            if rep == 0:
                ring = bfs_rings(mesh, int(seed), 5)
                inside = np.flatnonzero(ring >= 0)
                want = inside[np.lexsort((inside, ring[inside]))]
                np.testing.assert_array_equal(got[0], want)
                first[int(seed)] = got
            else:
                for x, y in zip(first[int(seed)], got):
                    np.testing.assert_array_equal(x, y)


def test_contacts_are_the_same_every_query(device):
    """A batch of probes (some on ties between vertices) twice, and one by one: the same faces,
    points and vertices."""
    _, mesh = scene_and_mesh()
    rng = np.random.default_rng(7)
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    probes = rng.uniform(lo - 0.02, hi + 0.02, size=(200, 3))
    e = mesh.edges[:20]
    probes[:20] = 0.5 * (mesh.vertices[e[:, 0]] + mesh.vertices[e[:, 1]])  # equidistant from two vertices
    a, b = find_contacts(mesh, probes, device=device), find_contacts(mesh, probes, device=device)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    for k in (0, 5, 150):
        one = find_contacts(mesh, probes[k], device=device)
        assert one.vertex == a.vertex[k] and one.face == a.face[k]
        np.testing.assert_array_equal(one.point, a.point[k])


_SCRIPT = textwrap.dedent(
    """
    import hashlib, sys
    sys.path.insert(0, {tests!r})
    import test_determinism as t
    for name, integrator in ((None, "explicit"), ("liver", "implicit")):
        trace, states, _ = t.session(name, integrator, {device!r})
        print(hashlib.sha256(trace.tobytes() + b"".join(s.tobytes() for s in states)).hexdigest())
    """
)


def digests(device):
    out = []
    for name, integrator in ((None, "explicit"), ("liver", "implicit")):
        trace, states, _ = session(name, integrator, device)
        out.append(hashlib.sha256(trace.tobytes() + b"".join(s.tobytes() for s in states)).hexdigest())
    return out


def test_separate_processes_give_the_same_bits(device):
    """A fresh process with another hash seed (set and dict order of strings, module load
    order, a cold DeviceMesh cache) and this one: the same digest of a whole session."""
    here = digests(device)
    script = _SCRIPT.format(tests=str(ROOT / "tests"), device=device)
    for seed in ("2024" if os.environ.get("PYTHONHASHSEED") != "2024" else "1",):
        env = dict(os.environ, PYTHONHASHSEED=seed,
                   PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
        r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, env=env, timeout=300)
        assert r.returncode == 0, r.stderr
        assert r.stdout.split() == here, (seed, r.stdout, here)


# -- CPU against CUDA ----------------------------------------------------------------------------
def test_cpu_and_cuda_agree_on_every_output(device):
    """The same session on this CUDA device and on the CPU: integer outputs (regions, contacts)
    equal; forces within 1e-5 of the peak, and every vertex's position within 1e-5 of the press
    depth; for the surface scene (explicit), the volume scene (implicit), and the global model."""
    if device == "cpu":
        pytest.skip("compares a CUDA device with the CPU")
    for name, integrator in ((None, "explicit"), ("liver", "implicit")):
        cpu_trace, cpu_states, cpu = session(name, integrator, "cpu")
        gpu_trace, gpu_states, gpu = session(name, integrator, device)
        np.testing.assert_array_equal(gpu.region.vertices(), cpu.region.vertices())
        np.testing.assert_array_equal(gpu.region.springs(), cpu.region.springs())
        peak = np.abs(cpu_trace[:, 0]).max()
        np.testing.assert_allclose(gpu_trace[:, 0], cpu_trace[:, 0], rtol=0, atol=1e-5 * peak, err_msg=str(name))
        for x, y in zip(gpu_states, cpu_states):
            n = len(x) // 2
            np.testing.assert_allclose(x[:n], y[:n], rtol=0, atol=1e-5 * DEPTH, err_msg=str(name))
    _, mesh = scene_and_mesh()
    probes = np.random.default_rng(3).uniform(mesh.vertices.min(axis=0) - 0.01, mesh.vertices.max(axis=0) + 0.01, size=(100, 3))
    c, g = find_contacts(mesh, probes, device="cpu"), find_contacts(mesh, probes, device=device)
    np.testing.assert_array_equal(g.vertex, c.vertex)
    np.testing.assert_allclose(g.point, c.point, rtol=0, atol=1e-7)
    scene, mesh = scene_and_mesh()
    a, _ = far_apart(mesh)
    results = []
    for d in ("cpu", device):
        p = Palpation(mesh, scene.tissue, rings="global", integrator="explicit", dt=1e-3, device=d)
        p.touch(a)
        results.append((p.press(DEPTH, 0.05, 0.02, 0.05), p.positions()))
    (rc, qc), (rg, qg) = results
    np.testing.assert_allclose(rg.force, rc.force, rtol=0, atol=1e-5 * rc.peak_force_N)
    np.testing.assert_allclose(qg, qc, rtol=0, atol=1e-5 * DEPTH)
