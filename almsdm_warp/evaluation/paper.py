"""The paper's own experiments: recovery after repeated presses (Fig. 9), Table 1 at 10 mm, force
against displacement (Fig. 10) and the frame rates of Table 2 (with a hook for the normals
strategies of almsdm_warp.normals).
"""

from __future__ import annotations

import math

from .common import DEPTH, DT, HOLD, RAMP, press_curve, shipped_scene, time_per_step, top_vertex

RECOVERY_RINGS = (1, 2, 3, 4, "global-free")

PAPER_PRESETS = {"stomach": "paper_stomach", "liver": "paper_liver"}
"""Organ -> the shipped scene on the paper's constants that its experiments run on (the default
scenes are on a material from the literature; docs/calibration.md)."""


def paper_scene(organ):
    """(Scene, its mesh) of an organ's paper preset."""
    return shipped_scene(PAPER_PRESETS[organ])

TABLE1_ROWS = (
    # (label, scene, rings, integrator, the paper's row it stands beside)
    ("stomach, 4 rings", "stomach", 4, "explicit", "local surface"),
    ("stomach, global anchored", "stomach", "global", "explicit", None),
    ("stomach, global free (no anchors)", "stomach", "global-free", "explicit", "global surface"),
    ("liver, 4 rings", "liver", 4, "implicit", "local volume"),
    ("liver, global anchored", "liver", "global", "implicit", "global volume"),
    ("liver, global free (no anchors)", "liver", "global-free", "implicit", None),
)
"""The liver's explicit critical step (0.24 ms over the whole mesh) is below 1 ms: implicit there."""

TABLE2_ROWS = (
    # (label, scene, rings, integrator, the paper's row)
    ("1 ring", "stomach", 1, "explicit", 1),
    ("2 rings", "stomach", 2, "explicit", 2),
    ("3 rings", "stomach", 3, "explicit", 3),
    ("4 rings", "stomach", 4, "explicit", 4),
    ("global surface (no anchors)", "stomach", "global-free", "explicit", "global surface"),
    ("4-ring volume (liver)", "liver", 4, "implicit", "4-ring volume"),
)


def run_recovery(settings, device, tasks) -> dict:
    """Fig. 9: `settings.presses` presses at the top of the stomach, 10 mm, explicit, dt 1 ms;
    the contact vertex's residual after each, for rings 1..4 and the unanchored global model."""
    from ..protocol.palpation import Palpation
    from ..solvers.stepper import SimulationDiverged

    scene, mesh = paper_scene("stomach")
    vertex = top_vertex(mesh)
    rows, curves = [], {}
    for rings in RECOVERY_RINGS:
        pal = Palpation(mesh, scene.tissue, rings=rings, integrator="explicit", dt=DT, device=device)
        pal.touch(vertex)
        presses, ran_away = [], None
        for k in range(settings.presses):
            try:
                presses.append(pal.press(DEPTH, RAMP, HOLD, settings.settle_s))
            except SimulationDiverged:
                # the unanchored mesh, yanked back by the next press, flies off (Palpation's guard:
                # more than twice the mesh's size from rest); the presses after it are not run
                ran_away = k + 1
                break
        missing = [math.inf] * (settings.presses - len(presses))
        rows.append(
            {
                "rings": rings,
                "region_vertices": pal.region_vertices,
                "region_springs": pal.region_springs,
                "residual_mm": [p.recovery_error_mm for p in presses] + missing,
                "peak_force_N": [p.peak_force_N for p in presses] + missing,
                "ran_away_at_press": ran_away,
            }
        )
        curves[str(rings)] = press_curve(presses[0])
        tasks.step(f"recovery: {rings}")
    return {"scene": "stomach", "vertex": vertex, "settle_s": settings.settle_s, "rows": rows, "curves": curves}


def run_table1(settings, device, tasks) -> dict:
    """Table 1 at 10 mm: recovery error, recovery time and feedback force of each model."""
    from ..protocol.palpation import Palpation

    rows = []
    for label, name, rings, integrator, paper in TABLE1_ROWS:
        scene, mesh = paper_scene(name)
        pal = Palpation(mesh, scene.tissue, rings=rings, integrator=integrator, dt=DT, device=device)
        pal.touch(top_vertex(mesh))
        r = pal.press(DEPTH, RAMP, HOLD, settings.settle_s)
        rows.append(
            {
                "label": label,
                "scene": name,
                "rings": rings,
                "integrator": integrator,
                "paper": paper,
                "recovery_error_mm": r.recovery_error_mm,
                "recovery_time_s": r.recovery_time_s,
                "peak_force_N": r.peak_force_N,
                "hold_end_force_N": float(r.force[r.release_step - 1]),
                "curve": press_curve(r),
            }
        )
        tasks.step(f"table 1: {label}")
    return {"settle_s": settings.settle_s, "rows": rows}


def find_normals_strategies():
    """Table 2's normals strategies: ``(names, timer)`` from almsdm_warp.normals, or None.

    ``normals.STRATEGIES`` (global / search / precomputed) and ``normals.time_strategy(palpation,
    name, budget_s) -> seconds per normals update`` of the touched, pressed palpation. Without
    them the table's normals columns read "not available".
    """
    try:
        from ..sim import normals  # noqa: F401 - the usd engineer's module (issue 4)
    except ImportError:
        return None
    names = getattr(normals, "STRATEGIES", None)
    timer = getattr(normals, "time_strategy", None)
    if not names or not callable(timer):
        return None
    return tuple(names), timer


def run_table2(settings, device, tasks, normals=None) -> dict:
    """Table 2: steps per second of the physics alone, and frames per second (a step and a
    normals update) with each normals strategy when `normals` = (names, timer) is given."""
    from ..protocol.palpation import Palpation

    rows = []
    for label, name, rings, integrator, paper in TABLE2_ROWS:
        scene, mesh = paper_scene(name)
        pal = Palpation(mesh, scene.tissue, rings=rings, integrator=integrator, dt=DT, device=device)
        pal.touch(top_vertex(mesh))
        step_s = time_per_step(pal, settings.timing_budget_s)
        row = {
            "label": label,
            "rings": rings,
            "integrator": integrator,
            "region_vertices": pal.region_vertices,
            "paper": paper,
            "step_us": step_s * 1e6,
            "steps_per_s": 1.0 / step_s,
            "fps": {},
        }
        if normals is not None:
            names, timer = normals
            for strategy in names:
                row["fps"][strategy] = 1.0 / (step_s + float(timer(pal, strategy, settings.timing_budget_s)))
        rows.append(row)
        tasks.step(f"table 2: {label}")
    return {"strategies": list(normals[0]) if normals else None, "rows": rows}


def count_tasks(settings) -> int:
    return len(RECOVERY_RINGS) + len(TABLE1_ROWS) + len(TABLE2_ROWS)
