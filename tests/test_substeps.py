"""A frame of n substeps moves the probe in n even steps (a first-order hold), as the batch's press
does: the one-palpation press and the batch agree at every n, and a frame of n substeps of dt / n
is n frames of dt / n (the press schedule counted in either)."""

import numpy as np
import pytest

from almsdm_warp.batch.batch_palpation import BatchPalpation
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.region.contact import top_vertex
from almsdm_warp.scene.loader import resolve_scene_or_mesh
from almsdm_warp.sim.model import PROBE_DISPLACEMENT, PROBE_OFF

DT = 1e-3
PRESS = dict(depth=0.008, ramp=0.02, hold=0.01, settle=0.02)


@pytest.fixture(scope="module")
def stomach():
    scene = resolve_scene_or_mesh(None)
    return scene, scene.load_mesh()


def palpation(stomach, dt, n, device="cpu", **kw):
    scene, mesh = stomach
    p = Palpation(mesh, scene.tissue, rings=4, dt=dt, device=device, substeps=n, **kw)
    p.touch(top_vertex(mesh))
    return p


def close(a, b, device):
    """The same bits on the CPU (one thread each, the same arithmetic in the same order); within
    float32 rounding on CUDA, where the batch's block and the one-palpation grid may contract
    products into fused multiply-adds differently."""
    if device == "cpu":
        np.testing.assert_array_equal(a, b)
    else:
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_a_press_in_substeps_is_the_batchs(stomach, device, n):
    """Peak (over every substep, as the batch's), hold force and recovery of Palpation.press equal
    BatchPalpation.press's at the same frame and substeps."""
    scene, mesh = stomach
    p = palpation(stomach, DT, n, device)
    one = p.press(**PRESS)
    batch = BatchPalpation(mesh, scene.tissue, rings=4, dt=DT, device=device, substeps=n, kernel="exact")
    both = batch.touch([p.vertex]).press(**PRESS)
    assert p.substeps == batch.substeps == n
    close(one.peak_force_N, both.peak_force[0], device)
    close(one.force[one.release_step - 1], both.hold_force[0], device)
    close(one.displacement[-1], both.recovery_error[0], device)


@pytest.mark.parametrize("n", [2, 3])
def test_a_press_of_n_substeps_is_a_press_at_dt_over_n(stomach, n):
    """Frame ends of dt in n substeps are every n-th frame of dt / n, bit for bit; the peak over
    the substeps is the fine press's peak over every frame (and not less than the frame ends')."""
    coarse = palpation(stomach, DT, n).press(**PRESS)
    fine = palpation(stomach, DT / n, 1).press(**PRESS)
    np.testing.assert_array_equal(coarse.force, fine.force[n - 1 :: n])
    assert coarse.peak_force_N == fine.peak_force_N == fine.force.max()
    assert coarse.peak_force_N >= coarse.force.max()
    assert coarse.recovery_error_mm == fine.recovery_error_mm


def test_a_haptic_target_is_interpolated_and_a_new_mode_starts_at_its_target(stomach):
    """step() after set_probe each frame: a frame of two substeps passes the midpoint of the last
    target and the new one, as two frames of dt / 2 given both; after the probe was off, the
    first frame holds the new target (no move from the target the last press left)."""
    coarse = palpation(stomach, DT, 2)
    fine = palpation(stomach, DT / 2, 1)
    rest, inward = coarse.rest_position(), coarse.inward_normal()
    depths = [1e-3, 3e-3, 2e-3, 2e-3, 0.5e-3]
    a = []
    for d in depths:
        coarse.set_probe(PROBE_DISPLACEMENT, rest + inward * d)
        a.append(coarse.step().copy())
    b, last = [], depths[0]  # the first frame turns the probe on: it holds its target
    for d in depths:
        for t in (0.5 * (last + d), d):
            fine.set_probe(PROBE_DISPLACEMENT, rest + inward * t)
            f = fine.step().copy()
        b.append(f)
        last = d
    np.testing.assert_array_equal(a, b)
    coarse.set_probe(PROBE_OFF)  # the probe off a frame, then on again 4 mm in
    coarse.step()
    for _ in range(2):
        fine.set_probe(PROBE_OFF)
        fine.step()
    coarse.set_probe(PROBE_DISPLACEMENT, rest + inward * 4e-3)
    held = coarse.step().copy()
    for _ in range(2):
        fine.set_probe(PROBE_DISPLACEMENT, rest + inward * 4e-3)
        f = fine.step()
    np.testing.assert_array_equal(held, f)
    np.testing.assert_array_equal(coarse.positions(), fine.positions())


def test_one_substep_reads_the_target_as_is(stomach):
    """At one step a frame the frame's move is never read: a start far off changes no bit."""
    runs = []
    for start in (None, np.full(3, 5.0)):
        p = palpation(stomach, DT, 1)
        target = p.rest_position() + p.inward_normal() * 5e-3
        forces = []
        for _ in range(10):
            p.set_probe(PROBE_DISPLACEMENT, target, start)
            forces.append(p.step().copy())
        runs.append((np.array(forces), p.positions()))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
