"""Where the wall time of `almsdm sweep` goes, for N points on a device: a table.

    python scripts/sweep_breakdown.py --points 1000000 --device cuda:0
    python scripts/sweep_breakdown.py --points 1000000 --device cuda:0 --tree OLD_CHECKOUT   # before
    python scripts/sweep_breakdown.py --points 100000 --device cpu --cprofile host.prof       # host costs

Runs the command in a fresh process (PYTHONPATH set to --tree, default this checkout) and reads
its output. A tree whose command has --profile prints the phases (sampling, set-up, region build,
planning, launch, waiting for the device, read-back, checks, writing, gather, output) and the
press kernels' device time. An older one gives only the process's wall time and the command's own
"pressed N points in S s" line: its press-kernel time is then the kernel-only figure of
scripts/ab_batch_cuda.py for the same batch. Either way the process's start-up (imports, Warp's
and the device's start, the mesh) is the wall time less the sweep's.
--cprofile FILE: run the command under cProfile (host costs; best on the CPU) and print the 25
functions of most cumulative time.
"""

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=100000)
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--scene", default="stomach")
    ap.add_argument("--tree", type=Path, default=HERE, help="checkout whose almsdm_warp runs (default: this one)")
    ap.add_argument("--suffix", default=".npz", choices=(".npz", ".csv"), help="the table's format")
    ap.add_argument("--cprofile", type=Path, default=None, metavar="FILE")
    ap.add_argument("extra", nargs="*", help="more arguments for almsdm sweep (after --)")
    args = ap.parse_args(argv)
    tree = args.tree.resolve()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), *filter(None, [os.environ.get("PYTHONPATH")])])}
    has_profile = "--profile" in subprocess.run([sys.executable, "-m", "almsdm_warp.cli.main", "sweep", "--help"],
                                                cwd=tree, env=env, capture_output=True, text=True).stdout
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / f"sweep{args.suffix}"
        cmd = ["-m", "almsdm_warp.cli.main", "sweep", args.scene, "--points", str(args.points), "--device", args.device,
               "--out", str(out), "--no-progress", *(["--profile"] if has_profile else []), *args.extra]
        if args.cprofile is not None:
            cmd = ["-m", "cProfile", "-o", str(args.cprofile.resolve()), *cmd]
        t0 = time.perf_counter()
        run = subprocess.run([sys.executable, *cmd], cwd=tree, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t0
    if run.returncode != 0:
        sys.exit(f"almsdm sweep failed ({run.returncode}):\n{run.stdout}{run.stderr}")
    print(f"{tree}: almsdm sweep {args.scene} --points {args.points} --device {args.device} ({args.suffix})")
    print(f"{'process wall':<26}{wall:10.3f} s")
    pressed = re.search(r"pressed \d+ points in ([0-9.]+) s", run.stdout)
    if pressed:
        print(f"{'pressing (command line)':<26}{float(pressed.group(1)):10.3f} s  (models, chunks and their writes)")
    table = run.stdout.split("where the sweep's wall time went", 1)
    if len(table) == 2:
        lines = table[1].splitlines()[1:]
        print("\n".join(line for line in lines if not line.startswith("wrote ")))
        sweep = re.search(r"^wall\s+([0-9.]+) s", table[1], re.M)
        if sweep:
            print(f"{'process start-up':<26}{wall - float(sweep.group(1)):10.3f} s  (imports, Warp, device, mesh)")
    else:
        print("(no --profile in this tree: the press kernels' own time is scripts/ab_batch_cuda.py's for this batch)")
    if args.cprofile is not None:
        import pstats

        pstats.Stats(str(args.cprofile)).sort_stats("cumulative").print_stats(25)


if __name__ == "__main__":
    main()
