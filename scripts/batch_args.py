"""What the batch scripts share (check_batch_bits.py, check_fast_sweep.py, profile_batch.py): their
arguments (a mesh, a device, how many palpations, rings) and Warp started before the mesh loads."""

import argparse
from pathlib import Path


def batch_parser(doc: str, count: str, count_default: int, *, device: str = "cuda:0", mesh_default=None, kernel: bool = True):
    """An argument parser: MESH (optional when `mesh_default` is given), --device, `count` (an int
    option, the number of palpations), --rings and, with `kernel`, --kernel (fast or exact)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    if mesh_default is None:
        ap.add_argument("mesh", type=Path)
    else:
        ap.add_argument("mesh", nargs="?", type=Path, default=mesh_default)
    ap.add_argument("--device", default=device)
    ap.add_argument(count, type=int, default=count_default)
    ap.add_argument("--rings", type=int, default=4)
    if kernel:
        ap.add_argument("--kernel", default=None, help="fast or exact (default: the device's)")
    return ap


def load_batch_mesh(path):
    """Warp started (quietly, once) and the mesh at `path` loaded."""
    from almsdm_warp import load_mesh
    from almsdm_warp.warp_init import init_warp

    init_warp()
    return load_mesh(path)
