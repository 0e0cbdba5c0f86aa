"""One palpation's CPU step, old tree against new, in alternating subprocesses (A/B interleaved).

    python scripts/ab_step_cpu.py OLD_CHECKOUT [--new NEW_CHECKOUT] [--alternations 5] [--blocks 15]
    python scripts/ab_step_cpu.py OLD_CHECKOUT --callgrind      # instructions a step (valgrind)

OLD_CHECKOUT: another checkout of the project (``git worktree add /tmp/old REV``). Each alternation
runs one subprocess on the old tree, then one on the new (default: this checkout), each with its
own PYTHONPATH and Warp kernel cache, and times, in that process:
- ``paper explicit`` / ``paper implicit``: scenes/stomach.obj on the paper's preset, 4 rings, the
  contact vertex held 5 mm in (almsdm_warp.evaluation.bench.measure);
- ``stomach explicit`` / ``stomach implicit``: the shipped default scene (scenes/stomach.toml: the
  material, its 10 mm sphere and its ring count), the sphere held 5 mm in.
Each figure is the median over blocks of 2000 `Palpation.step()` calls (the captured graph's
replay and a read of the force); the table gives the median of the runs' medians and new / old.
With --callgrind each tree runs once under valgrind's callgrind, instrumented only around 2000
steps of each configuration, and the figure is instructions a step: repeatable whatever else the
machine is doing (wall time on a shared 2-core machine is not). Uses only the public API both trees
have. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, os, statistics, subprocess, sys, time
import numpy as np
from almsdm_warp.warp_init import init_warp
init_warp()
from almsdm_warp import load_mesh
from almsdm_warp.evaluation.bench import measure, top_vertex
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.scene.loader import load_scene
from almsdm_warp.sim.model import PROBE_SPHERE

blocks = int(sys.argv[1])
grind = len(sys.argv) > 2
out = {}
dumps = []


def instrument(on, label=None):
    subprocess.run(["callgrind_control", "-i", "on" if on else "off", str(os.getpid())], stdout=subprocess.DEVNULL)
    if label:
        subprocess.run(["callgrind_control", "-d", label, str(os.getpid())], stdout=subprocess.DEVNULL)
        dumps.append(label)


def timed(key, step):
    if grind:
        for _ in range(20):
            step()
        instrument(True)
        for _ in range(2000):
            step()
        instrument(False, key)
        return None
    per = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        for _ in range(2000):
            step()
        per.append((time.perf_counter() - t0) / 2000)
    return statistics.median(per) * 1e6


mesh = load_mesh("scenes/stomach.obj")
for integrator in ("explicit", "implicit"):
    if grind:
        pal = Palpation(mesh, None, rings=4, integrator=integrator, dt=1e-3, device="cpu")
        pal.touch(top_vertex(mesh))
        pal.set_probe(1, pal.rest_position() + pal.inward_normal() * 0.005)
        for _ in range(500):
            pal.step()
        out[f"paper {integrator}"] = timed(f"paper {integrator}", pal.step)
    else:
        out[f"paper {integrator}"] = measure(mesh, 4, integrator, "cpu", blocks)["step_us_median"]
scene = load_scene("scenes/stomach.toml")
smesh = scene.load_mesh()
for integrator in ("explicit", "implicit"):
    pal = Palpation(smesh, scene.tissue, rings=scene.rings, integrator=integrator, dt=1e-3, device="cpu",
                    probe_radius=scene.probe_radius)
    v = top_vertex(smesh)
    pal.touch(v, 0.005)
    n = pal.inward_normal()
    centre = pal.rest_position() - n * pal.probe_radius + n * 0.005
    pal.set_probe(PROBE_SPHERE, centre)
    for _ in range(500):
        pal.step()
    out[f"stomach {integrator}"] = timed(f"stomach {integrator}", pal.step)
    assert np.isfinite(pal.feedback_force[2])
print("RESULT " + json.dumps(out))
"""


def run(tree: Path, blocks: int, grind: bool = False) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), WARP_CACHE_PATH=str(tree / ".warp_cache"))
    cmd = [sys.executable, "-c", CHILD, str(blocks)]
    if grind:
        subprocess.run(cmd, cwd=tree, env=env, capture_output=True)  # compile the kernels outside valgrind
        out = tree / ".callgrind"
        out.mkdir(exist_ok=True)
        for old in out.glob("cg.out*"):
            old.unlink()
        cmd = ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}/cg.out", *cmd, "grind"]
    proc = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            result = json.loads(line[7:])
            if grind:  # instructions a step from each dump (cg.out.1, .2, ... in the order taken)
                for k, key in enumerate(result, start=1):
                    text = (out / f"cg.out.{k}").read_text(errors="replace")
                    total = next(int(l.split()[1]) for l in text.splitlines() if l.startswith("totals:"))
                    result[key] = total / 2000
            return result
    raise SystemExit(f"{tree}: no result\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path)
    ap.add_argument("--new", type=Path, default=HERE)
    ap.add_argument("--alternations", type=int, default=5)
    ap.add_argument("--blocks", type=int, default=15)
    ap.add_argument("--callgrind", action="store_true", help="instructions a step under callgrind (one run a tree)")
    args = ap.parse_args(argv)
    if args.callgrind:
        res = {side: run(tree.resolve(), 1, grind=True) for side, tree in (("old", args.old), ("new", args.new))}
        print("| step, CPU | old instructions | new instructions | new / old |\n|---|---|---|---|")
        for key, o in res["old"].items():
            print(f"| {key} | {o:,.0f} | {res['new'][key]:,.0f} | {res['new'][key] / o:.4f} |")
        return
    old, new = args.old.resolve(), args.new.resolve()
    runs = {"old": [], "new": []}
    for a in range(args.alternations):
        for side, tree in (("old", old), ("new", new)):
            runs[side].append(run(tree, args.blocks))
            print(f"alternation {a + 1} {side}: " + ", ".join(f"{k} {v:.3f} us" for k, v in runs[side][-1].items()), flush=True)
    print(f"\n| step, CPU (median of {args.alternations} run medians) | old us | new us | new / old |\n|---|---|---|---|")
    for key in runs["old"][0]:
        o = statistics.median(r[key] for r in runs["old"])
        n = statistics.median(r[key] for r in runs["new"])
        print(f"| {key} | {o:.3f} | {n:.3f} | {n / o:.3f} |")


if __name__ == "__main__":
    main()
