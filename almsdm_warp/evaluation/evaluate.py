"""`almsdm evaluate`: the paper's experiments reproduced, speed charted against accuracy, stability
mapped, real anatomy, the continuum references (continuum.py; every tissue law deep, over bone and
over a lesion: depth_layers.py); one command regenerates docs/results.md and its figures.

    run_evaluation(out_dir, settings=SETTINGS["full"], device="cpu")

Every experiment runs first; the figures (PNG) and results.md (and results.json, the numbers
behind them) are written only at the end, each through a temporary file and a rename, so a run
that fails or is interrupted leaves the previous results as they were.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
import time
from pathlib import Path

from . import accuracy as evaluate_accuracy
from . import anatomy as evaluate_anatomy
from . import continuum as evaluate_continuum
from . import depth_layers as evaluate_depth
from . import paper as evaluate_paper
from . import stability as evaluate_stability
from .common import SETTINGS, Settings, Tasks

FIGURES = {
    "recovery": "results_recovery.png",
    "force_displacement": "results_force_displacement.png",
    "speed_accuracy": "results_speed_accuracy.png",
    "stability": "results_stability.png",
    "anatomy_cost": "results_anatomy_cost.png",
    "anatomy_force": "results_anatomy_force.png",
    "convergence": "results_convergence.png",
    "against_fem": "results_against_fem.png",
}
"""Figure files, written in `<out>/figures/`."""


def machine_info(device) -> dict:
    """The machine, the device and the software a run was made with (for results.md)."""
    import warp as wp

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            names = [line.split(":", 1)[1].strip() for line in f if line.startswith("model name")]
        cpu = names[0] if names else cpu
    except OSError:
        pass
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    dev = wp.get_device(device)
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "load_average_1_5_15": [round(x, 2) for x in load] if load else None,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "warp": wp.config.version,
        "device": str(dev),
        "device_name": dev.name,
    }


def run_evaluation(out_dir, settings: Settings | str = "full", device="cpu", *, command=None, extra_json=None,
                   progress=None, normals=None, auto_factory=None, meshes_dir=None) -> dict:
    """Run every experiment and write `<out_dir>/results.md`, `results.json` and `figures/*.png`.

    normals: (names, timer) for Table 2 (default: evaluate_paper.find_normals_strategies()).
    auto_factory: the "auto" rings hook (default: evaluate_accuracy.find_auto_factory()).
    extra_json: step times measured elsewhere (a GPU) added to the speed-accuracy figure.
    Returns the results dict (also written as results.json).
    """
    from .plots import (
        plot_anatomy_cost,
        plot_anatomy_force,
        plot_against_fem,
        plot_convergence,
        plot_force_displacement,
        plot_recovery,
        plot_speed_accuracy,
        plot_stability,
    )
    from .report import render_results
    from ..export.output import atomic_write_text
    from ..progress import Progress

    settings = SETTINGS[settings] if isinstance(settings, str) else settings
    out = Path(out_dir)
    normals = evaluate_paper.find_normals_strategies() if normals is None else normals
    auto_factory = evaluate_accuracy.find_auto_factory() if auto_factory is None else auto_factory
    started = time.perf_counter()
    total = sum(m.count_tasks(settings) for m in (evaluate_paper, evaluate_accuracy, evaluate_stability, evaluate_anatomy, evaluate_continuum, evaluate_depth))
    results = {
        "settings": settings.name,
        "command": command or f"almsdm evaluate --device {device}",
        "date_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": machine_info(device),
    }
    with Progress(total, enabled=progress, label="evaluate") as bar:
        tasks = Tasks(bar)
        parts = (
            ("recovery", lambda: evaluate_paper.run_recovery(settings, device, tasks)),
            ("table1", lambda: evaluate_paper.run_table1(settings, device, tasks)),
            ("table2", lambda: evaluate_paper.run_table2(settings, device, tasks, normals)),
            ("accuracy", lambda: evaluate_accuracy.run_accuracy(settings, device, tasks, auto_factory)),
            ("stability", lambda: evaluate_stability.run_stability(settings, device, tasks)),
            ("anatomy", lambda: evaluate_anatomy.run_anatomy(settings, device, tasks, meshes_dir)),
            ("convergence", lambda: evaluate_continuum.run_convergence(settings, device, tasks)),
            ("against_fem", lambda: evaluate_continuum.run_against_fem(settings, device, tasks)),
            ("depth_layers", lambda: evaluate_depth.run_depth_layers(settings, device, tasks)),
        )
        results["part_s"] = {}
        for name, run in parts:
            t0 = time.perf_counter()
            results[name] = run()
            results["part_s"][name] = round(time.perf_counter() - t0, 1)
    extra = evaluate_accuracy.join_extra_points(evaluate_accuracy.read_extra_points(extra_json), results["accuracy"]["rows"]) if extra_json else []
    results["accuracy"]["extra"] = extra
    results["machine"]["load_average_after"] = [round(x, 2) for x in os.getloadavg()] if hasattr(os, "getloadavg") else None
    results["elapsed_s"] = round(time.perf_counter() - started, 1)

    figures = out / "figures"
    figures.mkdir(exist_ok=True)
    written = {}
    written["recovery"] = plot_recovery(results["recovery"], figures / FIGURES["recovery"])
    written["force_displacement"] = plot_force_displacement(results["recovery"], results["table1"], figures / FIGURES["force_displacement"])
    written["speed_accuracy"] = plot_speed_accuracy(results["accuracy"], extra, figures / FIGURES["speed_accuracy"], results["against_fem"],
                                                   results["depth_layers"])
    written["stability"] = plot_stability(results["stability"], figures / FIGURES["stability"])
    if results["anatomy"]["rows"]:
        written["anatomy_cost"] = plot_anatomy_cost(results["anatomy"], figures / FIGURES["anatomy_cost"])
        written["anatomy_force"] = plot_anatomy_force(results["anatomy"], figures / FIGURES["anatomy_force"])
    written["convergence"] = plot_convergence(results["convergence"], figures / FIGURES["convergence"])
    written["against_fem"] = plot_against_fem(results["against_fem"], figures / FIGURES["against_fem"])
    results["figures"] = {k: f"figures/{Path(v).name}" for k, v in written.items()}
    atomic_write_text(out / "results.json", json.dumps(_clean(results), indent=1) + "\n")
    atomic_write_text(out / "results.md", render_results(results))
    return results


def _clean(x):
    """The results as strict JSON: inf and nan as null, numpy scalars as Python numbers."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (str, bool)) or x is None:
        return x
    if isinstance(x, (int, float)) or hasattr(x, "item"):
        x = x.item() if hasattr(x, "item") else x
        return x if not isinstance(x, float) or math.isfinite(x) else None
    return str(x)
