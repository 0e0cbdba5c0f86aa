"""Each tissue law against a neo-Hookean finite-element solve of the same tets: a sphere pressed deep,
tissue over bone, a stiff lesion. The presses are `almsdm evaluate`'s "depth, layers and lesions"
section (evaluation/depth_layers.py: the cases, the reference, the laws' presses); this prints them at
other sizes and depths.

    python scripts/law_vs_fem.py [--radius-mm 25] [--edge-mm 4] [--refine 2] [--sphere-mm 10]
        [--depths-mm 2 5 10] [--poisson 0.45] [--json out.json]
    python scripts/law_vs_fem.py --slab --edges-mm 2 1.4 1 [--sphere-mm 5] [--depths-mm 2]
    python scripts/law_vs_fem.py --lesion [--depths-mm 5]

Ball (default): a tet ball (mesh.primitives.tet_ball, graded finer at the top) resting on a support
(vertices below -0.6 R fixed), a rigid frictionless sphere pressed along -z at the top vertex.
--slab: tissue over bone, a slab 10 mm thick on a rigid base (its bottom fixed), 30 x 30 mm, its
tets of `--edges-mm` under the probe (graded to 3x that at its sides), the sphere pressed at the
top face's centre: one row per resolution. --lesion: the ball with a lesion 5x as stiff, radius 10 mm,
its centre 15 mm below the top; the force with it over the force without, each law's against the
FEM's. E 10 kPa throughout; the reference to fem_nonlinear.solve's own tolerances. Prints force / FEM
per law and depth, and the tets each law leaves inverted. An evaluation, not a test.
"""

import argparse
import json

from almsdm_warp.evaluation import depth_layers as dl


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radius-mm", type=float, default=dl.BALL["radius_mm"])
    ap.add_argument("--edge-mm", type=float, default=4.0)
    ap.add_argument("--refine", type=float, default=dl.BALL["refine_top"])
    ap.add_argument("--sphere-mm", type=float, default=None, help=f"default {dl.BALL['sphere_mm']:g} (--slab: {dl.SLAB['sphere_mm']:g})")
    ap.add_argument("--depths-mm", type=float, nargs="+", default=[2.0, 5.0, 10.0])
    ap.add_argument("--poisson", type=float, default=dl.POISSON)
    ap.add_argument("--json", default=None)
    ap.add_argument("--slab", action="store_true", help="tissue over bone: a 10 mm slab on a rigid base")
    ap.add_argument("--edges-mm", type=float, nargs="+", default=[2.0, 1.4, 1.0], help="--slab: its edges under the probe")
    ap.add_argument("--lesion", action="store_true", help="the ball with a stiff lesion: each law's force ratio against the FEM's")
    args = ap.parse_args(argv)
    from almsdm_warp.warp_init import init_warp

    init_warp()
    rows = []
    if args.slab:
        sphere = dl.SLAB["sphere_mm"] if args.sphere_mm is None else args.sphere_mm
        for h in args.edges_mm:
            for d in args.depths_mm:
                rows.append(report(dl.press_laws(dl.slab_case(h, d, sphere_mm=sphere, poisson=args.poisson))))
    else:
        sphere = dl.BALL["sphere_mm"] if args.sphere_mm is None else args.sphere_mm
        for d in args.depths_mm:
            case = dl.ball_case(args.edge_mm, d, radius_mm=args.radius_mm, refine_top=args.refine, sphere_mm=sphere, poisson=args.poisson)
            row = report(dl.press_laws(case))
            if args.lesion:
                row = report(dl.lesion_row(row, dl.press_laws(dl.with_lesion(case))))
            rows.append(row)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"rows": rows}, f, indent=1)


def report(row: dict) -> dict:
    """Print one case's line (force / FEM per law, or the lesion's ratios) and return the row."""
    if row.get("fem_N") is None:
        print(f"{row['label']}: the reference failed: {row.get('fem_error')}", flush=True)
    elif row["case"] == "lesion":
        laws = ", ".join(f"{law} {_fmt(p.get('ratio'))} ({_fmt(p.get('ratio_of_fem'))} of FEM's)" for law, p in row["laws"].items())
        print(f"{row['label']}: force ratio FEM {row['fem_ratio']:.3f}; {laws}", flush=True)
    else:
        laws = ", ".join(f"{law} {_fmt(p.get('of_fem'))} ({p.get('inverted_tets')} inverted)" if "error" not in p else f"{law} failed: {p['error']}"
                         for law, p in row["laws"].items())
        print(f"{row['label']}, {row['vertices']} vertices: FEM {row['fem_N']:.4f} N; force / FEM: {laws}", flush=True)
    return row


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.3f}"


if __name__ == "__main__":
    main()
