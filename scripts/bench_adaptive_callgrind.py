"""Instructions per step of AdaptivePalpation against Palpation (repeatable, unlike wall time here).

    valgrind --tool=callgrind --instr-atstart=no --callgrind-out-file=cg.out \
        $(python -c 'import sys; print(sys.executable)') scripts/bench_adaptive_callgrind.py 3 5000
    callgrind_annotate cg.out.1 | head -30   # fixed;  cg.out.2: auto

Builds both models at RINGS rings on the stomach scene (explicit, dt 1 ms, probe held 5 mm in),
then for each switches instrumentation on around STEPS steps and dumps the counts (a dump each).
The adaptive one has tol 1 m and no force criterion: it checks every 10 steps but never grows.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def callgrind(*args):
    subprocess.run(["callgrind_control", *args, str(os.getpid())], stdout=subprocess.DEVNULL, check=False)


def main():
    from almsdm_warp import load_mesh
    from almsdm_warp.protocol.adaptive import AdaptivePalpation
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.warp_init import init_warp

    init_warp()
    rings, steps = (int(a) for a in sys.argv[1:3]) if len(sys.argv) > 2 else (3, 5000)
    mesh = load_mesh(ROOT / "scenes" / "stomach.obj")
    v = int(mesh.surface_vertices[np.argmax(mesh.vertices[mesh.surface_vertices, 2])])
    fixed = Palpation(mesh, None, rings=rings, dt=1e-3, device="cpu")
    fixed.touch(v)
    auto = AdaptivePalpation(mesh, None, tol=1.0, dt=1e-3, device="cpu", retire=False, force_tol=1e9)
    auto.touch(v)
    auto.rebuild(rings)
    for p in (fixed, auto):
        p.set_probe(1, p.rest_position() + p.inward_normal() * 0.005)
        for _ in range(100):
            p.step()
    for name, p in (("fixed", fixed), ("auto", auto)):
        callgrind("-z")
        callgrind("-i", "on")
        for _ in range(steps):
            p.step()
        callgrind("-i", "off")
        callgrind("-d", name)


if __name__ == "__main__":
    main()
