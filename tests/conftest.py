"""Shared fixtures: every device present, the project's scenes, and the shared organ meshes."""

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# ../shared/meshes beside the checkout; ALMSDM_SHARED_MESHES points elsewhere (a copy carried to a GPU box)
SHARED_MESHES = Path(os.environ.get("ALMSDM_SHARED_MESHES", ROOT.parent / "shared" / "meshes"))
SCENES = ROOT / "scenes"

# a project-local kernel cache unless the caller chose one (CI sets it too)
os.environ.setdefault("WARP_CACHE_PATH", str(ROOT / ".warp_cache"))

import warp as wp  # noqa: E402

from almsdm_warp.warp_init import init_warp  # noqa: E402

init_warp()

DEVICES = ["cpu"] + [d.alias for d in wp.get_cuda_devices()]
MESH_SUFFIXES = {".obj", ".stl", ".ply", ".off", ".vtu", ".vtk", ".msh"}


@pytest.fixture(params=DEVICES)
def device(request):
    """Each kernel test runs once on `cpu` and once on each CUDA device present."""
    return request.param


def shared_mesh_paths():
    """The organ meshes in ../shared/meshes, or [] when the folder is absent."""
    if not SHARED_MESHES.is_dir():
        return []
    return sorted(p for p in SHARED_MESHES.iterdir() if p.suffix.lower() in MESH_SUFFIXES)


def scene_mesh_paths():
    return sorted(p for p in SCENES.glob("*") if p.suffix.lower() in MESH_SUFFIXES)


def mesh_params():
    """pytest params for every project scene mesh and every shared mesh (a skip when absent)."""
    params = [pytest.param(p, id=p.name) for p in scene_mesh_paths()]
    shared = shared_mesh_paths()
    if shared:
        params += [pytest.param(p, id="shared-" + p.name) for p in shared]
    else:
        params.append(pytest.param(None, id="shared-absent", marks=pytest.mark.skip(reason=f"{SHARED_MESHES} absent")))
    return params


_loaded = {}


def load_cached(path):
    """Load a mesh once per test session (the tests do not change meshes)."""
    from almsdm_warp import load_mesh

    key = str(path)
    if key not in _loaded:
        _loaded[key] = load_mesh(path)
    return _loaded[key]


@pytest.fixture
def full_disk(tmp_path):
    """A 64 KiB tmpfs (root only; skipped elsewhere): too small for a USD stage of the stomach or a large table."""
    import subprocess

    mount = tmp_path / "full"
    mount.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)],
                                           capture_output=True).returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root)")
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=False)
