"""The stability map: explicit and implicit integrators over a grid of time step and stiffness,
each cell stable, oscillating without settling, or diverged; with the linearized critical step
of semi-implicit Euler (Model.critical_dt) for the same region. And the paper's unsupported
global surface model (no anchors, no fixed ring) over the time steps: where its method fails.
The explicit cells take one step a frame (substeps=1): the map is of the scheme itself.
"""

from __future__ import annotations

import math

import numpy as np

from .common import DEPTH, scaled_tissue, top_vertex

STABLE, OSCILLATING, DIVERGED, NOT_RECOVERED = "stable", "oscillating", "diverged", "not recovered"
RAMP, HOLD, SETTLE = 0.1, 0.1, 0.5
"""A shorter press than the evaluation's: the smallest steps (0.1 ms) take 7000 of them."""


def classify(result) -> str:
    """A finished press: stable when the contact vertex came back within 1% of the depth and stayed
    (PressResult.recovery_time_s finite). Otherwise, over the last fifth of the settle window:
    oscillating when its distance from rest still swings up and down (two or more turns) by more
    than 1% of the depth; not recovered when it rests or drifts away from rest without swinging
    (the unanchored model: nothing pulls it back)."""
    if math.isfinite(result.recovery_time_s):
        return STABLE
    tail = result.displacement[result.release_step :]
    tail = tail[-max(len(tail) // 5, 3) :]
    swing = float(tail.max() - tail.min()) > 0.01 * result.depth
    slope = np.diff(tail)
    slope = slope[np.abs(slope) > 1e-3 * 0.01 * result.depth]  # ignore float32 flicker at rest
    turns = int(np.count_nonzero(np.diff(np.sign(slope)) != 0))
    return OSCILLATING if swing and turns >= 2 else NOT_RECOVERED


def _cell(pal, check_every) -> str:
    from ..solvers.stepper import SimulationDiverged

    try:
        result = pal.press(DEPTH, RAMP, HOLD, SETTLE, check_every=check_every)
    except SimulationDiverged:
        return DIVERGED
    return classify(result)


def run_stability(settings, device, tasks) -> dict:
    """The stomach scene at its top vertex, 4 rings: every (integrator, dt, stiffness scale) cell;
    then the unanchored global model at stiffness 1 over `settings.stability_free_dt_ms`."""
    from .common import shipped_scene
    from ..protocol.palpation import Palpation

    scene, mesh = shipped_scene("paper_stomach")  # the paper's constants, scaled
    vertex = top_vertex(mesh)
    cells, critical = [], {}
    for scale in settings.stability_scales:
        tissue = scaled_tissue(scene.tissue, scale)
        for integrator in ("explicit", "implicit"):
            for dt_ms in settings.stability_dt_ms:
                pal = Palpation(mesh, tissue, rings=4, integrator=integrator, dt=dt_ms * 1e-3, device=device, substeps=1)
                pal.touch(vertex)
                if scale not in critical:
                    free = pal.region.vertices()[: pal.region.free_count]
                    critical[scale] = pal.model.critical_dt(free) * 1e3
                cells.append({"model": "4 rings", "integrator": integrator, "dt_ms": dt_ms, "scale": scale, "state": _cell(pal, 10)})
                tasks.step(f"stability: {integrator} dt {dt_ms:g} ms x{scale:g}")
    free_cells = []
    free_critical = None
    for integrator in ("explicit", "implicit"):
        for dt_ms in settings.stability_free_dt_ms:
            pal = Palpation(mesh, scene.tissue, rings="global-free", integrator=integrator, dt=dt_ms * 1e-3, device=device, substeps=1)
            pal.touch(vertex)
            if free_critical is None:
                free_critical = pal.model.critical_dt(anchors=False) * 1e3
            free_cells.append({"model": "global-free", "integrator": integrator, "dt_ms": dt_ms, "scale": 1.0, "state": _cell(pal, 10)})
            tasks.step(f"stability: global-free {integrator} dt {dt_ms:g} ms")
    anchored_critical = None
    if 1.0 in critical:
        pal = Palpation(mesh, scene.tissue, rings="global", dt=1e-3, device=device)
        anchored_critical = pal.model.critical_dt() * 1e3
    return {
        "scene": "stomach",
        "vertex": vertex,
        "press": {"depth_mm": DEPTH * 1e3, "ramp_s": RAMP, "hold_s": HOLD, "settle_s": SETTLE},
        "cells": cells,
        "critical_dt_ms": {str(k): v for k, v in critical.items()},
        "global_free_cells": free_cells,
        "global_free_critical_dt_ms": free_critical,
        "global_critical_dt_ms": anchored_critical,
    }


def explicit_boundary(result) -> dict:
    """Per stiffness scale: the largest dt [ms] at which the explicit 4-ring press was stable and
    the smallest at which it diverged (None where none), to set beside the critical step."""
    out = {}
    for scale in sorted({c["scale"] for c in result["cells"]}):
        cs = [c for c in result["cells"] if c["scale"] == scale and c["integrator"] == "explicit"]
        stable = [c["dt_ms"] for c in cs if c["state"] == STABLE]
        diverged = [c["dt_ms"] for c in cs if c["state"] == DIVERGED]
        out[scale] = (max(stable) if stable else None, min(diverged) if diverged else None)
    return out


def count_tasks(settings) -> int:
    return 2 * len(settings.stability_scales) * len(settings.stability_dt_ms) + 2 * len(settings.stability_free_dt_ms)

