"""The adaptive region against fixed rings and the global anchored reference (docs/adaptive.md).

    python scripts/adaptive_accuracy.py [MESH_OR_SCENE ...] [--tol-mm 0.01 0.03 0.1 0.3 1] [--seeds 3]
                                        [--device cpu] [--json out.json]

Default: the stomach and liver scenes and every mesh in ../shared/meshes (a bare mesh gets the
default tissue and is scaled to a 150 mm organ when its file units are not millimetres). At each
contact vertex (the highest surface vertex, then vertices spread over the surface), the protocol
of almsdm_warp.evaluation.adaptive_accuracy (10 mm, ramp 0.1 s, hold 0.2 s, implicit, dt 5 ms) on the global
anchored model, on rings 1..8 and on `auto` at each tolerance. For each (contact, tolerance):
N* = the fewest fixed rings with peak-force error <= 1% and displacement error <= T; whether auto
meets both; and auto's vertices against N*'s. Prints a Markdown table, one row per mesh and tolerance.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"


def load(name):
    from almsdm_warp.mesh.io import load_mesh
    from almsdm_warp.scene.loader import resolve_scene_or_mesh

    if name in ("stomach", "liver") or name.endswith(".toml"):
        scene = resolve_scene_or_mesh(name)
        return scene.load_mesh(), scene.tissue, Path(scene.mesh_path).name
    mesh = load_mesh(name)
    extent_mm = float(np.ptp(mesh.vertices, axis=0).max()) * 1e3
    if extent_mm < 50.0:  # scene units (the SOFA and MOR livers): make it a 150 mm organ
        mesh = load_mesh(name, scale=150.0 / extent_mm)
    return mesh, None, Path(name).name


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("meshes", nargs="*")
    ap.add_argument("--tol-mm", type=float, nargs="+", default=[0.01, 0.03, 0.1, 0.3, 1.0])
    ap.add_argument("--seeds", type=int, default=3, help="contact vertices per mesh")
    ap.add_argument("--max-rings", type=int, default=8)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--margin", type=float, default=None, help="safety factor on the fixed-ring estimate (default: adaptive.MARGIN)")
    ap.add_argument("--force-tol", type=float, default=None, help="AdaptivePalpation's force_tol (default: adaptive.FORCE_TOL)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    from almsdm_warp.evaluation.adaptive_accuracy import auto_point, fixed_point, global_reference, top_vertex
    from almsdm_warp.warp_init import init_warp

    init_warp()
    options = {k: v for k, v in (("margin", args.margin), ("force_tol", args.force_tol)) if v is not None}
    names = args.meshes or ["stomach", "liver"] + sorted(str(p) for p in SHARED.glob("*") if p.suffix in (".obj", ".vtu"))
    rows, records = [], []
    print("| mesh | contacts | tol (mm) | auto rings | N* (fixed) | auto meets tol | auto vertices <= N*'s | worst force error auto | worst disp error auto / T |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in names:
        mesh, tissue, label = load(name)
        sv = mesh.surface_vertices
        seeds = [top_vertex(mesh)] + [int(v) for v in sv[np.linspace(0, len(sv) - 1, max(args.seeds - 1, 0) + 2).astype(int)[1:-1]]]
        per_tol = {t: [] for t in args.tol_mm}
        for v in seeds[: args.seeds]:
            ref = global_reference(mesh, tissue, args.device, vertex=v)
            fixed = {n: fixed_point(mesh, tissue, n, args.device, vertex=v, reference=ref) for n in range(1, args.max_rings + 1)}
            for t in args.tol_mm:
                a = auto_point(mesh, tissue, t * 1e-3, args.device, vertex=v, reference=ref, options=options)
                meets = [n for n, p in fixed.items() if p["force_error"] <= 0.01 and p["displacement_error_mm"] <= t]
                n_star = min(meets) if meets else None
                ok = a["force_error"] <= 0.01 and a["displacement_error_mm"] <= t
                small = n_star is not None and a["region_vertices"] <= fixed[n_star]["region_vertices"]
                per_tol[t].append((a, n_star, ok, small))
                records.append({"mesh": label, "vertex": v, "tol_mm": t, "auto": a, "n_star": n_star,
                                "fixed": {str(n): p for n, p in fixed.items()}})
            print(f"  {label} vertex {v} done", file=sys.stderr)
        for t, items in per_tol.items():
            autos = [a["rings"] for a, *_ in items]
            stars = [n for _, n, *_ in items]
            rows.append(
                f"| {label} | {len(items)} | {t:g} | {autos} | {stars} | {sum(ok for *_, ok, _ in items)}/{len(items)} | "
                f"{sum(s for *_, s in items)}/{len(items)} | {max(a['force_error'] for a, *_ in items):.3%} | "
                f"{max(a['displacement_error_mm'] / t for a, *_ in items):.2f} |"
            )
            print(rows[-1], flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
