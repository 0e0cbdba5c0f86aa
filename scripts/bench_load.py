"""Time and peak memory of load_mesh on a large closed surface (about 2 million triangles).

    python scripts/bench_load.py                # OBJ, STL and PLY, one process each
    python scripts/bench_load.py --format obj --triangles 2000000

Writes a UV sphere of radius 50 mm with about --triangles faces in each format to a temporary
folder, then loads each in a fresh process and prints its seconds and peak resident memory
(resource.getrusage: the whole process, Python and the libraries included).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def write_sphere(folder: Path, triangles: int, formats) -> dict:
    import numpy as np
    import trimesh

    n = int(np.sqrt(triangles / 4))  # a UV sphere of count [n, n] has about 4 n^2 triangles
    sphere = trimesh.creation.uv_sphere(radius=50.0, count=[n, n])
    paths = {}
    for fmt in formats:
        paths[fmt] = folder / f"sphere.{fmt}"
        sphere.export(paths[fmt])
    return {"faces": len(sphere.faces), "vertices": len(sphere.vertices), "paths": paths}


def measure(path: str) -> dict:
    import resource

    from almsdm_warp import load_mesh

    start = time.perf_counter()
    mesh = load_mesh(path)
    seconds = time.perf_counter() - start
    peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    return {"seconds": round(seconds, 2), "peak_rss_MiB": round(peak_kib / 1024), "triangles": mesh.triangle_count,
            "vertices": mesh.vertex_count}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--triangles", type=int, default=2_000_000)
    parser.add_argument("--format", choices=["obj", "stl", "ply"], action="append")
    parser.add_argument("--measure", help=argparse.SUPPRESS)  # the child process: load one file
    args = parser.parse_args(argv)
    if args.measure:
        print(json.dumps(measure(args.measure)))
        return 0
    formats = args.format or ["obj", "stl", "ply"]
    with tempfile.TemporaryDirectory() as tmp:
        made = write_sphere(Path(tmp), args.triangles, formats)
        print(f"UV sphere: {made['vertices']} vertices, {made['faces']} triangles")
        for fmt, path in made["paths"].items():
            size = path.stat().st_size / 2**20
            out = subprocess.run([sys.executable, __file__, "--measure", str(path)], capture_output=True, text=True)
            if out.returncode:
                print(f"{fmt}: failed: {out.stderr.strip().splitlines()[-1:]}")
                continue
            r = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"{fmt} ({size:.0f} MiB): {r['seconds']} s, peak RSS {r['peak_rss_MiB']} MiB, "
                  f"{r['vertices']} vertices, {r['triangles']} triangles")
    return 0


if __name__ == "__main__":
    sys.exit(main())
