"""How a sweep's cost follows the mesh: the same sweep on organs of 2.5k to 500k vertices, a table.

    python scripts/mesh_size_sweep.py --device cpu --points 64               # the CPU, few points
    python scripts/mesh_size_sweep.py --device cuda:0 --points 200000        # a GPU (the issue's target)
    python scripts/mesh_size_sweep.py --device cpu --points 64 --sizes 2562 10242 --tree OLD_CHECKOUT

Each organ is a geodesic sphere of radius 50 mm (an icosahedron's faces cut into f x f triangles and
projected: 10 f^2 + 2 vertices; 2,562 / 10,242 / 40,962 / 501,762 for f = 16 / 32 / 64 / 224), written
as OBJ to a temporary folder (or --mesh-dir, kept for the next run) with a scene that is the shipped
stomach's (its material, its 10 mm sphere, 1 ring, its press) on that mesh. Each sweep runs
`almsdm sweep SCENE --points N --device D --profile` in a fresh process and reports: loading (the
mesh read, checked and its topology: the sweep's "loading" phase), outside the kernels (the sweep's
wall less its press kernels and loading: sampling, models, region builds, planning, read-back,
writing), the press kernels (device time), the sweep's wall, the process's wall (imports and Warp's
start included) and its peak resident memory (os.wait4's ru_maxrss: the whole process).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent
FREQUENCIES = {2562: 16, 10242: 32, 40962: 64, 501762: 224}
"""Vertex count -> the geodesic sphere's frequency f (10 f^2 + 2 vertices)."""


def geodesic_sphere(frequency: int, radius: float = 50.0):
    """An icosahedron's 20 faces each cut into frequency^2 triangles, every vertex projected onto the sphere
    of `radius` [file units]: (vertices [10 f^2 + 2, 3], triangles [20 f^2, 3]), wound outward."""
    import numpy as np
    import trimesh

    ico = trimesh.creation.icosahedron()
    f = int(frequency)
    i, j = (a.ravel() for a in np.meshgrid(np.arange(f + 1), np.arange(f + 1), indexing="ij"))
    keep = i + j <= f
    i, j = i[keep], j[keep]
    index = np.full((f + 1, f + 1), -1, dtype=np.int64)
    index[i, j] = np.arange(len(i))
    a, b = (x.ravel() for x in np.meshgrid(np.arange(f), np.arange(f), indexing="ij"))
    up = a + b < f  # (a, b), (a + 1, b), (a, b + 1)
    down = a + b + 1 < f  # (a + 1, b), (a + 1, b + 1), (a, b + 1)
    tris = np.concatenate([np.stack([index[a[up], b[up]], index[a[up] + 1, b[up]], index[a[up], b[up] + 1]], axis=1),
                           np.stack([index[a[down] + 1, b[down]], index[a[down] + 1, b[down] + 1], index[a[down], b[down] + 1]], axis=1)])
    weights = np.stack([f - i - j, i, j], axis=1) / f
    points = np.einsum("mk,tkd->tmd", weights, ico.vertices[ico.faces]).reshape(-1, 3)
    faces = (tris[None] + (np.arange(20) * len(weights))[:, None, None]).reshape(-1, 3)
    unit = points / np.linalg.norm(points, axis=1, keepdims=True)
    _, first, inverse = np.unique(np.round(unit, 9), axis=0, return_index=True, return_inverse=True)
    return radius * unit[first], inverse.ravel()[faces]


def write_organ(folder: Path, vertices: int) -> Path:
    """The scene of the geodesic sphere of `vertices` vertices in `folder` (made once): its OBJ and a copy
    of scenes/stomach.toml that points at it."""
    f = FREQUENCIES.get(vertices) or round(((vertices - 2) / 10) ** 0.5)
    scene = folder / f"sphere_{10 * f * f + 2}.toml"
    if scene.exists():
        return scene
    import trimesh

    mesh = folder / f"sphere_{10 * f * f + 2}.obj"
    trimesh.Trimesh(*geodesic_sphere(f), process=False).export(mesh)
    text = (HERE / "scenes" / "stomach.toml").read_text()
    scene.write_text(re.sub(r'^path = "stomach.obj"', f'path = "{mesh.resolve()}"', text, flags=re.M))
    return scene


def run_sweep(tree: Path, scene: Path, args, out: Path) -> dict:
    """One sweep in a fresh process: its phases (seconds), process wall [s] and peak RSS [MiB]."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), *filter(None, [os.environ.get("PYTHONPATH")])])}
    cmd = [sys.executable, "-m", "almsdm_warp.cli.main", "sweep", str(scene), "--points", str(args.points),
           "--device", args.device, "--out", str(out), "--no-progress", "--profile", *args.extra]
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as log:
        child = subprocess.Popen(cmd, cwd=tree, env=env, stdout=log, stderr=subprocess.STDOUT, text=True)
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - t0
        child.returncode = os.waitstatus_to_exitcode(status)
        log.seek(0)
        text = log.read()
    if child.returncode != 0:
        return {"error": text.strip().splitlines()[-1:] or [f"exit {child.returncode}"], "process_s": wall}
    phase = lambda name: float(m.group(1)) if (m := re.search(rf"^{re.escape(name)}\s+([0-9.]+) s", text, re.M)) else 0.0
    return {"loading_s": phase("loading"), "kernels_s": phase("press kernels (device)"), "sweep_s": phase("wall"),
            "process_s": wall, "peak_rss_MiB": usage.ru_maxrss / 1024}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--points", type=int, default=64)
    ap.add_argument("--sizes", type=int, nargs="+", default=list(FREQUENCIES), metavar="V",
                    help="vertex counts (the nearest 10 f^2 + 2); default 2562 10242 40962 501762")
    ap.add_argument("--mesh-dir", type=Path, default=None, help="where the meshes are written and kept (default: a temporary folder)")
    ap.add_argument("--tree", type=Path, default=HERE, help="checkout whose almsdm_warp runs (default: this one)")
    ap.add_argument("extra", nargs="*", help="more arguments for almsdm sweep (after --)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.mesh_dir or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        print(f"almsdm sweep --points {args.points} --device {args.device} {' '.join(args.extra)} ({args.tree.resolve()})")
        print(f"{'vertices':>9} {'loading s':>10} {'outside s':>10} {'kernels s':>10} {'kernels %':>10} {'sweep s':>9} "
              f"{'process s':>10} {'peak RSS MiB':>13}")
        for n in args.sizes:
            r = run_sweep(args.tree.resolve(), write_organ(folder, n), args, Path(tmp) / f"sweep_{n}.npz")
            if "error" in r:
                print(f"{n:>9} failed after {r['process_s']:.1f} s: {' '.join(r['error'])}", flush=True)
                continue
            outside = r["sweep_s"] - r["kernels_s"] - r["loading_s"]
            share = 100 * r["kernels_s"] / max(r["sweep_s"], 1e-9)
            print(f"{n:>9} {r['loading_s']:>10.2f} {outside:>10.2f} {r['kernels_s']:>10.2f} {share:>10.1f} {r['sweep_s']:>9.2f} "
                  f"{r['process_s']:>10.2f} {r['peak_rss_MiB']:>13.0f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
