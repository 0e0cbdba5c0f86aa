"""Throughput measurements: one palpation's step, a batch's region-steps, the global model, a peer.

Used by ``almsdm bench`` and scripts/bench_*.py. Benchmarks, not tests: each measurement warms
up first (kernel compilation stays out of the timed part), synchronizes the device before it
reads the clock, and reports medians.
"""

from __future__ import annotations

import statistics
import time

import numpy as np
import warp as wp


def top_vertex(mesh) -> int:
    """The highest surface vertex: where the single-palpation benchmarks press."""
    return int(mesh.surface_vertices[np.argmax(mesh.vertices[mesh.surface_vertices, 2])])


def measure(mesh, rings, integrator, device, blocks, steps=2000):
    """One palpation: probe held 5 mm in, `blocks` blocks of `steps` Palpation.step() calls, each
    replaying the captured graph and reading the feedback force through the host view."""
    from ..protocol.palpation import Palpation

    pal = Palpation(mesh, None, rings=rings, integrator=integrator, dt=1e-3, device=device)
    pal.touch(top_vertex(mesh))
    pal.set_probe(1, pal.rest_position() + pal.inward_normal() * 0.005)
    for _ in range(min(500, steps)):
        pal.step()
    per_step = []
    force = 0.0
    for _ in range(blocks):
        t0 = time.perf_counter()
        for _ in range(steps):
            f = pal.step()
            force = f[2]  # read every step
        per_step.append((time.perf_counter() - t0) / steps)
    assert np.isfinite(force)
    return {
        "rings": rings,
        "integrator": integrator,
        "region_vertices": pal.region_vertices,
        "free_vertices": pal.solver.free_count,
        "step_us_median": statistics.median(per_step) * 1e6,
        "step_us_best": min(per_step) * 1e6,
        "steps_per_s": 1.0 / statistics.median(per_step),
        "cg_iterations": pal.solver.cg_stats[0] if integrator == "implicit" else None,
    }


def spread_vertices(mesh, count: int) -> np.ndarray:
    """`count` contact vertices: the surface vertices in a fixed shuffled order, repeated as needed."""
    surface = np.random.default_rng(0).permutation(mesh.surface_vertices)
    return np.resize(surface, count).astype(np.int64)


def measure_batch(mesh, rings, batch, device, *, steps=1000, repeats=5, threads=None, model=None, dt=1e-3, kernel=None):
    """Region-steps per second of BatchPalpation: `batch` presses of `steps` steps of `dt` (10 mm
    ramp over the first 100 steps, then held), timed between device synchronizations; the median
    of `repeats`."""
    from ..batch.batch_palpation import BatchPalpation
    bp = BatchPalpation(mesh, rings=rings, dt=dt, device=device, threads=threads, model=model, kernel=kernel)
    t0 = time.perf_counter()
    bp.touch(spread_vertices(mesh, batch))
    wp.synchronize_device(bp.device)
    build_s = time.perf_counter() - t0
    bp.depth, bp.ramp_steps, bp.press_steps = 0.01, 100, steps
    bp.launch_steps(0, 2)  # compile and load
    wp.synchronize_device(bp.device)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        bp.launch_steps(0, steps)
        wp.synchronize_device(bp.device)
        times.append(time.perf_counter() - t0)
    t = statistics.median(times)
    f = bp.hold_reaction.numpy()
    return {
        "rings": rings,
        "batch": batch,
        "region_steps_per_s": batch * steps / t,
        "step_us_median": t / steps * 1e6,
        "threads": bp.threads,
        "kernel": bp.kernel,
        "shared": bp.shared,
        "build_ms": build_s * 1e3,
        "region_vertices_max": int(bp.region_vertex_counts.max()),
        "finite": bool(np.all(np.isfinite(f))),
    }


def measure_newton(mesh, device, steps=2000):
    """newton's semi-implicit spring solver on the same particles and springs (the whole mesh,
    anchors left out: newton has no per-particle anchor spring), or why it was skipped.

    Set up as newton's users set up springs alone: no gravity, no triangles (so no triangle
    contact), no bodies, no contacts, and particle-particle contact off (``model.particle_grid =
    None``, which SolverSemiImplicit.step checks before it launches its hash-grid contact kernel):
    the timed step is newton's spring forces and integration, what our step computes."""
    try:
        import newton
    except ImportError:
        return {"skipped": "newton is not installed (pip install newton)"}
    try:
        from ..tissue.params import TissueParams

        t = TissueParams()
        builder = newton.ModelBuilder(gravity=(0.0, 0.0, 0.0))
        mass = mesh.vertex_masses(t.density, t.thickness)
        for p, m in zip(mesh.vertices, mass):
            builder.add_particle(tuple(map(float, p)), (0.0, 0.0, 0.0), float(m))
        for a, b in mesh.edges:
            builder.add_spring(int(a), int(b), t.edge_stiffness, t.edge_damping, control=0.0)
        model = builder.finalize(device=device)
        model.particle_grid = None  # no particle-particle contact: springs alone
        solver = newton.solvers.SolverSemiImplicit(model)
        s0, s1 = model.state(), model.state()
        control = model.control()
        def two_steps():
            for a, b in ((s0, s1), (s1, s0)):
                a.clear_forces()
                solver.step(a, b, control, None, 1e-3)

        for _ in range(5):
            two_steps()
        graph = None
        try:  # replayed as a graph, as our one-palpation step is (Python launch overhead out)
            with wp.ScopedCapture(device=device, force_module_load=False) as cap:
                two_steps()
            graph = cap.graph
        except Exception:
            graph = None
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        for _ in range(steps // 2):
            if graph is not None:
                wp.capture_launch(graph)
            else:
                two_steps()
        wp.synchronize_device(device)
        dt = (time.perf_counter() - t0) / (2 * (steps // 2))
        return {
            "version": getattr(newton, "__version__", "?"),
            "steps_per_s": 1.0 / dt,
            "step_us_median": dt * 1e6,
            "captured": graph is not None,
            "particle_contact": False,
        }
    except Exception as exc:  # a peer's API changes: report it, do not fail the benchmark
        return {"skipped": f"newton failed: {type(exc).__name__}: {exc}"}
