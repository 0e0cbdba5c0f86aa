"""`almsdm evaluate`: regenerate docs/results.md and its figures (the paper's experiments, speed
against accuracy, the stability map, real anatomy, mesh convergence and the ball against finite
elements: evaluation/continuum.py; every tissue law on a slab, deep and over a lesion:
evaluation/depth_layers.py)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..errors import InputError
from .args import add_command, get_device, quiet_warp


DEFAULT_OUT = "evaluation_results"
"""Where a run without --out writes: a folder of its own, never the committed docs/."""


def add_parser(sub) -> None:
    p = add_command(
        sub,
        "evaluate",
        "run the evaluation and write results.md and its figures",
        "Run the paper's experiments (recovery, Table 1, force against displacement, Table 2), speed against "
        "accuracy, the stability map, the real-anatomy runs, mesh convergence (the same press at three resolutions) "
        "the ball against finite elements (P2 and Hertz) and every tissue law against a neo-Hookean FEM on a slab over bone, "
        "a deep press and a lesion; write OUT/results.md, OUT/results.json and "
        "OUT/figures/*.png (nothing is written until every experiment has run).",
    )
    p.add_argument("--quick", action="store_true", help="reduced versions of every part (under 2 minutes on 2 CPU cores)")
    p.add_argument("--out", default=None, metavar="DIR", help=f"folder for results.md and figures/ (default {DEFAULT_OUT}/, made if missing; "
                   "the project's committed results are docs/: --out docs replaces them)")
    p.add_argument("--extra-json", default=None, metavar="PATH", help="step times measured elsewhere (e.g. `almsdm bench` on a GPU) to add to the speed-accuracy figure")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None, help="progress bar on stderr (default: only on a terminal)")
    p.add_argument("--settings", choices=("full", "quick", "tiny"), default=None, help=argparse.SUPPRESS)  # tests: "tiny"
    p.set_defaults(func=cmd_evaluate)


def cmd_evaluate(args) -> int:
    from ..evaluation.evaluate import run_evaluation

    make = args.out is None and not Path(DEFAULT_OUT).exists()  # the default folder is made when the run starts
    if args.out is None:
        args.out = DEFAULT_OUT
    out = Path(args.out)
    if make:
        if not os.access(out.absolute().parent, os.W_OK):
            raise InputError(f"cannot make {out}/ in {out.absolute().parent}: folder is not writable (give --out DIR)")
    elif not out.is_dir():
        raise InputError(f"--out {out}: no such folder")
    if not make and not os.access(out, os.W_OK) or ((out / "figures").exists() and not os.access(out / "figures", os.W_OK)):
        raise InputError(f"--out {out}: folder is not writable")
    if args.extra_json is not None:
        from ..evaluation.accuracy import read_extra_points

        read_extra_points(args.extra_json)  # bad input fails now, not after the run
    quiet_warp()
    device = get_device(args.device)
    settings = args.settings or ("quick" if args.quick else "full")
    if make:
        out.mkdir()
    results = run_evaluation(out, settings, str(device), command=_command(args, settings), extra_json=args.extra_json, progress=args.progress)
    print(f"wrote {out / 'results.md'}, {out / 'results.json'} and {len(results['figures'])} figures in {out / 'figures'} ({results['elapsed_s']:.0f} s)")
    return 0


def _command(args, settings) -> str:
    """The command that reproduces this run, for results.md."""
    parts = ["almsdm evaluate"]
    if settings != "full":
        parts.append("--quick" if settings == "quick" else f"--settings {settings}")
    parts += ["--device", str(args.device), "--out", str(args.out)]
    if args.extra_json:
        parts += ["--extra-json", str(args.extra_json)]
    return " ".join(parts)
