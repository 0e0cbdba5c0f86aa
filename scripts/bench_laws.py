"""One palpation's CPU step with each tissue law on the same region, interleaved in one process.

    python scripts/bench_laws.py [--rings 3] [--blocks 15] [--steps 1000] [--scene liver]
    python scripts/bench_laws.py --scene liver --integrator implicit --dt-ms 1   # the liver scene's own step
    valgrind --tool=callgrind --instr-atstart=no --callgrind-out-file=/tmp/cg.out python scripts/bench_laws.py --callgrind
        # instructions a step of each law (repeatable on a loaded host)

A 25 mm tet ball of 3 mm edges (mesh.primitives.tet_ball), E 10 kPa, nu 0.45, the top vertex held
1 mm in, dt 0.1 ms in one substep (under both laws' critical steps; --integrator implicit, --dt-ms:
backward Euler and its frame, as the shipped liver scene steps); --scene: a shipped scene's mesh,
material, support and ring count instead (its top vertex held 1 mm in); blocks of `steps`
`Palpation.step()` calls alternate between the laws. Prints each law's median and best
microseconds a step and their ratio. A benchmark, not a test.
"""

import argparse
import statistics
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rings", type=int, default=3)
    ap.add_argument("--blocks", type=int, default=15)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--scene", default=None, help="a shipped scene (liver) in place of the tet ball")
    ap.add_argument("--integrator", default="explicit", choices=("explicit", "implicit"))
    ap.add_argument("--dt-ms", type=float, default=0.1, help="the step [ms] (default 0.1: one explicit substep)")
    ap.add_argument("--callgrind", action="store_true", help="run under valgrind's callgrind: instrument one block of each law, print instructions a step")
    args = ap.parse_args(argv)
    from almsdm_warp.warp_init import init_warp

    init_warp()
    from almsdm_warp.mesh.primitives import tet_ball
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.tissue.laws import LAWS
    from almsdm_warp.tissue.material import Material

    mesh = tet_ball(25.0, 3.0)
    material = Material(youngs_modulus=10e3, poisson_ratio=0.45, density=1000.0, rayleigh_alpha=60.0)
    fixed_below = None
    if args.scene:
        from almsdm_warp.scene.loader import default_scene_path, load_scene

        scene = load_scene(default_scene_path(args.scene))
        mesh, material, fixed_below, args.rings = scene.load_mesh(), scene.tissue, scene.fixed_below, scene.rings
    top = int(np.argmax(mesh.vertices[:, 2]))
    pals = {}
    for law in LAWS:
        p = Palpation(mesh, material, rings=args.rings, law=law, dt=args.dt_ms * 1e-3, device="cpu", substeps=1,
                      integrator=args.integrator, fixed_below=fixed_below)
        p.touch(top)
        p.set_probe(1, p.rest_position() + p.inward_normal() * 0.001)
        for _ in range(300):
            p.step()
        pals[law] = p
    first = next(iter(pals.values()))
    print(f"{mesh.summary()}; {args.rings} rings: {first.region_vertices} region vertices, {first.solver.free_count} free")
    if args.callgrind:
        import os
        import subprocess

        for k, (law, p) in enumerate(pals.items(), start=1):
            subprocess.run(["callgrind_control", "-i", "on", str(os.getpid())], stdout=subprocess.DEVNULL)
            for _ in range(args.steps):
                p.step()
            subprocess.run(["callgrind_control", "-i", "off", str(os.getpid())], stdout=subprocess.DEVNULL)
            subprocess.run(["callgrind_control", "-d", law, str(os.getpid())], stdout=subprocess.DEVNULL)
            print(f"{law}: dump {k} (instructions a step: its totals over {args.steps})")
        return
    times = {law: [] for law in pals}
    for _ in range(args.blocks):
        for law, p in pals.items():
            t0 = time.perf_counter()
            for _ in range(args.steps):
                p.step()
            times[law].append((time.perf_counter() - t0) / args.steps * 1e6)
    base = statistics.median(times["springs"])
    for law, t in times.items():
        print(f"{law}: {statistics.median(t):.2f} us a step (median), best {min(t):.2f}; {statistics.median(t) / base:.2f} x springs")


if __name__ == "__main__":
    main()
