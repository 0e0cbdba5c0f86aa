"""Real anatomy: the recovery, force and speed experiments on the organ meshes of ../shared/meshes
(when present), and the cost of a step against mesh size over the MOR liver series (one liver at
five resolutions): flat for the local model, growing with the mesh for the global one.

Surfaces get the stomach scene's tissue, tet meshes the liver scene's; SOFA and MOR livers are in
scene units and are scaled to about 19-21 cm. Implicit integrator, dt 1 ms, everywhere: the small
elements of some meshes put the explicit critical step far below 1 ms.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from .common import DEPTH, DT, HOLD, RAMP, hold_press, time_per_step, top_vertex


def shared_meshes_dir() -> Path | None:
    """../shared/meshes beside the checkout (as the tests find it), or $ALMSDM_SHARED_MESHES."""
    env = os.environ.get("ALMSDM_SHARED_MESHES")
    folder = Path(env) if env else Path(__file__).resolve().parents[3] / "shared" / "meshes"
    return folder if folder.is_dir() else None


def run_anatomy(settings, device, tasks, folder=None) -> dict:
    """Per mesh: 4-ring presses (peak force, residual after each), the unanchored global model's
    residual (up to `settings.anatomy_free_max_vertices`), the anchored global force, and the time
    of a step of the 4-ring and the global model."""
    from .common import press_curve, shipped_scene
    from ..mesh.io import load_mesh
    from ..protocol.palpation import Palpation
    from ..solvers.stepper import SimulationDiverged

    folder = shared_meshes_dir() if folder is None else Path(folder)
    if folder is None:
        return {"folder": None, "rows": []}
    rows = []
    for file, scale_mm in settings.anatomy:
        path = folder / file
        if not path.is_file():
            tasks.step(f"anatomy: {file} (absent)", _weight(file))
            continue
        mesh = load_mesh(path, scale=scale_mm)
        tissue = shipped_scene("paper_liver" if mesh.is_volume else "paper_stomach")[0].tissue  # anchored: no support needed
        vertex = top_vertex(mesh)
        row = {"file": file, "scale_mm": scale_mm, "vertices": mesh.vertex_count, "volume": mesh.is_volume, "edges": mesh.edge_count}
        local = Palpation(mesh, tissue, rings=4, integrator="implicit", dt=DT, device=device)
        local.touch(vertex)
        presses = [local.press(DEPTH, RAMP, HOLD, settings.settle_s) for _ in range(min(settings.presses, 3))]
        row["region_vertices"] = local.region_vertices
        row["local_peak_force_N"] = presses[0].peak_force_N
        row["local_residual_mm"] = [p.recovery_error_mm for p in presses]
        row["local_recovery_time_s"] = presses[0].recovery_time_s
        row["local_step_us"] = time_per_step(local, settings.timing_budget_s) * 1e6
        glob = Palpation(mesh, tissue, rings="global", integrator="implicit", dt=DT, device=device)
        glob.touch(vertex)
        _, peak, _, force, target = hold_press(glob)
        row["global_peak_force_N"] = peak
        row["global_curve"] = ((target[::5] * 1e3).round(4).tolist(), force[::5].round(5).tolist())
        row["global_step_us"] = time_per_step(glob, settings.timing_budget_s) * 1e6
        row["local_curve"] = press_curve(presses[0])
        row["free_residual_mm"] = None
        if mesh.vertex_count <= settings.anatomy_free_max_vertices:
            free = Palpation(mesh, tissue, rings="global-free", integrator="implicit", dt=DT, device=device)
            free.touch(vertex)
            try:
                row["free_residual_mm"] = free.press(DEPTH, RAMP, HOLD, settings.settle_s).recovery_error_mm
            except SimulationDiverged:  # the unanchored mesh flew off: it certainly did not recover
                row["free_residual_mm"] = math.inf
        rows.append(row)
        tasks.step(f"anatomy: {file}", _weight(file))
    return {"folder": str(folder), "rows": rows}


def _weight(file) -> int:
    """Progress units of one real mesh: its global model's steps dominate, and grow with its size
    (the shared meshes' README: up to 5587 vertices); a fixed guess per name, no loading needed."""
    return 30 if any(k in file for k in ("Fine", "5587", "SemiFine", "smooth")) else 6


def count_tasks(settings) -> int:
    return sum(_weight(file) for file, _ in settings.anatomy)
