"""How many rings does a shipped scene need? The peak force of its own press against the global model.

For each scene (its mesh, tissue, probe, supports and press, as `almsdm palpate` runs it), at
`--contacts` contacts spread by farthest-point sampling over the surface vertices the support does
not hold (starting from the top vertex), with each integrator: the peak force of the global model
(the same springs, anchors and supports over the whole mesh, no ring boundary) and of 1..`--max-rings`
rings; the worst relative error over the contacts per ring count (of the peak, and of the force at
the end of the hold), and the smallest ring count within `--tol` of the peak at every contact. With a sphere the region grows from the patch the sphere covers at
the press depth, as the command line's. A scene with a lesion adds the contact nearest the lesion.

    python scripts/scene_rings.py [--scenes stomach liver] [--contacts 12] [--max-rings 4] [--tol 0.01]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from almsdm_warp.batch.sampling import farthest_points
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.region.contact import top_vertex
from almsdm_warp.scene.loader import default_scene_path, load_scene


def contacts(mesh, scene, n: int) -> np.ndarray:
    """`n` surface vertices spread over the organ (farthest-point, from the top one), none held by the support."""
    v = mesh.vertices
    surface = np.asarray(mesh.surface_vertices)
    if scene.fixed_below is not None:
        surface = surface[v[surface, 2] >= scene.fixed_below]
    start = int(np.flatnonzero(surface == top_vertex(mesh))[0])
    picked = surface[farthest_points(v[surface], n, start)]
    if scene.lesion is None:
        return picked
    # and the surface vertex nearest the lesion's centre, where the stiffer tissue is pressed
    near = int(surface[np.argmin(np.linalg.norm(v[surface] - np.asarray(scene.lesion.center), axis=1))])
    return np.append(picked[picked != near], near)


def press_forces(mesh, scene, rings, vertex: int, integrator: str, dt: float) -> tuple[float, float, int]:
    """(peak force [N] of the scene's press at `vertex`, force at the end of the hold [N], region
    vertices; the whole mesh for "global")."""
    p = scene.press
    scales = scene.lesion.scales(mesh, scene.tissue) if scene.lesion is not None else (None, None)
    pal = Palpation(mesh, scene.tissue, rings=rings, integrator=integrator, dt=dt, device="cpu",
                    fixed_below=scene.fixed_below, probe_radius=scene.probe_radius, edge_scale=scales[0], anchor_scale=scales[1])
    if scene.probe_radius > 0:
        pal.touch(vertex, p.depth)
    else:
        pal.touch(vertex)
    result = pal.press(p.depth, ramp=p.ramp, hold=p.hold, settle=dt)  # the peak comes before release
    size = pal.region_vertices if pal.region is not None else mesh.vertex_count
    return result.peak_force_N, float(result.force[result.release_step - 1]), size


def run_scene(name: str, args) -> None:
    scene = load_scene(default_scene_path(name))
    mesh = scene.load_mesh()
    picked = contacts(mesh, scene, args.contacts)
    print(f"\n{scene.summary()}; probe R {scene.probe_radius * 1e3:g} mm; {len(picked)} contacts: {picked.tolist()}")
    for integrator in args.integrators:
        start = time.perf_counter()
        errors = np.zeros((args.max_rings, len(picked)))
        hold_errors = np.zeros((args.max_rings, len(picked)))
        sizes = np.zeros((args.max_rings, len(picked)), dtype=int)
        reference = np.zeros(len(picked))
        for c, vertex in enumerate(picked):
            reference[c], hold, _ = press_forces(mesh, scene, "global", int(vertex), integrator, args.dt)
            for rings in range(1, args.max_rings + 1):
                force, held, sizes[rings - 1, c] = press_forces(mesh, scene, rings, int(vertex), integrator, args.dt)
                errors[rings - 1, c] = force / reference[c] - 1.0
                hold_errors[rings - 1, c] = held / hold - 1.0
        print(f"\n{integrator}, dt {args.dt * 1e3:g} ms ({time.perf_counter() - start:.0f} s): global peak "
              f"{reference.min():.5f}..{reference.max():.5f} N")
        print("| rings | region vertices (median / max) | worst peak error (at) | median peak error | worst end-of-hold error (at) |")
        print("|---|---|---|---|---|")
        for r in range(args.max_rings):
            w = int(np.argmax(np.abs(errors[r])))
            h = int(np.argmax(np.abs(hold_errors[r])))
            print(f"| {r + 1} | {int(np.median(sizes[r]))} / {sizes[r].max()} | {errors[r, w]:+.3%} (vertex {picked[w]}) | "
                  f"{np.median(errors[r]):+.3%} | {hold_errors[r, h]:+.3%} (vertex {picked[h]}) |")
        if args.per_contact:
            print("per contact (vertex: global peak [N], error at 1.. rings): " + "; ".join(
                f"{v}: {reference[c]:.4f}, " + " ".join(f"{e:+.2%}" for e in errors[:, c]) for c, v in enumerate(picked)))
        within = [r + 1 for r in range(args.max_rings) if np.all(np.abs(errors[r]) <= args.tol)]
        print(f"smallest ring count within {args.tol:.1%} of the peak at every contact: {within[0] if within else 'none'}", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["stomach", "liver"])
    parser.add_argument("--integrators", nargs="+", choices=["explicit", "implicit"], default=["implicit", "explicit"])
    parser.add_argument("--contacts", type=int, default=12)
    parser.add_argument("--max-rings", type=int, default=4)
    parser.add_argument("--tol", type=float, default=0.01, help="relative force error allowed (default 0.01)")
    parser.add_argument("--per-contact", action="store_true", help="print every contact's error too")
    parser.add_argument("--dt", type=float, default=1e-3, help="frame [s] (default 1e-3, the command line's)")
    args = parser.parse_args(argv)
    for name in args.scenes:
        run_scene(name, args)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
