"""What recording costs: a press with and without the USD hook, the time per recorded frame, and
the memory of a long recording with the crate layer saved every 64 frames or only at the end.

    python scripts/bench_recording.py [MESH_OR_SCENE] [--rings 4] [--presses 10] [--suffix .usdc]

Memory is the peak resident set (ru_maxrss) of a fresh child process per setting, so the two
settings do not share a high-water mark. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def palpation(scene, rings):
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.scene.loader import resolve_scene_or_mesh

    sc = resolve_scene_or_mesh(scene)
    mesh = sc.load_mesh()
    pal = Palpation(mesh, sc.tissue, rings=rings, device="cpu")
    sv = mesh.surface_vertices
    pal.touch(int(sv[np.argmax(mesh.vertices[sv, 2])]))
    return pal


def press_times(scene, rings, repeats):
    """Median seconds of one 1.3 s press (1300 steps): no hook, and a hook that does nothing."""
    pal = palpation(scene, rings)
    pal.press()  # warm-up: compile, capture
    variants = (("no hook", {}), ("empty hook every step", {"record": lambda k, t: None}))
    times = {name: [] for name, _ in variants}
    for _ in range(repeats):  # interleaved, so that a neighbour's load hits both alike
        for name, kw in variants:
            t0 = time.perf_counter()
            pal.press(**kw)
            times[name].append(time.perf_counter() - t0)
    return {name: statistics.median(t) for name, t in times.items()}


def record(scene, rings, presses, every, flush_every, suffix):
    """Seconds per recorded frame, file size; run in a child for the memory figure."""
    import resource

    from almsdm_warp.export.usd import UsdRecorder

    pal = palpation(scene, rings)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"rec{suffix}"
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        t0 = time.perf_counter()
        with UsdRecorder(path, pal, every=every, flush_every=flush_every or None) as rec:
            rec.frame(0)
            for _ in range(presses):
                pal.press(record=rec.on_press_step, record_every=every)
        seconds = time.perf_counter() - t0
        size = path.stat().st_size
    steps = presses * 1300
    return {
        "frames": rec.frames,
        "flush_every": rec.flush_every,
        "file_MB": size / 1e6,
        "run_s": seconds,
        "maxrss_MB_before": rss0 / 1024,
        "maxrss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "steps": steps,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=None)
    ap.add_argument("--rings", type=int, default=4)
    ap.add_argument("--presses", type=int, default=10)
    ap.add_argument("--suffix", default=".usdc")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    from almsdm_warp.warp_init import init_warp

    init_warp()
    if args.child:
        every, flush = (int(x) for x in args.child.split(","))
        print(json.dumps(record(args.scene, args.rings, args.presses, every, flush, args.suffix)))
        return
    t = press_times(args.scene, args.rings, args.repeats)
    print(f"press of 1300 steps, median of {args.repeats}: " + ", ".join(f"{k} {v * 1e3:.2f} ms" for k, v in t.items()))
    print("| every | saved every | frames | run s | ms per frame (run minus press) | file MB | peak RSS MB (before recording) |")
    print("|---|---|---|---|---|---|---|")
    base = t["no hook"] * args.presses
    for every, flush in ((1, 64), (1, 0), (1, 10**9), (10, 0)):  # flush 0: the default, ~64 MB
        cmd = [sys.executable, __file__, *([args.scene] if args.scene else []), "--rings", str(args.rings)]
        cmd += ["--presses", str(args.presses), "--suffix", args.suffix, "--child", f"{every},{flush}"]
        r = json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.splitlines()[-1])
        per_frame = (r["run_s"] - base) / r["frames"] * 1e3
        flush_text = "end only" if flush >= 10**9 else (f"{flush} frames" if flush else "64 MB (default)")
        print(f"| {every} | {flush_text} | {r['frames']} | {r['run_s']:.2f} | {per_frame:.3f} | {r['file_MB']:.1f} | {r['maxrss_MB']:.0f} ({r['maxrss_MB_before']:.0f}) |", flush=True)


if __name__ == "__main__":
    main()
