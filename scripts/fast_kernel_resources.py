"""Registers, spills and shared memory of the fast batch kernel's variants, compiled for a GPU without one.

Warp's NVRTC writes each variant's PTX for `--arch` (no CUDA driver needed); `ptxas -v` (CUDA's, on
the PATH) assembles it and reports what a thread uses. A plan is the kernel's compile-time sizes:
threads a block, vertex, free-vertex and spring capacities (springs a thread follow). The default
plans are the paper probe's (R = 0, 4 rings) and the stomach scene's at 1 and 4 rings
(docs/performance.md); `--registers` assembles each with other register caps too.

    python scripts/fast_kernel_resources.py [--threads 64 128 256] [--registers 80 128] [--arch 90] [--ptx-version 9.0]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

PLANS = {"paper R 0, 4 rings": (64, 48, 144, False), "scene, 1 ring": (192, 144, 464, True), "scene, 4 rings": (352, 288, 896, True)}
"""name: (vertex capacity, free-vertex capacity, spring capacity, sphere)."""


def ptxas(ptx: Path, arch: int, registers: int, version: str | None) -> str:
    """`ptxas -v`'s registers, spills and shared memory for the PTX with its register cap set to
    `registers` (and its `.version` set to `version`, for a ptxas older than Warp's NVRTC)."""
    text = ptx.read_text().replace("\0", "")
    text = re.sub(r"\.maxnreg \d+", f".maxnreg {registers}", text)
    if version:
        text = re.sub(r"^\.version [\d.]+", f".version {version}", text, flags=re.M)
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "k.ptx"
        src.write_text(text)
        out = subprocess.run(["ptxas", f"-arch=sm_{arch}", "-v", str(src), "-o", str(Path(tmp) / "k.cubin")], capture_output=True, text=True)
    if out.returncode != 0:  # a PTX newer than this ptxas: say so rather than guess
        return "ptxas failed: " + out.stderr.strip().splitlines()[0]
    found = re.findall(r"(\d+) bytes spill stores|(\d+) bytes spill loads|Used (\d+) registers|(\d+) bytes smem", out.stderr)
    stores, loads, regs, smem = (next(g[i] for g in found if g[i]) for i in range(4))
    return f"{regs} registers, spills {stores} B stored / {loads} B loaded, {smem} B shared"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[64, 128, 256])
    parser.add_argument("--registers", type=int, nargs="+", default=None, help="register caps (default: the kernel's MAX_REGISTERS)")
    parser.add_argument("--arch", type=int, default=90, help="compute capability x 10 (default 90: H100, H200)")
    parser.add_argument("--ptx-version", default=None, help="rewrite the PTX's .version (e.g. 9.0) for an older ptxas")
    args = parser.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.init()
    from almsdm_warp.kernels.explicit.batch_fast import MAX_REGISTERS, press_kernel_fast

    print("| plan | threads | springs a thread | register cap | ptxas |\n|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name, (cv, cf, cs, sphere) in PLANS.items():
            for threads in args.threads:
                per_thread = -(-cs // threads)
                kernel = press_kernel_fast(threads, per_thread, cv, cf, cs, 6, sphere=sphere)
                (ptx,) = wp.compile_aot_module(kernel.module, arch=args.arch, module_dir=Path(tmp) / f"{cs}_{threads}", use_ptx=True)
                for registers in args.registers or [MAX_REGISTERS]:
                    print(f"| {name} | {threads} | {per_thread} | {registers} | {ptxas(Path(ptx), args.arch, registers, args.ptx_version)} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
