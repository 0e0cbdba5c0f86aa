"""Sweeps at ``--rings auto``: each contact's region sized as ``almsdm palpate --rings auto`` sizes it.

The batched simulator (BatchPalpation) holds one ring count per launch, so the adaptive criterion
(docs/adaptive.md) runs first, per contact: for each distinct contact vertex of the sweep, one
AdaptivePalpation on the CPU (the sweep's tissue, lesion, integrator and dt) is pressed by the
sweep's own ramp and hold to its depth, and the rings it grew to are that contact's ring count.
The settle window is left out: a region grows only while pressed. Between contacts the region is
retired (every vertex put at rest), so each contact is sized from rest, as a fresh palpation
would be. The sweep then presses every point with a fixed region of its ring count, one batch per
ring count in a chunk (sweep.press_chunk): a fixed region of the size the adaptive one grew to,
which is what the accuracy table of docs/adaptive.md measures (N*, within 1% force and T).

Sizing on the CPU whatever the sweep's devices: the ring counts (and so the resumable parts' key)
do not depend on where the batch runs.
"""

from __future__ import annotations

import numpy as np


def size_regions(mesh, tissue, vertices, tol, *, depth, ramp, hold, integrator="explicit", dt=1e-3,
                 on_point=None, **model) -> np.ndarray:
    """Rings the adaptive region grows to at each of `vertices` under the press (depth [m], ramp and
    hold [s]) at tolerance `tol` [m]: int64, one per vertex (each distinct vertex sized once).

    model: the palpation's keywords (edge_scale, anchor_scale, element_scale, fixed_below, law,
    probe_radius: a sphere's region grown from the patch it covers at `depth`, as palpate's).
    on_point(): called after each distinct vertex (a progress bar)."""
    from ..protocol.adaptive import AdaptivePalpation, hold_press

    verts = np.asarray(vertices, dtype=np.int64)
    distinct, inverse = np.unique(verts, return_inverse=True)
    pal = AdaptivePalpation(mesh, tissue, tol=tol, integrator=integrator, dt=dt, device="cpu", retire=False, **model)
    sphere = pal.probe_radius > 0
    chosen = np.empty(len(distinct), dtype=np.int64)
    for i, v in enumerate(distinct):
        pal.touch(int(v), depth if sphere else None)
        hold_press(pal, depth, ramp, hold)
        chosen[i] = pal.rings_chosen
        pal.retire_region()  # every vertex at rest in both states: the next contact starts from rest
        if on_point is not None:
            on_point()
    return chosen[inverse]


def rings_summary(rings) -> str:
    """'rings 2 x 5, 3 x 1' for the per-point ring counts."""
    values, counts = np.unique(np.asarray(rings), return_counts=True)
    return "rings " + ", ".join(f"{int(v)} x {int(c)}" for v, c in zip(values, counts))
