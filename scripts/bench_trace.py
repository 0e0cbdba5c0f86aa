"""Haptic rate with a moving probe: the latency of each step over the built-in stroke, and a
lesion felt as a force rise.

    python scripts/bench_trace.py [--core 0] [--integrators explicit implicit] [--rings 4] [--repeats 3]

Pinned to one CPU core (sched_setaffinity; BLAS and OpenMP at one thread, set before NumPy loads).
Each configuration: a ProbeStroke (protocol/stroke.py) on the stomach scene, the built-in stroke
(touch down, press 8 mm, slide 60 mm at 20 mm/s, lift) run once to compile and warm up, then
`--repeats` times on a fresh ProbeStroke, each step timed alone (perf_counter_ns around
`step(centre)`, in wall time and in this thread's CPU time: the contact search, the region's move where it moves, the integrator's substeps,
the force read back). The first step of a run (it builds the first region) is reported apart;
the distribution is over the others, relocation steps also on their own. Python's garbage
collector is off while timing, as in a haptic loop. The wall time holds what the scheduler takes
(another process on the core); the CPU time is the step's own cost.

The lesion: the same kind of stroke, 60 mm across the lesion of scenes/stomach_lesion.toml, on that
scene and on the plain stomach; the force's magnitude over the lesion against away from it, and
against the plain stomach at the same place. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import gc  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
R = 10e-3  # the sphere's radius [m] (almsdm trace's default)
PCTS = (50, 90, 99, 99.9)


def stroke_for(scene_name, rings, integrator):
    from almsdm_warp.protocol.stroke import ProbeStroke
    from almsdm_warp.scene.loader import load_scene

    scene = load_scene(ROOT / "scenes" / f"{scene_name}.toml")
    mesh = scene.load_mesh()
    es, ans = scene.lesion.scales(mesh) if scene.lesion is not None else (None, None)

    def make():
        return ProbeStroke(mesh, scene.tissue, probe_radius=R, rings=rings, integrator=integrator, dt=1e-3,
                           device="cpu", edge_scale=es, anchor_scale=ans, fixed_below=scene.fixed_below)

    return scene, mesh, make


def timed_run(make, centres):
    """(per-step wall seconds, per-step CPU seconds of this thread, relocation flags, forces) of one
    run of `centres` on a fresh stroke. A relocation's flags cover every step it is spread over: the
    one that takes the seeds, the builds into the spare region and the swap."""
    s = make()
    n = len(centres)
    dt_ns = np.zeros(n, dtype=np.int64)
    cpu_ns = np.zeros(n, dtype=np.int64)
    moved = np.zeros(n, dtype=bool)
    forces = np.zeros((n, 3))
    clock, cpu = time.perf_counter_ns, time.thread_time_ns
    gc.collect()
    gc.disable()
    try:
        for k in range(n):
            before, busy = s.relocations, s.relocating
            c0, t0 = cpu(), clock()
            f = s.step(centres[k])
            dt_ns[k] = clock() - t0
            cpu_ns[k] = cpu() - c0
            moved[k] = busy or s.relocating or s.relocations != before  # a step of a relocation: any of its stages
            forces[k] = f
    finally:
        gc.enable()
    return dt_ns * 1e-9, cpu_ns * 1e-9, moved, forces


def stats_us(seconds):
    us = np.asarray(seconds) * 1e6
    if not len(us):
        return {}
    return {**{f"p{p:g}_us": float(np.percentile(us, p)) for p in PCTS}, "max_us": float(us.max()), "count": int(len(us))}


def latency(rings, integrator, repeats):
    from almsdm_warp.protocol.stroke import builtin_stroke

    _, mesh, make = stroke_for("stomach", rings, integrator)
    path = builtin_stroke(mesh, R, dt=1e-3)
    timed_run(make, path.centre)  # compile and warm up
    first, walls, cpus, flags, relocations = [], [], [], [], []
    for _ in range(repeats):
        wall, cpu, moved, _ = timed_run(make, path.centre)
        first.append(wall[0])
        walls.append(wall[1:])
        cpus.append(cpu[1:])
        flags.append(moved[1:])
        relocations.append(int(moved[1:].sum()))
    wall, cpu, moved = np.concatenate(walls), np.concatenate(cpus), np.concatenate(flags)
    bins = [0, 25, 50, 75, 100, 150, 200, 300, 500, 1000, 1e9]
    return {
        "rings": rings, "integrator": integrator, "steps_per_run": len(path.centre), "runs": repeats,
        "relocations_per_run": relocations, "first_step_us": [x * 1e6 for x in first],
        "wall": stats_us(wall), "cpu": stats_us(cpu), "relocation_wall": stats_us(wall[moved]),
        "relocation_cpu": stats_us(cpu[moved]), "steady_cpu": stats_us(cpu[~moved]), "steady_wall": stats_us(wall[~moved]),
        "histogram_bins_us": bins[:-1], "histogram_wall": np.histogram(wall * 1e6, bins=bins)[0].tolist(),
        "histogram_cpu": np.histogram(cpu * 1e6, bins=bins)[0].tolist(),
    }


def lesion_path(mesh, lesion):
    """A built-in stroke whose slide's middle passes over the lesion: it starts 30 mm from the
    surface point nearest the lesion's centre, heading to it, and slides 60 mm."""
    from almsdm_warp.protocol.stroke import builtin_stroke

    surface = mesh.surface_vertices
    x = mesh.vertices[surface]
    centre = np.asarray(lesion.center, dtype=np.float64)
    hit = x[np.argmin(np.linalg.norm(x - centre, axis=1))]
    d = np.linalg.norm(x - hit, axis=1)
    start = surface[np.argmin(np.abs(d - 30e-3))]
    direction = hit - mesh.vertices[start]
    return builtin_stroke(mesh, R, dt=1e-3, vertex=int(start), direction=direction), hit


def lesion_rise(integrator):
    scene, mesh, make_lesion = stroke_for("stomach_lesion", 4, integrator)
    path, hit = lesion_path(mesh, scene.lesion)
    _, _, make_plain = stroke_for("stomach", 4, integrator)
    f_lesion = timed_run(make_lesion, path.centre)[3]
    f_plain = timed_run(make_plain, path.centre)[3]
    slide = path.phase == 1
    # the sphere's contact point: R below the centre along the way to the surface
    over = slide & (np.linalg.norm(path.centre - hit, axis=1) < scene.lesion.radius)
    away = slide & (np.linalg.norm(path.centre - hit, axis=1) > scene.lesion.radius + 10e-3)
    m_l, m_p = np.linalg.norm(f_lesion, axis=1), np.linalg.norm(f_plain, axis=1)
    return {
        "integrator": integrator, "slide_steps": int(slide.sum()), "over_steps": int(over.sum()), "away_steps": int(away.sum()),
        "lesion_over_N": float(m_l[over].mean()), "lesion_away_N": float(m_l[away].mean()),
        "plain_over_N": float(m_p[over].mean()), "plain_away_N": float(m_p[away].mean()),
        "over_vs_away": float(m_l[over].mean() / m_l[away].mean()),
        "lesion_vs_plain_over": float(m_l[over].mean() / m_p[over].mean()),
        "lesion_vs_plain_away": float(m_l[away].mean() / m_p[away].mean()),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--core", type=int, default=0, help="the CPU core to run on (default 0)")
    ap.add_argument("--rings", type=int, default=4)
    ap.add_argument("--integrators", nargs="*", default=["explicit", "implicit"])
    ap.add_argument("--repeats", type=int, default=3, help="timed runs of the stroke (default 3)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.core})
    from almsdm_warp.warp_init import init_warp

    init_warp()
    print(f"one core ({sorted(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else '?'}); stomach scene, "
          f"built-in stroke, sphere {R * 1e3:g} mm, dt 1 ms, {args.rings} rings")
    print("| integrator | clock | steps | p50 us | p90 | p99 | p99.9 | max | relocation steps (all stages): n, p50, max "
          "| other steps: p99, max | first step us |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    out = {"latency": [], "lesion": []}
    for integrator in args.integrators:
        row = latency(args.rings, integrator, args.repeats)
        out["latency"].append(row)
        for clock in ("wall", "cpu"):
            a, m, o = row[clock], row[f"relocation_{clock}"], row[f"steady_{clock}"]
            reloc = f"{m['count']}, {m['p50_us']:.0f}, {m['max_us']:.0f}" if m else "0"
            first = ", ".join(f"{x:.0f}" for x in row["first_step_us"]) if clock == "wall" else ""
            print(f"| {integrator} | {clock} | {a['count']} | {a['p50_us']:.1f} | {a['p90_us']:.1f} | {a['p99_us']:.1f} "
                  f"| {a['p99.9_us']:.1f} | {a['max_us']:.1f} | {reloc} | {o['p99_us']:.1f}, {o['max_us']:.1f} | {first} |")
        for clock in ("wall", "cpu"):
            print(f"  {integrator} {clock} histogram, us {row['histogram_bins_us']}: {row[f'histogram_{clock}']}")
    for integrator in args.integrators:
        r = lesion_rise(integrator)
        out["lesion"].append(r)
        print(f"lesion ({integrator}): |F| over the lesion {r['lesion_over_N']:.3f} N, away {r['lesion_away_N']:.3f} N "
              f"(x{r['over_vs_away']:.2f}); plain stomach at the same places {r['plain_over_N']:.3f} / {r['plain_away_N']:.3f} N "
              f"(lesion / plain: x{r['lesion_vs_plain_over']:.2f} over, x{r['lesion_vs_plain_away']:.2f} away)")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
