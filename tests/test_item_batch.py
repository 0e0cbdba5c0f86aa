"""Several items of one mesh in one batch (batch/item_batch.py): each palpation presses its own item's
model, as a batch of that model alone does, whatever the items beside it. Every device present."""

import numpy as np
import pytest

from almsdm_warp.batch.batch_palpation import BatchPalpation
from almsdm_warp.batch.item_batch import ItemBatch, StackedModel
from almsdm_warp.mesh.primitives import icosphere, tet_ball
from almsdm_warp.sim.model import Model
from almsdm_warp.tissue.lesion import Lesion
from almsdm_warp.tissue.material import Material

PRESS = dict(depth=4e-3, ramp=0.02, hold=0.01, settle=0.01)


def item_models(mesh, tissue, law=None):
    """A baseline and two lesions (a 4x one over the top, a 0.5x one on the side) of `mesh`, on the CPU."""
    lesions = [Lesion((0.0, 0.0, 0.03), 0.02, 4.0), Lesion((0.03, 0.0, 0.0), 0.02, 0.5)]
    scales = [{}] + [lesion.model_scales(mesh, tissue, law) for lesion in lesions]
    return [Model(mesh, tissue, "cpu", law=law, **s) for s in scales], scales


@pytest.mark.parametrize("case", ["springs, the paper's probe", "springs, a sphere", "neo-Hookean tets"])
def test_each_palpation_presses_its_own_items_model(device, case):
    if case == "neo-Hookean tets":
        mesh, tissue, law, radius = tet_ball(30.0, 8.0), Material(youngs_modulus=5e3, density=1000.0, rayleigh_alpha=60.0), "neo-hookean", 0.0
    else:
        mesh = icosphere(30.0, 2)
        tissue, law = Material(youngs_modulus=2e3, density=1000.0, thickness=3e-3, foundation=1e5, rayleigh_alpha=60.0), None
        radius = 8e-3 if "sphere" in case else 0.0
    models, scales = item_models(mesh, tissue, law)
    top = np.argsort(mesh.vertices[:, 2])[::-1]
    surface = np.intersect1d(top[:40], mesh.surface_vertices)
    vertices = np.array([surface[0], surface[1], surface[0], surface[2], surface[0]])
    items = np.array([1, 0, 2, 2, 0])  # interleaved, the top vertex pressed by every item
    # each kernel of the device (CUDA's fast one where the regions fit), the same for the batch of items and each model's
    batch = ItemBatch(StackedModel(models, device), rings=2, dt=1e-3, substeps=2, probe_radius=radius)
    result = batch.build(vertices, PRESS["depth"], items).plan().press(**PRESS)
    for k in range(len(models)):  # the same presses, every one on item k's model alone: those of item k agree
        alone = BatchPalpation(mesh, tissue, rings=2, dt=1e-3, device=device, substeps=2, probe_radius=radius, law=law, **scales[k])
        assert alone.touch(vertices, PRESS["depth"]).kernel == batch.kernel
        expected = alone.press(**PRESS)
        mine = items == k
        for field in ("peak_force", "hold_force", "recovery_error"):
            np.testing.assert_array_equal(getattr(result, field)[mine], getattr(expected, field)[mine], err_msg=f"{field} of item {k}")
    # the 4x lesion under the top vertex makes it stiffer there than the baseline: the items are their own models
    assert result.peak_force[0] > 1.2 * result.peak_force[4]


def test_a_stack_holds_each_items_constants_at_its_offset():
    mesh = icosphere(30.0, 1)
    tissue = Material(youngs_modulus=2e3, density=1000.0, thickness=3e-3, foundation=1e5, rayleigh_alpha=60.0)
    models, _ = item_models(mesh, tissue)
    stacked = StackedModel(models, "cpu")
    n, e = mesh.vertex_count, len(mesh.edges)
    for k, m in enumerate(models):
        for name in ("particle_mass", "anchor_ke", "anchor_kd", "spring_ke", "spring_kd", "spring_rest_length"):
            size = n if name in ("particle_mass", "anchor_ke", "anchor_kd") else e
            np.testing.assert_array_equal(getattr(stacked, name).numpy()[k * size:(k + 1) * size], getattr(m, name).numpy())
        offsets, vertex, edge = (np.asarray(a) for a in mesh.adjacency)
        rows = slice(k * len(vertex), (k + 1) * len(vertex))
        np.testing.assert_array_equal(stacked.adj_vertex.numpy()[rows], vertex + k * n)
        np.testing.assert_array_equal(stacked.adj_edge.numpy()[rows], edge + k * e)
        np.testing.assert_array_equal(stacked.adj_offsets.numpy()[k * n:(k + 1) * n + 1], offsets + k * len(vertex))
    with pytest.raises(ValueError, match="another mesh"):
        StackedModel([models[0], Model(icosphere(30.0, 2), tissue, "cpu")], "cpu")


def test_auto_substeps_are_those_of_the_stiffest_items_own_batch():
    mesh = icosphere(30.0, 2)
    tissue = Material(youngs_modulus=2e3, density=1000.0, thickness=3e-3, foundation=1e5, rayleigh_alpha=60.0)
    models, scales = item_models(mesh, tissue)
    top = np.argsort(mesh.vertices[:, 2])[::-1][:3]
    batch = ItemBatch(StackedModel(models, "cpu"), rings=2, dt=4e-3).build(np.repeat(top, 3), None, np.tile([0, 1, 2], 3)).plan()
    alone = [BatchPalpation(mesh, tissue, rings=2, dt=4e-3, device="cpu", **s).touch(top).substeps for s in scales]
    assert batch.substeps == max(alone) and max(alone) > min(alone)  # the 4x lesion's item needs more


def _nh_ball_items(device):
    mesh = tet_ball(30.0, 8.0)
    tissue = Material(youngs_modulus=5e3, density=1000.0, rayleigh_alpha=60.0)
    models, scales = item_models(mesh, tissue, "neo-hookean")
    top = np.intersect1d(np.argsort(mesh.vertices[:, 2])[::-1][:40], mesh.surface_vertices)[:2]
    return mesh, tissue, models, scales, top


def test_a_press_that_diverged_is_pressed_again_at_twice_the_substeps(device):
    """A plan too bold for the 4x lesion's item (its step planned from the baseline's critical step) diverges
    there and holds at twice the substeps: those rows are the lesion's own batch at twice the substeps, bit
    for bit, and the baseline's rows its own batch at the plan's."""
    from almsdm_warp.solvers.stepper import SimulationDiverged

    mesh, tissue, models, scales, top = _nh_ball_items(device)
    base = BatchPalpation(mesh, tissue, rings=2, dt=1e-3, device=device, law="neo-hookean").touch(top)
    dt = 1.5 * base.critical_dt  # the baseline: 2 substeps (0.75 of its step); the 4x lesion's step is about half
    vertices, items = np.repeat(top, 2), np.tile([0, 1], len(top))
    batch = ItemBatch(StackedModel(models, device), rings=2, dt=dt)
    batch.known_critical_dt = base.critical_dt
    result = batch.build(vertices, None, items).plan().press(**PRESS)
    assert batch.substeps == 2 and result.substeps.tolist() == [2, 4] * len(top)
    for k, n in ((0, 2), (1, 4)):
        alone = BatchPalpation(mesh, tissue, rings=2, dt=dt, device=device, substeps=n, law="neo-hookean", **scales[k]).touch(top)
        expected = alone.press(**PRESS)
        for field in ("peak_force", "hold_force", "recovery_error"):
            np.testing.assert_array_equal(getattr(result, field)[items == k], getattr(expected, field), err_msg=f"{field} of item {k}")
    with pytest.raises(SimulationDiverged, match="at 2 of 2 contacts"):  # the lesion alone at the plan's substeps diverges
        BatchPalpation(mesh, tissue, rings=2, dt=dt, device=device, substeps=2, law="neo-hookean", **scales[1]).touch(top).press(**PRESS)
    # fixed substeps are the caller's: never pressed again; nor past REPRESSES doublings
    bold = ItemBatch(StackedModel(models, device), rings=2, dt=16 * dt)
    bold.known_critical_dt = 16 * base.critical_dt
    with pytest.raises(SimulationDiverged, match="in 8 substep"):
        bold.build(vertices, None, items).plan().press(**PRESS)


def test_regions_from_a_table_give_each_item_the_tets_of_a_build(device):
    """A batch of tet items whose regions are gathered from a RegionTable (as a dataset's are) and offset to
    each palpation's item builds the local tets and presses of the same batch built on its own, bit for
    bit: each item's parameters at its offset (element_shift), its corners outside the region its own."""
    mesh, tissue, models, _, top = _nh_ball_items(device)
    stacked = StackedModel(models, device)
    vertices, items = np.array([top[0], top[1], top[0], top[1], top[0]]), np.array([2, 0, 1, 1, 0])
    built = ItemBatch(stacked, rings=2, dt=1e-3, substeps=2).build(vertices, None, items).plan()
    gathered = ItemBatch(stacked, rings=2, dt=1e-3, substeps=2)
    gathered.cache_regions(top)
    gathered.build(vertices, None, items).plan()
    count = built.region_vertex_counts
    np.testing.assert_array_equal(gathered.region_vertex_counts, count)
    eo, go = built.element_offsets.numpy(), gathered.element_offsets.numpy()
    for b, n in enumerate(count):
        np.testing.assert_array_equal(go[b, :n + 1], eo[b, :n + 1])
        np.testing.assert_array_equal(gathered.element_shift.numpy()[b, :n], built.element_shift.numpy()[b, :n])
        np.testing.assert_array_equal(gathered.element_topology.numpy()[b, :go[b, n]], built.element_topology.numpy()[b, :eo[b, n]])
    shift = built.element_shift.numpy()
    assert not np.array_equal(shift[0], shift[2]) and not np.array_equal(shift[2], shift[4])  # one vertex, three items' parameters
    a, b = built.press(**PRESS), gathered.press(**PRESS)
    for field in ("peak_force", "hold_force", "recovery_error"):
        np.testing.assert_array_equal(getattr(b, field), getattr(a, field), err_msg=field)
