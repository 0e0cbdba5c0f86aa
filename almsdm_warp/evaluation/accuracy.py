"""Speed against accuracy, the headline figure: for each region size, the error against the global
anchored reference (force at the probe, and the largest displacement error over the mesh, both at
the end of the hold) against the time of one step.

Rings "auto" (the adaptive region) go through a hook, like the normals of Table 2; CUDA points come
from a JSON file of step times measured on a GPU (`almsdm evaluate --extra-json`).
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path

import numpy as np

from ..errors import InputError
from .common import DT, hold_press, reset_to_rest, spread_vertices, time_per_step

SERIES = (
    # (scene, integrator): the liver's explicit critical step is below 1 ms (docs/calibration.md)
    ("stomach", "explicit"),
    ("stomach", "implicit"),
    ("liver", "implicit"),
)


def find_auto_factory():
    """The "auto:T" points' factory: ``almsdm_warp.adaptive.make_auto_palpation(mesh, tissue, *,
    integrator, dt, device, tol)``, or None where the adaptive region is absent (those points are
    then reported as not available)."""
    try:
        from ..protocol import adaptive
    except ImportError:
        return None
    factory = getattr(adaptive, "make_auto_palpation", None)
    return factory if callable(factory) else None


def is_auto(rings) -> bool:
    return isinstance(rings, str) and rings.startswith("auto")


def auto_tol(rings) -> float:
    """Tolerance [m] of an "auto:T" entry (T in mm)."""
    return float(rings.split(":", 1)[1]) * 1e-3


def _make(mesh, tissue, rings, integrator, device, auto_factory):
    from ..protocol.palpation import Palpation

    if is_auto(rings):
        return auto_factory(mesh, tissue, integrator=integrator, dt=DT, device=device, tol=auto_tol(rings))
    return Palpation(mesh, tissue, rings=rings, integrator=integrator, dt=DT, device=device)


def run_accuracy(settings, device, tasks, auto_factory=None) -> dict:
    """Rows per (scene, integrator, rings): median and largest errors over the contact vertices,
    the region's size and the median time of a step (timed at the first contact)."""
    from .common import shipped_scene

    rings_list = [r for r in settings.accuracy_rings if not is_auto(r) or auto_factory is not None]
    rows = []
    for name, integrator in SERIES:
        scene, mesh = shipped_scene(f"paper_{name}")  # its reference, the global anchored model, needs anchors
        contacts = spread_vertices(mesh, settings.accuracy_contacts)
        reference = {}
        for rings in ["global"] + [r for r in rings_list if r != "global"]:
            pal = _make(mesh, scene.tissue, rings, integrator, str(device), auto_factory)
            force_err, disp_err, sizes = [], [], []
            for v in contacts:
                pal.touch(v)
                reset_to_rest(pal)
                f_end, f_peak, q, _, _ = hold_press(pal)
                if rings == "global":
                    reference[v] = (f_end, f_peak, q)
                f_ref_end, f_ref_peak, q_ref = reference[v]
                force_err.append(abs(f_peak - f_ref_peak))
                disp_err.append(float(np.linalg.norm(q - q_ref, axis=1).max()))
                sizes.append(pal.region_vertices)
            step_s = time_per_step(pal, settings.timing_budget_s)
            rows.append(
                {
                    "scene": name,
                    "integrator": integrator,
                    "rings": rings,
                    "device": "cpu" if str(device).startswith("cpu") else str(device),
                    "region_vertices": int(statistics.median(sizes)),
                    "force_error_N": statistics.median(force_err),
                    "force_error_max_N": max(force_err),
                    "reference_force_N": statistics.median(reference[v][1] for v in contacts),
                    "disp_error_mm": statistics.median(disp_err) * 1e3,
                    "disp_error_max_mm": max(disp_err) * 1e3,
                    "step_us": step_s * 1e6,
                }
            )
            tasks.step(f"speed-accuracy: {name} {integrator} {rings}")
    missing = [r for r in settings.accuracy_rings if is_auto(r)] if auto_factory is None else []
    if missing:
        tasks.step("speed-accuracy: auto not available", len(SERIES) * len(missing))
    return {"contacts": settings.accuracy_contacts, "rows": rows, "not_available": missing}


def read_extra_points(path) -> list[dict]:
    """Step times measured elsewhere (a GPU), checked: a list of rows, or an object with such a list
    under "single" or "rows" (the JSON of scripts/bench_palpation.py and `almsdm bench`). Each row
    has "rings", "step_us_median" (or "step_us"), "integrator" (default explicit), and "mesh" or
    "scene" (a scene name or a mesh path: its stem is matched, ".../stomach.obj" is the stomach) and
    "device", on the row or on the object. Returns [{scene, integrator, rings, step_us, device}]."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the extra points ({exc})") from exc
    top = data if isinstance(data, dict) else {}
    items = data if isinstance(data, list) else top.get("single", top.get("rows"))
    if not isinstance(items, list):
        raise InputError(f"{path}: expected a list of rows, or an object with a list under 'single' or 'rows'")
    out = []
    for i, item in enumerate(items):
        if not isinstance(item, dict):
            raise InputError(f"{path}: row {i} is not an object")
        where = item.get("scene") or item.get("mesh") or top.get("scene") or top.get("mesh")
        step = item.get("step_us_median", item.get("step_us"))
        if where is None or "rings" not in item or not isinstance(step, (int, float)) or not step > 0:
            raise InputError(f"{path}: row {i} needs 'rings', a positive 'step_us_median' and 'mesh' or 'scene'")
        out.append(
            {
                "scene": Path(str(where)).stem,
                "integrator": str(item.get("integrator", "explicit")),
                "rings": str(item["rings"]),
                "step_us": float(step),
                "device": str(item.get("device") or top.get("device") or "extra"),
            }
        )
    return out


def join_extra_points(points, rows) -> list[dict]:
    """The extra points with this run's errors for the same (scene, integrator, rings): float32 on
    every device, so the error does not depend on where the step was timed. Points with no match
    (another mesh, a ring count not run) are left out."""
    ours = {(r["scene"], r["integrator"], str(r["rings"])): r for r in rows}
    out = []
    for p in points:
        mine = ours.get((p["scene"], p["integrator"], p["rings"]))
        if mine is not None:
            out.append({**mine, "step_us": p["step_us"], "device": p["device"]})
    return out


def count_tasks(settings) -> int:
    return len(SERIES) * len(settings.accuracy_rings)
