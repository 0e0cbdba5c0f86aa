"""The built-in stroke over the shipped scenes: the local model that follows the probe against the global one.

For each scene, one rigid sphere runs the built-in stroke (protocol.stroke.builtin_stroke: touch
down at the top vertex, press 8 mm, slide 60 mm at 20 mm/s, lift) twice: on the local region that
follows the contact (ProbeStroke, `--rings` rings) and on the global model (every vertex free).
Printed per scene: the RMS of the difference of the two force traces over the RMS of the global
trace [%]; at each relocation (the step that swaps the region and the next) the step-to-step change
of the local force over the force [%] (the largest; beside it the largest part of such a change that
the global model does not make at the same step: the relocation's own); the largest
distance any vertex moves in one step, local and global [mm]; the relocations; and the local step's
wall and CPU (this thread's) times, p50 / p99 / max [us], from the fourth step on (START).

    python scripts/stroke_continuity.py                       # stomach and liver scenes
    python scripts/stroke_continuity.py scenes/stomach.toml --rings 3 --radius-mm 8
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from almsdm_warp.protocol.stroke import ProbeStroke, builtin_stroke  # noqa: E402
from almsdm_warp.scene.loader import load_scene  # noqa: E402
from almsdm_warp.tissue.material import Material  # noqa: E402

START = 3
"""Steps left out of the timings: the first loads the kernels, the next two capture the step's graphs."""

INTEGRATOR = {"liver": "implicit"}
"""The liver's thin lobe puts the explicit critical step near 0.13 ms (scenes/liver.toml): implicit at 1 ms."""


def run(scene, rings, radius, integrator, dt, lead=None):
    """Forces [n, 3], the largest per-step vertex move [n], relocation steps, wall and CPU times [us]."""
    mesh = scene.load_mesh()
    path = builtin_stroke(mesh, radius, dt=dt)
    stroke = ProbeStroke(mesh, scene.tissue, probe_radius=radius, rings=rings, integrator=integrator, dt=dt,
                         fixed_below=scene.fixed_below, lead=lead)
    n = len(path.t)
    force, move, wall, cpu = np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros(n)
    moved_at = []
    q_prev = stroke.positions()
    for k, c in enumerate(path.centre):
        before = stroke.relocations
        w0, c0 = time.perf_counter(), time.thread_time()
        force[k] = stroke.step(c)
        cpu[k], wall[k] = time.thread_time() - c0, time.perf_counter() - w0
        if stroke.relocations != before:
            moved_at.append(k)
        q = stroke.positions()
        move[k] = np.linalg.norm(q - q_prev, axis=1).max()
        q_prev = q
    return force, move, moved_at, wall[START:] * 1e6, cpu[START:] * 1e6, stroke


def jumps(f_loc, f_glo, k):
    """At step k: the local force's change |F_k - F_(k-1)| over |F_k| [%], and the part of it that is
    not the global model's own change there, |dF_local - dF_global| / |F_k| [%] (0, 0 with no force)."""
    f = np.linalg.norm(f_loc[k])
    if f == 0:
        return 0.0, 0.0
    d_loc, d_glo = f_loc[k] - f_loc[k - 1], f_glo[k] - f_glo[k - 1]
    return 100.0 * np.linalg.norm(d_loc) / f, 100.0 * np.linalg.norm(d_loc - d_glo) / f


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenes", nargs="*", default=[str(ROOT / "scenes" / "stomach.toml"), str(ROOT / "scenes" / "liver.toml")])
    ap.add_argument("--rings", type=int, default=4)
    ap.add_argument("--radius-mm", type=float, default=10.0)
    ap.add_argument("--dt-ms", type=float, default=1.0)
    ap.add_argument("--integrator", default=None, help="default: explicit (implicit for the liver)")
    ap.add_argument("--material", nargs=3, type=float, metavar=("E_KPA", "THICKNESS_MM", "FOUNDATION_KPA_PER_MM"),
                    help="replace the scene's tissue by a material (Poisson 0.45, damping ratio 0.1) with a foundation")
    ap.add_argument("--lead-mm", type=float, default=None, help="ProbeStroke's lead (default: twice the mean edge)")
    args = ap.parse_args(argv)
    radius, dt = args.radius_mm * 1e-3, args.dt_ms * 1e-3
    print("| scene | integrator | rings | region vertices at the end | relocations | force RMS vs global [%] | largest force jump at a relocation [%] "
          "(not the global's) | largest vertex move in a step, local / global [mm] | step wall p50 / p99 / max [us] "
          "| step CPU p50 / p99 / max [us] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for path in args.scenes:
        scene = load_scene(path)
        if args.material:
            e_kpa, t_mm, k_kpa_mm = args.material
            tissue = Material(youngs_modulus=e_kpa * 1e3, poisson_ratio=0.45, thickness=t_mm * 1e-3,
                              foundation=k_kpa_mm * 1e6, damping_ratio=0.1)
            scene = dataclasses.replace(scene, tissue=tissue)
        integrator = args.integrator or INTEGRATOR.get(scene.name, "explicit")
        lead = None if args.lead_mm is None else args.lead_mm * 1e-3
        f_loc, mv_loc, moved, wall, cpu, stroke = run(scene, args.rings, radius, integrator, dt, lead)
        f_glo, mv_glo, _, _, _, _ = run(scene, "global", radius, integrator, dt)
        rms = 100.0 * np.sqrt(np.mean(np.sum((f_loc - f_glo) ** 2, axis=1)) / np.mean(np.sum(f_glo**2, axis=1)))
        at = [jumps(f_loc, f_glo, j) for k in moved for j in (k, k + 1) if j < len(f_loc)]
        worst = max(at, default=(0.0, 0.0))
        excess = max((e for _, e in at), default=0.0)
        print(f"| {scene.name} | {integrator} | {args.rings} | {stroke.region_vertices} | {stroke.relocations} | {rms:.3f} | {worst[0]:.2f} ({excess:.3f}) "
              f"| {mv_loc.max() * 1e3:.3f} / {mv_glo.max() * 1e3:.3f} "
              f"| {np.percentile(wall, 50):.0f} / {np.percentile(wall, 99):.0f} / {wall.max():.0f} "
              f"| {np.percentile(cpu, 50):.0f} / {np.percentile(cpu, 99):.0f} / {cpu.max():.0f} |")


if __name__ == "__main__":
    main()
