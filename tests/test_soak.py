"""A short soak (scripts/soak.py, a few seconds): press cycles and relocations in one process.
Memory stays flat, the tissue comes back to its rest shape after every cycle, and the device's
rest positions and rest lengths keep their bits. The long run (1e6 steps, 1e4 relocations)
is `python scripts/soak.py`; its results are in docs/reliability.md."""

import numpy as np
import pytest
from helpers import load_script


@pytest.fixture(scope="module")
def soak_module():
    return load_script("soak")


@pytest.mark.parametrize("integrator, steps, relocations", [("explicit", 60_000, 600), ("implicit", 6_000, 150)])
def test_short_soak(device, soak_module, integrator, steps, relocations):
    if device != "cpu" and integrator == "implicit":  # one thread per region on CUDA: ~1 ms a step
        steps, relocations = steps // 3, relocations // 3
    r = soak_module.soak(None, steps=steps, relocation_count=relocations, rings=4, integrator=integrator, device=device,
                         press_sample_every=steps // 10, relocation_sample_every=relocations // 10)
    assert r["steps"] == steps and r["relocations"] == relocations
    assert r["rest_shape_bits_unchanged"]
    # every settled cycle and the end: back at rest to a micrometre (float32 of 0.1 m is 7 nm)
    assert len(r["samples"]) >= 20
    assert r["settled_offset_max_mm"] < 1e-3 and r["final_offset_mm"] < 1e-3
    # memory: flat after the warm-up; a leak of one captured graph per relocation would be ~MB here
    assert r["press_rss_growth_MB"] < 2.0, r["samples"]
    assert r["relocation_rss_growth_MB"] < 4.0, r["samples"]
    assert r["ok"]


def test_soak_sees_what_it_should(soak_module):
    """Not vacuous: the drift measure reads a deformed tissue as deformed, and the RSS reader
    sees an allocation of 64 MB."""
    from almsdm_warp.sim.model import PROBE_DISPLACEMENT
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.scene.loader import resolve_scene_or_mesh

    scene = resolve_scene_or_mesh(None)
    mesh = scene.load_mesh()
    p = Palpation(mesh, scene.tissue, rings=2, device="cpu")
    p.touch(int(mesh.surface_vertices[0]))
    p.set_probe(PROBE_DISPLACEMENT, p.rest_position() + p.inward_normal() * 1e-3)
    p.step()
    p.step()
    assert soak_module.largest_offset(p) > 0.9e-3
    before = soak_module.rss_kb()
    block = np.ones(64 * 1024 * 1024 // 8)
    assert soak_module.rss_kb() - before > 60 * 1024
    del block
