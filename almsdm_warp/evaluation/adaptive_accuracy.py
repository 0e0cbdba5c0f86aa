"""Accuracy of a region against the global anchored reference, for the adaptive region and fixed rings.

One protocol for all (DESIGN.md, evaluation): the contact vertex is driven along the inward normal
to `depth` over `ramp` and held for `hold`; the peak feedback force is the largest over ramp and
hold, and the displacement error the largest distance, over every mesh vertex, between the model's
and the reference's positions at the end of the hold. `auto_point` is one point of the
speed-accuracy chart (issue 5) for the adaptive region at one tolerance.
"""

from __future__ import annotations


import numpy as np
import warp as wp

from ..protocol.adaptive import hold_press
from ..protocol.palpation import Palpation
from ..protocol.timing import time_steps
from ..region.contact import top_vertex

PROTOCOL = {"depth": 0.01, "ramp": 0.1, "hold": 0.2}
"""The default press [m, s, s]: the scenes' depth, ramp and hold (no settle: accuracy is at the hold)."""


def _median_step_us(pal, batches=10, batch=20):
    """Median wall time of a step [us] with the probe held where it is (the region as grown)."""
    times = time_steps(pal.step, batches, batch, warmup=5, sync=lambda: wp.synchronize_device(pal.device))
    return times.median * 1e6


def _point(pal, reference, protocol, time_steps):
    peak, q = hold_press(pal, **protocol)
    g_peak, g_q = reference
    point = {
        "rings": int(pal.region.outer_ring) if pal.region is not None else None,
        "region_vertices": int(pal.region_vertices),
        "region_springs": int(pal.region_springs),
        "peak_force_N": peak,
        "force_error": abs(peak - g_peak) / g_peak,
        "displacement_error_mm": float(np.linalg.norm(q - g_q, axis=1).max() * 1e3),
        "reference_peak_force_N": g_peak,
    }
    if time_steps:
        point["step_us"] = _median_step_us(pal)
    return point


def global_reference(mesh, tissue=None, device=None, *, vertex=None, integrator="implicit", dt=5e-3, probe_radius=0.0,
                     fixed_below=None, **protocol):
    """(peak force [N], hold-end positions [m]) of the global anchored model under the protocol (a sphere
    of `probe_radius` [m] > 0 pressed the same depth; vertices below `fixed_below` [m] supported)."""
    prot = {**PROTOCOL, **protocol}
    pal = Palpation(mesh, tissue, rings="global", integrator=integrator, dt=dt, device=device, probe_radius=probe_radius,
                    fixed_below=fixed_below)
    pal.touch(top_vertex(pal.mesh) if vertex is None else vertex)
    return hold_press(pal, **prot)


def fixed_point(mesh, tissue, rings, device=None, *, vertex=None, integrator="implicit", dt=5e-3, reference=None,
                time_steps=False, probe_radius=0.0, fixed_below=None, **protocol):
    """The same as auto_point for a fixed ring count (the chart's other points, and the comparison)."""
    prot = {**PROTOCOL, **protocol}
    model = dict(probe_radius=probe_radius, fixed_below=fixed_below)
    pal = Palpation(mesh, tissue, rings=rings, integrator=integrator, dt=dt, device=device, **model)
    v = top_vertex(pal.mesh) if vertex is None else vertex
    pal.touch(v)
    if reference is None:
        reference = global_reference(mesh, tissue, device, vertex=v, integrator=integrator, dt=dt, **model, **prot)
    return _point(pal, reference, prot, time_steps)


def auto_point(mesh, tissue=None, tol=1e-4, device=None, *, vertex=None, integrator="implicit", dt=5e-3, reference=None,
               time_steps=False, options=None, **protocol):
    """The adaptive region at tolerance `tol` [m], pressed by the protocol and compared to the global
    anchored model: dict(rings, region_vertices, region_springs, peak_force_N, force_error (relative),
    displacement_error_mm, tol_mm, reason, events, reference_peak_force_N[, step_us]).

    mesh: a TissueMesh (SI) or a path; vertex: the contact (default: the highest surface vertex);
    reference: a global_reference() result to reuse across tolerances; time_steps: also time a step
    of the grown region (median of 10 batches of 20, the probe held); options: more keyword
    arguments of AdaptivePalpation (margin, force_tol, start_rings, probe_radius, fixed_below, ...), the
    last two also the reference's.
    """
    from ..protocol.adaptive import AdaptivePalpation
    from ..mesh.io import load_mesh

    if isinstance(mesh, (str, bytes)) or hasattr(mesh, "__fspath__"):
        mesh = load_mesh(mesh)
    prot = {**PROTOCOL, **protocol}
    pal = AdaptivePalpation(mesh, tissue, tol=tol, integrator=integrator, dt=dt, device=device, retire=False, **(options or {}))
    v = top_vertex(pal.mesh) if vertex is None else vertex
    pal.touch(v)
    if reference is None:
        model = {k: v for k, v in (options or {}).items() if k in ("probe_radius", "fixed_below")}
        reference = global_reference(mesh, tissue, device, vertex=v, integrator=integrator, dt=dt, **model, **prot)
    point = _point(pal, reference, prot, time_steps)
    point.update(tol_mm=tol * 1e3, reason=pal.auto_reason, events=list(pal.events), vertex=int(v))
    return point
