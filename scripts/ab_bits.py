"""The same bits as another checkout: every path's results on the CPU, old tree against new.

    python scripts/ab_bits.py OLD_CHECKOUT [--new NEW_CHECKOUT]

Runs the same presses in a subprocess on each tree (PYTHONPATH set to it, its own Warp kernel
cache) and compares every array bit for bit: one palpation (explicit and implicit; the paper's
probe and the shipped scene's sphere; substeps), the batch (exact, fast on the CPU, implicit; both
probes), several probes (MultiPalpation), a sliding probe (ProbeStroke, explicit and implicit), the
adaptive region. For a refactoring that must change no result. Uses only the public API both trees
have; exits 1 when any array differs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]

CHILD = r"""
import sys
import numpy as np
from almsdm_warp.warp_init import init_warp
init_warp()
from almsdm_warp import load_mesh
from almsdm_warp.batch.batch_palpation import BatchPalpation
from almsdm_warp.protocol.adaptive import AdaptivePalpation
from almsdm_warp.protocol.multi import MultiPalpation
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.protocol.stroke import ProbeStroke, builtin_stroke
from almsdm_warp.scene.loader import load_scene

out = {}
paper = load_mesh("scenes/stomach.obj")
scene = load_scene("scenes/stomach.toml")
smesh = scene.load_mesh()
top = int(paper.surface_vertices[np.argmax(paper.vertices[paper.surface_vertices, 2])])
verts = np.random.default_rng(1).choice(paper.surface_vertices, 12, replace=False)


def keep(key, result):
    for name in ("force", "displacement"):
        out[f"{key} {name}"] = np.asarray(getattr(result, name))
    out[f"{key} peak"] = np.array([result.peak_force_N])


for integrator in ("explicit", "implicit"):
    for substeps in ("auto", 3):
        pal = Palpation(paper, None, rings=4, integrator=integrator, dt=1e-3, device="cpu", substeps=substeps)
        pal.touch(top)
        keep(f"paper {integrator} {substeps}", pal.press(0.01, ramp=0.05, hold=0.05, settle=0.1))
        out[f"paper {integrator} {substeps} q"] = pal.positions()
    pal = Palpation(smesh, scene.tissue, rings=scene.rings, integrator=integrator, dt=1e-3, device="cpu",
                    probe_radius=scene.probe_radius)
    pal.touch(top)
    keep(f"stomach {integrator}", pal.press(0.01, ramp=0.05, hold=0.05, settle=0.1))
    out[f"stomach {integrator} q"] = pal.positions()
    glob = Palpation(paper, None, rings="global", integrator=integrator, dt=1e-3, device="cpu")
    glob.touch(top)
    keep(f"global {integrator}", glob.press(0.01, ramp=0.05, hold=0.05, settle=0.1))
    pal = Palpation(paper, None, rings=3, integrator=integrator, dt=1e-3, device="cpu")
    pal.touch(top)
    keep(f"paper force-press {integrator}", pal.press_force(1.0, ramp=0.05, hold=0.05, settle=0.1))

for kernel, integrator, radius, mesh, tissue in (
    ("exact", "explicit", 0.0, paper, None), ("fast", "explicit", 0.0, paper, None), ("exact", "implicit", 0.0, paper, None),
    ("exact", "explicit", scene.probe_radius, smesh, scene.tissue), ("fast", "explicit", scene.probe_radius, smesh, scene.tissue),
    ("exact", "implicit", scene.probe_radius, smesh, scene.tissue),
):
    bp = BatchPalpation(mesh, tissue, rings=3, dt=1e-3, device="cpu", kernel=kernel, integrator=integrator, probe_radius=radius)
    bp.touch(verts)
    r = bp.press(0.01, ramp=0.05, hold=0.05, settle=0.1)
    for name in ("peak_force", "hold_force", "recovery_error"):
        out[f"batch {kernel} {integrator} R{radius:g} {name}"] = getattr(r, name)

for integrator in ("explicit", "implicit"):
    dt = 1e-3 if integrator == "explicit" else 5e-3
    multi = MultiPalpation(smesh, scene.tissue, rings=2, integrator=integrator, dt=dt, device="cpu")
    multi.touch(verts[:2])
    for i, r in enumerate(multi.press(0.005, ramp=0.05, hold=0.05, settle=0.1)):
        keep(f"multi {integrator} {i}", r)
    auto = AdaptivePalpation(smesh, scene.tissue, tol=1e-4, integrator=integrator, dt=1e-3, device="cpu")
    auto.touch(top)
    keep(f"adaptive {integrator}", auto.press(0.005, ramp=0.05, hold=0.05, settle=0.1))
    path = builtin_stroke(smesh, 0.005, depth=0.003, length=0.01, speed=0.02, vertex=top, hold=0.02)
    stroke = ProbeStroke(smesh, scene.tissue, probe_radius=0.005, rings=2, device="cpu", integrator=integrator)
    out[f"stroke {integrator} force"] = np.array([stroke.step(c) for c in path.centre])
    out[f"stroke {integrator} q"] = stroke.positions()

np.savez(sys.argv[1], **out)
"""


def run(tree: Path, dest: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), WARP_CACHE_PATH=str(tree / ".warp_cache"))
    proc = subprocess.run([sys.executable, "-c", CHILD, str(dest)], cwd=tree, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{tree}: failed\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}")
    with np.load(dest) as z:
        return {k: z[k] for k in z.files}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path)
    ap.add_argument("--new", type=Path, default=HERE)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        old = run(args.old.resolve(), Path(tmp) / "old.npz")
        new = run(args.new.resolve(), Path(tmp) / "new.npz")
    differ = 0
    for key in old:
        same = key in new and old[key].shape == new[key].shape and np.array_equal(old[key], new[key])
        if not same:
            differ += 1
            diff = np.max(np.abs(old[key] - new[key])) if key in new and old[key].shape == new[key].shape else "shape"
            print(f"DIFFERS {key}: max |old - new| = {diff}")
    print(f"{len(old) - differ} of {len(old)} arrays the same bits ({differ} differ)")
    sys.exit(1 if differ else 0)


if __name__ == "__main__":
    main()
