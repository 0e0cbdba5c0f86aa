"""A batch's region-steps per second with each tissue law on the shipped liver scene, in one process.

    python scripts/bench_laws_batch.py [--device cuda:0] [--batch 100000] [--rings 6] [--steps 300] [--repeats 3]
    python scripts/bench_laws_batch.py --integrator implicit --dt-ms 1 --batch 2000 --steps 30   # the scene's own step

The liver scene's tet mesh, material, sphere and support (scenes/liver.toml), B contacts spread over
the surface its support leaves free, each law's batch (the exact kernel for the neo-Hookean law: the
fast kernel is a layout of the springs law) timed over `steps` steps of a press after one that
compiles, between device synchronizations (dt 0.1 ms in one step, under both laws' critical steps;
--integrator implicit, --dt-ms: backward Euler and its frame, a region's system in memory each: fewer
contacts); the median of `repeats`. Prints both and their ratio.
A benchmark, not a test.
"""

import argparse
import statistics
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--batch", type=int, default=100000)
    ap.add_argument("--rings", type=int, default=None, help="the scene's ring count by default")
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--integrator", default="explicit", choices=("explicit", "implicit"))
    ap.add_argument("--dt-ms", type=float, default=0.1)
    ap.add_argument("--laws", nargs="+", default=None, help="the laws to time (default: every law)")
    args = ap.parse_args(argv)
    from almsdm_warp.warp_init import init_warp

    init_warp()
    import warp as wp

    from almsdm_warp.batch.batch_palpation import BatchPalpation
    from almsdm_warp.scene.loader import default_scene_path, load_scene
    from almsdm_warp.sim.model import Model
    from almsdm_warp.tissue.laws import LAWS

    scene = load_scene(default_scene_path("liver"))
    mesh = scene.load_mesh()
    surface = np.asarray(mesh.surface_vertices)
    surface = surface[mesh.vertices[surface, 2] >= scene.fixed_below]
    vertices = np.resize(np.random.default_rng(0).permutation(surface), args.batch).astype(np.int64)
    rings = args.rings or scene.rings
    rates = {}
    for law in args.laws or LAWS:
        model = Model(mesh, scene.tissue, args.device, fixed_below=scene.fixed_below, law=law)
        bp = BatchPalpation(model=model, rings=rings, dt=args.dt_ms * 1e-3, probe_radius=scene.probe_radius, substeps=1,
                            integrator=args.integrator)
        bp.touch(vertices, scene.press.depth)
        if args.integrator == "explicit":
            bp.start_press(scene.press.depth, scene.press.ramp, scene.press.hold, scene.press.settle)  # compile and load
            steps = lambda: bp.launch_steps(0, args.steps)
        else:  # a press of `steps` frames: half a ramp, half a settle (each frame a launch)
            half = args.steps * bp.frame_dt / 2
            steps = lambda: bp.start_press(scene.press.depth, half, 0.0, half)
            steps()  # compile and load
        wp.synchronize_device(bp.device)
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            steps()
            wp.synchronize_device(bp.device)
            times.append(time.perf_counter() - t0)
        rates[law] = args.batch * args.steps / statistics.median(times)
        print(f"{law}: {rates[law]:.4e} region-steps/s ({bp.kernel} kernel, regions of {int(np.median(bp.region_vertex_counts))} "
              f"vertices median, {int(bp.region_vertex_counts.max())} max, B = {args.batch}, {rings} rings)", flush=True)
    if {"springs", "neo-hookean"} <= rates.keys():
        print(f"neo-hookean / springs: {rates['neo-hookean'] / rates['springs']:.3f}")


if __name__ == "__main__":
    main()
