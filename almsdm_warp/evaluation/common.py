"""What every experiment of `almsdm evaluate` shares: the settings of a run, the paper's numbers,
the press protocol pieces and the timing of a step.

The experiments (evaluate_paper, evaluate_accuracy, evaluate_stability, evaluate_anatomy) return
plain dicts of numbers (SI inside, unit-suffixed keys where they leave); evaluate_report turns them
into docs/results.md, evaluate_plots into PNG figures.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..protocol.schedule import PressSchedule
from ..region.contact import top_vertex

DT = 1e-3
"""The haptic step [s] of every experiment but the stability map."""
DEPTH = 10e-3
"""Press depth [m] (the paper's Table 1: 10 mm)."""
RAMP, HOLD = 0.1, 0.2
"""Ramp and hold [s] of the evaluation press (the scenes' protocol)."""

PAPER = {
    "regions": {1: (7, 12), 2: (20, 45), 3: (41, 98), 4: (70, 187)},
    "recovery_mm": {1: "< 0.11", 2: "< 0.11", 3: "~0.48", 4: "~1.15", "global-free": "never recovers"},
    # Table 1 at 10 mm: (recovery error mm, recovery time s, feedback force N)
    "table1": {
        "local surface": (0.455, 0.982, 2.402),
        "global surface": (15.224, ">5.122", 2.514),
        "local volume": (0.081, 0.556, 2.312),
        "global volume": (0.022, 0.252, 2.578),
    },
    # Table 2, frames per second: (global normals, local normals, precomputed local normals)
    "table2_fps": {
        1: ("~38", "84-93", ">=120"),
        2: ("~38", "84-93", ">=120"),
        3: ("~38", "84-93", ">=120"),
        4: ("~38", "84-93", ">=120"),
        "global surface": ("34.5", "73.1", "115.3"),
        "4-ring volume": ("37.1", "84.1", ">=120"),
    },
    "fps_4_rings": 120.0,
    "fps_global_surface": 34.5,
}


@dataclass(frozen=True)
class ContinuumSettings:
    """How much of the spring model against continuum mechanics a run does (evaluation/continuum)."""

    subdivisions: tuple = (4, 5, 6)
    """Icosphere subdivisions of the mesh-convergence section."""
    edges_mm: tuple = (8.0, 6.5, 5.5)
    """Tet ball edge lengths [mm] of the mesh-convergence section."""
    fem_edge_mm: float = 8.0
    """Edge [mm] of the tet ball pressed against the P2 reference (P2 costs seconds at 8 mm)."""
    fem_rings: tuple = (2, 4, 6, 8)
    """Ring counts of the local model pressed against the P2 reference (and the global model)."""
    hertz_block: bool = True
    """Solve P2 on a large block against Hertz's half-space (about 15 s on 2 cores)."""


@dataclass(frozen=True)
class DepthSettings:
    """How much of the "depth, layers and lesions" section a run does (evaluation/depth_layers)."""

    slab_edges_mm: tuple = (2.0, 1.4, 1.0)
    """Edges [mm] under the probe of the slab on a rigid base, one row each (1014, 2312, 3971 vertices)."""
    ball_edge_mm: float = 4.0
    """Edge [mm] of the tet ball of the deep press and the lesion (1435 vertices)."""
    rings: tuple = (2, 4, 6)
    """Ring counts of each law's local region on the deep press, beside its global model."""
    fem_steps_per_mm: float = 2.0
    """The reference's load steps a millimetre of depth (at least 4)."""
    fem_rtol: float = 1e-6
    """The reference's Newton tolerance, relative to the largest internal force (fem_nonlinear's 1e-9 stalls
    on some meshes: the contact's kinks hold Newton's steps at ~1e-4 of the force)."""
    fem_gap_rtol: float = 1e-4
    """The reference's contact tolerance: the largest penetration left, relative to the depth."""


@dataclass(frozen=True)
class Settings:
    """How much of each experiment a run does: "full" (docs/results.md), "quick" (< 2 min on 2
    CPU cores) or "tiny" (the test's: every part, the least work that still shows each effect)."""

    name: str
    presses: int
    """Presses at one spot for the recovery figure (the paper: 5-6)."""
    settle_s: float
    """Settle window after each press [s]."""
    accuracy_rings: tuple
    """Fixed ring counts, "global", and "auto:T" (the adaptive region at tolerance T mm)."""
    accuracy_contacts: int
    """Contact vertices (spread over the surface) the speed-accuracy errors are taken over."""
    timing_budget_s: float
    """Wall time spent timing one configuration's step [s] (median of blocks)."""
    stability_dt_ms: tuple
    stability_scales: tuple
    stability_free_dt_ms: tuple
    anatomy: tuple
    """(file name in the shared meshes, millimetres per file unit) of the real meshes to run."""
    anatomy_free_max_vertices: int = 2500
    """The unanchored global model is run on real meshes up to this many vertices."""
    continuum: ContinuumSettings = ContinuumSettings()
    """The mesh-convergence and against-FEM sections."""
    depth: DepthSettings = DepthSettings()
    """The depth, layers and lesions section."""


_ANATOMY_FULL = (
    ("gca_stomach_1002v.obj", 1.0),
    ("gca_stomach_5587v.obj", 1.0),
    ("liver-smooth.obj", 30.0),
    ("sofa_liver_tets.vtu", 30.0),
    ("sofa_liver2_tets.vtu", 100.0),
    ("mor_liverTinyMesh.vtu", 30.0),
    ("mor_liverVeryCOARSE.vtu", 30.0),
    ("mor_liverCoarse.vtu", 30.0),
    ("mor_liverSemiFine.vtu", 30.0),
    ("mor_liverFine.vtu", 30.0),
)

SETTINGS = {
    "full": Settings(
        name="full",
        presses=6,
        settle_s=1.0,
        accuracy_rings=(1, 2, 3, 4, 5, 6, 7, 8, 9, 10, "auto:0.5", "auto:0.1", "auto:0.02", "global"),
        accuracy_contacts=16,
        timing_budget_s=1.0,
        stability_dt_ms=(0.1, 0.2, 0.5, 1.0, 1.5, 2.0, 5.0, 10.0, 20.0),
        stability_scales=(0.25, 0.5, 1.0, 2.0, 4.0, 8.0),
        stability_free_dt_ms=(0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0),
        anatomy=_ANATOMY_FULL,
    ),
    "quick": Settings(
        name="quick",
        presses=3,
        settle_s=0.5,
        accuracy_rings=(1, 2, 3, 4, 6, 8, "auto:0.5", "auto:0.05", "global"),
        accuracy_contacts=2,
        timing_budget_s=0.1,
        stability_dt_ms=(0.5, 1.0, 2.0, 5.0, 20.0),
        stability_scales=(0.5, 1.0, 4.0),
        stability_free_dt_ms=(1.0, 20.0),
        anatomy=(
            ("gca_stomach_1002v.obj", 1.0),
            ("mor_liverTinyMesh.vtu", 30.0),
            ("mor_liverVeryCOARSE.vtu", 30.0),
            ("mor_liverCoarse.vtu", 30.0),
        ),
        anatomy_free_max_vertices=1100,
        continuum=ContinuumSettings((4, 5), (10.0, 8.0), fem_edge_mm=12.0, fem_rings=(2, 4), hertz_block=False),
        depth=DepthSettings((3.0,), 8.0, (2, 4), fem_steps_per_mm=1.0, fem_rtol=1e-6, fem_gap_rtol=1e-3),
    ),
    "tiny": Settings(
        name="tiny",
        presses=2,
        settle_s=0.3,
        accuracy_rings=(1, 3, "auto:0.1", "global"),
        accuracy_contacts=1,
        timing_budget_s=0.03,
        stability_dt_ms=(1.0, 20.0),
        stability_scales=(1.0,),
        stability_free_dt_ms=(1.0,),
        anatomy=(("mor_liverTinyMesh.vtu", 30.0), ("mor_liverVeryCOARSE.vtu", 30.0)),
        anatomy_free_max_vertices=100,
        continuum=ContinuumSettings((3, 4), (16.0, 12.0), fem_edge_mm=16.0, fem_rings=(1, 2), hertz_block=False),
        depth=DepthSettings((4.0,), 8.0, (2,), fem_steps_per_mm=1.0, fem_rtol=1e-6, fem_gap_rtol=1e-3),
    ),
}


@functools.lru_cache(maxsize=None)
def shipped_scene(name):
    """(Scene, its mesh) of a shipped scene, loaded once per process (nothing changes a mesh)."""
    from ..scene.loader import resolve_scene_or_mesh

    scene = resolve_scene_or_mesh(name)
    return scene, scene.load_mesh()


def press_curve(result):
    """(displacement [mm], force [N]) over the ramp and hold of a PressResult, every 5th step."""
    n = result.release_step
    ramp_n = PressSchedule.from_times(result.dt, RAMP, 0.0).ramp_n
    depth = result.depth * np.minimum(np.arange(1, n + 1) / ramp_n, 1.0)
    return (depth[::5] * 1e3).round(4).tolist(), result.force[:n:5].round(5).tolist()


def spread_vertices(mesh, count: int) -> list[int]:
    """`count` contact vertices: the top one first, then surface vertices spread by id."""
    sv = mesh.surface_vertices
    out = [top_vertex(mesh)]
    for v in sv[np.linspace(0, len(sv) - 1, count + 1).astype(int)[1:]]:
        if len(out) >= count:
            break
        if int(v) not in out:
            out.append(int(v))
    return out[:count]


def scaled_tissue(tissue, scale: float):
    """The tissue with every stiffness multiplied by `scale` (masses and dampers unchanged)."""
    from dataclasses import replace

    return replace(tissue, edge_stiffness=tissue.edge_stiffness * scale, anchor_stiffness=tissue.anchor_stiffness * scale)


def reset_to_rest(pal) -> None:
    """Put every vertex of both of the palpation's states back at rest, in place (captured graphs
    keep their arrays): each contact of a sweep then starts from the undeformed organ. Touching a
    new vertex alone resets only the vertices the old region leaves behind (and, for the global
    models, none)."""
    import warp as wp

    for state in pal.states:
        wp.copy(state.particle_q, pal.model.particle_q_rest)
        state.particle_qd.zero_()


def hold_press(pal, depth=DEPTH, ramp=RAMP, hold=HOLD):
    """Ramp the touched vertex to `depth` [m] along the inward normal and hold it (no release).

    Returns (force at the end of the hold [N], peak force [N], positions at the end of the hold [m],
    per-step |force| [N], per-step commanded depth [m]). Raises SimulationDiverged."""
    from ..sim.model import PROBE_DISPLACEMENT

    rest, direction = pal.rest_position(), pal.inward_normal()
    schedule = PressSchedule.from_times(pal.dt, ramp, hold)
    total = schedule.release_step
    force = np.zeros(total)
    target = np.zeros(total)
    for s in range(total):
        target[s] = depth * schedule.fraction(s)
        pal.set_probe(PROBE_DISPLACEMENT, rest + direction * target[s])
        f = pal.step()
        force[s] = math.sqrt(float(f[0]) ** 2 + float(f[1]) ** 2 + float(f[2]) ** 2)
        if not math.isfinite(force[s]) or (s % 50 == 0 and s):
            pal.check_finite(s + 1)
    pal.check_finite(total)
    return force[-1], float(force.max()), pal.positions(), force, target


def time_per_step(pal, budget_s: float, blocks: int = 9, depth=0.5 * DEPTH) -> float:
    """Median wall time of one `Palpation.step()` [s], the probe held `depth` in (the force read
    every step, as a haptic loop does), over `blocks` blocks that together take about `budget_s`
    (the warm-up, 10 steps, sizes them)."""
    from ..protocol.timing import time_palpation
    from ..sim.model import PROBE_DISPLACEMENT

    pal.set_probe(PROBE_DISPLACEMENT, pal.rest_position() + pal.inward_normal() * depth)
    return time_palpation(pal, blocks, read_force=True, warmup=10, budget_s=budget_s, max_steps=5000).median


def finite_or_none(x):
    """A float for JSON, None where it is not finite."""
    x = float(x)
    return x if math.isfinite(x) else None


def fmt(x, digits=3, none="-"):
    """A number for a Markdown table: fixed digits, "inf" / "-" where not finite or missing."""
    if x is None:
        return none
    if isinstance(x, str):
        return x
    if math.isinf(x):
        return "inf"
    if math.isnan(x):
        return none
    return f"{x:.{digits}f}"


class Tasks:
    """The progress of an evaluation, in units of work (about 0.3 s each alone on one CPU core: a
    configuration run, a real mesh counts more): a thin counter over progress.Progress."""

    def __init__(self, bar):
        self.bar = bar

    def step(self, label: str, weight: int = 1) -> None:
        self.bar.label = label
        self.bar.advance(weight)
