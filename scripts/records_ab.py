"""What the rows for learning cost a sweep: the same sweep without and with records, interleaved in one
process (A B A B ...), after one warm-up of each (kernel compilation), medians of the wall time of
`almsdm sweep` in-process; and whether the rows change the default columns (they must not).

    python scripts/records_ab.py --device cpu --points 2000 --rounds 5
    python scripts/records_ab.py --device cuda:0 --points 200000 --rounds 5 --scene stomach
    python scripts/records_ab.py --device cuda:0 --points 200000 --rounds 5 --scene paper_stomach --records "--curve-points 16"

A: the default sweep; B: the same with --records (default "--curve-points 16 --tactile-size 8", which
needs a sphere: the shipped stomach scene has one; paper_stomach takes --curve-points only).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import shlex
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def sweep(argv: list[str]) -> float:
    """Wall time [s] of one `almsdm sweep` in this process (its output swallowed); SystemExit on failure."""
    from almsdm_warp.cli.main import main

    out = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        code = main(argv)
    if code != 0:
        sys.exit(f"almsdm sweep {' '.join(argv)} failed ({code}):\n{out.getvalue()}")
    return time.perf_counter() - t0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="stomach")
    p.add_argument("--device", default="cpu")
    p.add_argument("--points", type=int, default=2000)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--records", default="--curve-points 16 --tactile-size 8")
    p.add_argument("--press", default="", help="extra sweep arguments for both (e.g. '--ramp-s 0.05 --hold-s 0.05')")
    args = p.parse_args()
    from almsdm_warp.batch.sweep_plan import SWEEP_TABLE

    folder = Path(tempfile.mkdtemp(prefix="records_ab."))
    base = ["sweep", args.scene, "--points", str(args.points), "--device", args.device, "--no-progress", *shlex.split(args.press)]
    runs = {"A (default)": base, f"B ({args.records})": base + shlex.split(args.records)}
    times = {k: [] for k in runs}
    for r in range(args.rounds + 1):  # round 0: warm-up (kernels compiled or loaded), not counted
        for k, argv in runs.items():
            out = folder / f"{'AB'[list(runs).index(k)]}{r}.npz"
            t = sweep([*argv, "--out", str(out)])
            if r:
                times[k].append(t)
    a, b = (SWEEP_TABLE.read(folder / f"{x}{args.rounds}.npz") for x in "AB")
    same = all(np.array_equal(a[c], b[c], equal_nan=True) for c in SWEEP_TABLE.dtypes)
    print(f"{args.scene}, {args.points} points on {args.device}, {args.rounds} rounds A/B interleaved (medians):")
    for k, ts in times.items():
        print(f"  {k}: {statistics.median(ts):.3f} s  (all: {', '.join(f'{t:.3f}' for t in ts)})")
    print(f"  the default columns of B {'equal' if same else 'differ from'} A's, bit for bit"
          + ("" if same or args.device == "cpu" else " (on CUDA a --tactile-size press runs the exact kernel, whose forces differ from "
                                                      "the fast kernel's by up to 5e-6 relative; with --curve-points alone they must be equal)"))


if __name__ == "__main__":
    main()
