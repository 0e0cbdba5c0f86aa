"""The built-in stroke over the shipped scenes: the local model that follows the probe against the global one.

For each scene, one rigid sphere runs the built-in stroke (protocol.stroke.builtin_stroke: touch
down at the top vertex, press 8 mm, slide 60 mm at 20 mm/s, lift) twice: on the local region that
follows the contact (ProbeStroke, `--rings` rings) and on the global model (every vertex free).
Printed per scene: the RMS of the difference of the two force traces over the RMS of the global
trace [%]; at each relocation the step-to-step change of the local force over the force [%] (the
largest; beside it the global model's change at the same step, the path's own); the largest
distance any vertex moves in one step, local and global [mm]; the relocations; and the local step's
wall and CPU (this thread's) times, p50 / p99 / max [us].

    python scripts/stroke_continuity.py                       # stomach and liver scenes
    python scripts/stroke_continuity.py scenes/stomach.toml --rings 3 --radius-mm 8
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from almsdm_warp.protocol.stroke import ProbeStroke, builtin_stroke  # noqa: E402
from almsdm_warp.scene.loader import load_scene  # noqa: E402

INTEGRATOR = {"liver": "implicit"}
"""The liver's thin lobe puts the explicit critical step near 0.13 ms (scenes/liver.toml): implicit at 1 ms."""


def run(scene, rings, radius, integrator, dt):
    """Forces [n, 3], the largest per-step vertex move [n], relocation steps, wall and CPU times [us]."""
    mesh = scene.load_mesh()
    path = builtin_stroke(mesh, radius, dt=dt)
    stroke = ProbeStroke(mesh, scene.tissue, probe_radius=radius, rings=rings, integrator=integrator, dt=dt,
                         fixed_below=scene.fixed_below)
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
    return force, move, moved_at, wall[1:] * 1e6, cpu[1:] * 1e6, stroke


def jump(force, k):
    """|F_k - F_(k-1)| / |F_k| [%] (0 where there is no force)."""
    f = np.linalg.norm(force[k])
    return 100.0 * np.linalg.norm(force[k] - force[k - 1]) / f if f > 0 else 0.0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenes", nargs="*", default=[str(ROOT / "scenes" / "stomach.toml"), str(ROOT / "scenes" / "liver.toml")])
    ap.add_argument("--rings", type=int, default=4)
    ap.add_argument("--radius-mm", type=float, default=10.0)
    ap.add_argument("--dt-ms", type=float, default=1.0)
    ap.add_argument("--integrator", default=None, help="default: explicit (implicit for the liver)")
    args = ap.parse_args(argv)
    radius, dt = args.radius_mm * 1e-3, args.dt_ms * 1e-3
    print("| scene | integrator | rings | relocations | force RMS vs global [%] | largest jump at a relocation [%] "
          "(global there) | largest vertex move in a step, local / global [mm] | step wall p50 / p99 / max [us] "
          "| step CPU p50 / p99 / max [us] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for path in args.scenes:
        scene = load_scene(path)
        integrator = args.integrator or INTEGRATOR.get(scene.name, "explicit")
        f_loc, mv_loc, moved, wall, cpu, stroke = run(scene, args.rings, radius, integrator, dt)
        f_glo, mv_glo, _, _, _, _ = run(scene, "global", radius, integrator, dt)
        rms = 100.0 * np.sqrt(np.mean(np.sum((f_loc - f_glo) ** 2, axis=1)) / np.mean(np.sum(f_glo**2, axis=1)))
        jumps = [(max(jump(f_loc, k), jump(f_loc, k + 1)), max(jump(f_glo, k), jump(f_glo, k + 1))) for k in moved]
        worst = max(jumps, default=(0.0, 0.0))
        print(f"| {scene.name} | {integrator} | {args.rings} | {stroke.relocations} | {rms:.3f} | {worst[0]:.2f} ({worst[1]:.2f}) "
              f"| {mv_loc.max() * 1e3:.3f} / {mv_glo.max() * 1e3:.3f} "
              f"| {np.percentile(wall, 50):.0f} / {np.percentile(wall, 99):.0f} / {wall.max():.0f} "
              f"| {np.percentile(cpu, 50):.0f} / {np.percentile(cpu, 99):.0f} / {cpu.max():.0f} |")


if __name__ == "__main__":
    main()
