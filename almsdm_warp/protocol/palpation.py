"""One palpation: a probe pressing an organ, simulated on its local region (or the whole mesh).

The step is captured once in a Warp graph (CPU and CUDA) and replayed; the probe's target goes
in and the feedback force comes out through host views kept across steps, so the hot loop has
no allocation and no extra copy on the CPU (on CUDA, pinned buffers copied inside the graph).
"""

from __future__ import annotations

import functools
import math
import numbers
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..kernels.probes.press import hold_probe
from ..kernels.region.state import reset_vertices_left_behind
from ..mesh.topology import inverted_tets
from ..mesh.validate import MAX_COORDINATE_M
from ..sim.model import PROBE_DISPLACEMENT, PROBE_FORCE, PROBE_OFF, PROBE_SPHERE, Model
from ..region.patch import sphere_patches
from ..region.region import Region
from ..solvers import make_solver
from ..solvers.stepper import (REPRESSES, SimulationDiverged, capture_step_pair, diverged, force_bound, may_press_again, plan_substeps,
                               remedies, restore_states, snapshot_states)
from ..checks import check_value, fixed_substeps
from ..errors import InputError
from .schedule import PressSchedule, check_press

GLOBAL_MODELS = ("global", "global-free")

PATCH_DEPTH = 0.01
"""Depth [m] a spherical probe's contact patch is sized for when touch() is given none (a press
then resizes it to its own depth)."""


PROBE_RADIUS_FACTOR = 100.0
"""A sphere more than this many times the mesh's extent is a plane to the organ, and its centre so far
off that its float32 position loses the press (a radius of 1e9 m read 0 N): refused."""
PROBE_MODES = {PROBE_OFF: "PROBE_OFF", PROBE_DISPLACEMENT: "PROBE_DISPLACEMENT", PROBE_FORCE: "PROBE_FORCE",
               PROBE_SPHERE: "PROBE_SPHERE"}
"""The probe's modes (sim.model), by value: set_probe takes these and no other."""


NEAR_RING = 0.5
"""A press whose sphere comes within this many of its radii of the region's fixed ring (PressResult.ring_gap)
on a tet mesh is warned of: the ring holds still tissue the press moves (a 10 mm sphere pressed
10 mm into a 25 mm ball on a support collapsed to 0.23-0.39 of the global model's force with the ring
1.2-1.4 mm from it, and held, 13-17% high, at 8.8 mm: docs/calibration.md)."""


def runaway(q: np.ndarray, qd: np.ndarray, rest: np.ndarray, size: float) -> bool:
    """Whether a state (positions q [m], velocities qd [m/s], rest positions, host arrays [n, 3]) ran away:
    a value not finite, or a vertex more than twice the mesh's size `size` [m] from rest."""
    if not len(q):
        return False
    return not (float(np.abs(q - rest).max()) < 2.0 * size and float(np.abs(qd).max()) < math.inf)


def check_probe_radius(radius, mesh=None) -> float:
    """The probe's radius [m]: a number >= 0 (0: the paper's probe, one driven vertex) of the magnitude every
    parameter is held to (checks.check_value) and, with `mesh`, at most PROBE_RADIUS_FACTOR x its extent.
    TypeError for a non-number, ValueError (an InputError) naming probe_radius and the value otherwise."""
    if isinstance(radius, (bool, np.bool_)) or not isinstance(radius, numbers.Real):
        raise TypeError(f"probe_radius must be a number [m], got {type(radius).__name__}")
    value = check_value(radius, float, ">= 0", "probe_radius [m]")
    if mesh is not None:
        extent = float(np.ptp(mesh.vertices, axis=0).max())
        if value > PROBE_RADIUS_FACTOR * extent:
            raise InputError(f"probe_radius {value:g} m is more than {PROBE_RADIUS_FACTOR:g} x the mesh's extent "
                             f"({extent:.4g} m): a sphere that large is a plane to the organ, beyond what float32 positions resolve")
    return value


def check_point(value, name: str):
    """`value` where it is 3 finite numbers within the +-1 km meshes are held to (a position [m], a force
    [N]), else ValueError naming `name` and the value (cheap: set_probe calls it every step)."""
    m = MAX_COORDINATE_M
    try:
        x, y, z = value
        ok = -m <= x <= m and -m <= y <= m and -m <= z <= m  # NaN compares False
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"{name} must be 3 finite numbers within {m:g}, got {value!r}")
    return value


@dataclass
class PressResult:
    """One press: ramp to depth along the inward normal, hold, release, settle (SI inside)."""

    vertex: int
    depth: float
    dt: float
    release_step: int
    force: np.ndarray = field(repr=False)
    """|feedback force| [N] per step (0 after release), shape [steps]."""
    displacement: np.ndarray = field(repr=False)
    """Distance of the contact vertex from its rest position [m] per step, shape [steps]."""
    step_peak: float | None = None
    """Largest |feedback force| [N] over every integrator step while pressed (a frame's substeps
    included); None: the largest of `force`."""
    inverted_tets: int | None = None
    """Tets inverted (det F <= 0) at the end of the hold, the deepest frame (mesh.topology.inverted_tets);
    None on a surface mesh or where nothing was counted."""
    substeps: int | None = None
    """The integrator's steps a frame at the press's end: the plan's (an adaptive region that grew during
    the press planned again for it), or more where the press diverged at the plan and was pressed again
    (REPRESSES); None where not counted."""
    diverged_at: tuple = ()
    """The substeps a frame of each attempt that diverged and was pressed again (REPRESSES), in order;
    () where the press held as it began."""
    ring_gap: float | None = None
    """The sphere's least distance [m] at full depth from a vertex of the region's fixed outer ring
    (negative: it reaches into the ring, which it cannot move); None for the paper's probe or the global model."""

    @property
    def peak_force_N(self) -> float:
        """The peak force [N]: over every integrator step, as the batch's (BatchResult.peak_force)."""
        if self.step_peak is not None:
            return float(self.step_peak)
        return float(self.force.max(initial=0.0))

    @property
    def hold_force_N(self) -> float:
        """The force at the end of the hold [N]: the last pressed frame's (force[release_step - 1]),
        as the batch's (BatchResult.hold_force); 0 for a press with no pressed frame."""
        return float(self.force[self.release_step - 1]) if self.release_step > 0 else 0.0

    @property
    def stiffness_N_per_mm(self) -> float:
        """Hold force over depth [N/mm], as BatchResult.stiffness_N_per_mm."""
        return self.hold_force_N / (self.depth * 1e3)

    @property
    def recovery_error_mm(self) -> float:
        """Residual displacement of the contact vertex at the end of the settle window [mm]."""
        return float(self.displacement[-1] * 1e3)

    @property
    def recovery_time_s(self) -> float:
        """Time from release until the displacement stays under 1% of the depth [s]; inf if never."""
        after = self.displacement[self.release_step :]
        above = np.flatnonzero(after >= 0.01 * self.depth)
        if len(above) == 0:
            return 0.0
        if above[-1] == len(after) - 1:
            return math.inf
        return float((above[-1] + 1) * self.dt)

    def summary(self) -> dict:
        return {
            "vertex": self.vertex,
            "peak_force_N": self.peak_force_N,
            "recovery_error_mm": self.recovery_error_mm,
            "recovery_time_s": self.recovery_time_s,
        }


class Palpation:
    """A probe on an organ: Model, two States, a Control, a solver and the region it steps.

    rings: an int (the local model: the rings around the contact vertex, the outer one fixed),
    "global" (every vertex free, anchored: the accuracy reference) or "global-free" (every vertex
    free, no anchors: the paper's global surface model). dt [s]. edge_scale [edge_count] and
    anchor_scale [vertex_count]: per-spring and per-anchor multipliers of stiffness and damping
    (a scene's lesion, `Lesion.scales`), fixed for the model's life; element_scale [tet_count] a
    volumetric law's per-tet multiplier of its moduli (`Lesion.model_scales` gives either).

    dt is the frame: step() advances the model by dt and reports the force at its end. The explicit
    integrator takes `substeps` steps of dt / substeps in each frame, as many as keep each under 0.9 x
    the critical step of the region's free vertices (re-checked whenever the region changes); past
    LIMITS["substeps"] the palpation switches to the implicit integrator and says so in `notes`.
    substeps: "auto" (that) or an int >= 1, fixed whatever the critical step (the paper's scheme
    at 1: a step past the critical one then diverges and raises).
    step() raises SimulationDiverged when the force it reads is not finite or beyond force_bound.
    fixed_below [m]: vertices with z below it are supported (fixed), as Model's. probe_radius [m]: 0, the
    paper's probe (the contact vertex is driven); > 0, a rigid sphere in frictionless one-sided
    contact with every free surface vertex it would contain, its region grown from the patch it
    covers at full depth. law: the tissue law (almsdm_warp.tissue.laws.LAWS: "springs", the paper's;
    "neo-hookean", stable neo-Hookean tets of a material on a tet mesh).
    """

    protocol = "palpation"
    """What this class is, as a tissue law's `paths` name it (a law without kernels for it is refused)."""

    def __init__(self, mesh, tissue=None, *, rings=4, integrator="explicit", dt=1e-3, device=None, capture=True,
                 edge_scale=None, anchor_scale=None, fixed_below=None, substeps="auto", probe_radius=0.0, law=None,
                 element_scale=None, **solver_kw):
        if not (isinstance(rings, (int, np.integer)) and not isinstance(rings, bool)) and rings not in GLOBAL_MODELS:
            raise ValueError(f"rings must be an int >= 1 or one of {GLOBAL_MODELS}, got {rings!r}")
        if isinstance(rings, (int, np.integer)) and rings < 1:
            raise ValueError(f"rings must be >= 1 (ring 0 is the contact vertex alone), got {rings}")
        check_value(dt, float, "> 0", "dt [s]")
        self.probe_radius = check_probe_radius(probe_radius, mesh)
        self.model = Model(mesh, tissue, device, edge_scale=edge_scale, anchor_scale=anchor_scale, fixed_below=fixed_below, law=law,
                           element_scale=element_scale)
        self.model.law_entry.require(path=self.protocol)
        self.device = self.model.device
        self.mesh = self.model.mesh
        self.rings = rings
        self.dt = float(dt)
        self.solver = make_solver(self.model, integrator, **solver_kw)
        self._solver_kw = solver_kw
        self._fixed_substeps = fixed_substeps(substeps)
        self.substeps = 1
        """Explicit steps in each frame of dt (1 for the implicit integrator)."""
        self.critical_dt = math.inf
        """Critical step [s] of the explicit integrator over the region's free vertices (inf: not asked)."""
        self.notes = []
        """What the palpation changed on its own (a fall-back to the implicit integrator), one line each."""
        self._parity = 1  # substeps % 2: whether a frame ends in the other state
        self._substeps_floor = 1  # the fewest substeps a plan takes at this contact (raised by a press pressed again)
        self._critical_cache = {}
        self._bound = force_bound(self.model)
        self.states = [self.model.state(), self.model.state()]
        self._cur = 0  # states[_cur] is the current state
        self.control = self.model.control()
        if self.probe_radius > 0:
            self.control.set_sphere(self.probe_radius)
        self.patch_depth = None
        """Depth [m] the sphere's contact patch (the region's ring 0) was sized for; None: no patch."""
        self.region = Region(self.model.dmesh) if rings not in GLOBAL_MODELS else None
        self.capture = bool(capture)
        self.vertex = -1
        self._graphs = None
        self._cpu = self.device.is_cpu
        if self._cpu:
            self._target = self.control.probe_target.numpy()
            self._force = self.control.probe_force.numpy()
            self._mode = self.control.probe_mode.numpy()
            self._reaction = self.control.probe_reaction.numpy()
            self._move = self.control.probe_move.numpy()
            self._peak = self.control.probe_reaction_peak.numpy()
        else:
            # pinned host buffers, copied inside the captured graph; numpy views of them for Python
            self._pinned = {
                name: wp.zeros(1, dtype=dtype, device="cpu", pinned=True)
                for name, dtype in (("target", wp.vec3), ("force", wp.vec3), ("mode", wp.int32), ("reaction", wp.vec3),
                                    ("peak", wp.vec3))
            }
            self._pinned["move"] = wp.zeros(2, dtype=wp.vec3d, device="cpu", pinned=True)
            self._target = self._pinned["target"].numpy()
            self._force = self._pinned["force"].numpy()
            self._mode = self._pinned["mode"].numpy()
            self._reaction = self._pinned["reaction"].numpy()
            self._move = self._pinned["move"].numpy()
            self._peak = self._pinned["peak"].numpy()
        self._force_view = self._reaction[0]  # a view of the reaction buffer: no copy per step
        self._force_words = memoryview(self._reaction).cast("B").cast("f")  # the reaction as Python floats
        if self.region is None:
            self.solver.set_global(anchors=(rings == "global"))
            self.plan_substeps()

    # -- the region ----------------------------------------------------------------------------
    @property
    def state(self):
        """The current State (the one the last step wrote)."""
        return self.states[self._cur]

    @property
    def region_vertices(self) -> int:
        return self.region.vertex_count if self.region is not None else self.model.particle_count

    @property
    def region_springs(self) -> int:
        """The region's springs: the springs law's, or for a tet law the edges among its vertices (its topology)."""
        return self.region.spring_count if self.region is not None else self.model.spring_count

    @property
    def region_tets(self) -> int | None:
        """The tets the region integrates (those with a free vertex): a volumetric law's elements; None for springs."""
        if not self.model.law_entry.volumetric:
            return None
        free = np.zeros(self.model.particle_count, dtype=bool)
        free[self.solver.free_vertex.numpy()[: self.solver.free_count]] = True
        return int(np.count_nonzero(free[self.mesh.tetrahedra].any(axis=1)))

    def touch(self, vertex: int, depth: float | None = None) -> None:
        """Put the probe on `vertex`; the local model builds its region there (relocating it). With a
        sphere, ring 0 is the patch it covers pressed `depth` [m] deep (default PATCH_DEPTH)."""
        from ..mesh.device_mesh import check_vertex

        check_vertex(self.mesh, vertex, "contact vertex")
        if depth is not None:
            check_value(depth, float, "> 0", "depth [m]")
        if self.model.support_count and 0 <= vertex < self.model.particle_count and self.model.support_mask[vertex]:
            raise ValueError(f"vertex {vertex} is held by the support (below the fixed plane): the probe cannot move it")
        self._substeps_floor = 1
        if self.region is not None:
            old = self.region
            old_count = old.vertex_count
            if old_count:
                old_vertex = wp.clone(old.region_vertex[:old_count])
            if self.probe_radius > 0:
                self.patch_depth = PATCH_DEPTH if depth is None else float(depth)
                old.build_seeds(self.sphere_patch(vertex, self.patch_depth), self.rings, contact=vertex)
            else:
                old.build(vertex, self.rings)
            if old_count:
                reset_vertices_left_behind(self.model, old_vertex, old_count, old, self.states)
            self.solver.set_region(old)
            self.plan_substeps()
        self.vertex = int(vertex)
        self.control.set(vertex=self.vertex, mode=PROBE_OFF)
        self._mode[0] = PROBE_OFF
        self._graphs = None

    def sphere_patch(self, vertex: int, depth: float) -> np.ndarray:
        """Surface vertices the sphere may touch pressed `depth` [m] at `vertex` (region.patch.sphere_patches);
        `vertex` among them."""
        from ..mesh.device_mesh import check_vertex

        vertex = check_vertex(self.mesh, vertex, "contact vertex")
        offsets, ids = sphere_patches(self.model, np.array([vertex]), self.probe_radius, depth)
        return ids[offsets[0] : offsets[1]]

    def expand(self, rings: int = 1) -> None:
        """Grow the local region by `rings` rings in place (during a press, too)."""
        if self.region is None:
            raise RuntimeError("the global models have no region to expand")
        self.region.expand(rings)
        self.rings = self.region.rings
        self.solver.set_region(self.region)
        self.plan_substeps()
        self._graphs = None

    @property
    def step_dt(self) -> float:
        """The integrator's step [s]: the frame dt over its substeps."""
        return self.dt / self.substeps

    def region_critical_dt(self) -> float:
        """The explicit integrator's critical step [s] over the free vertices (Model.critical_dt), cached by region."""
        # the solver's free set: the region's (or every vertex) less the supported ones
        free = self.solver.free_vertex.numpy()[: self.solver.free_count]
        anchors = self.rings != "global-free"
        key = (np.sort(free).tobytes(), anchors)
        if key not in self._critical_cache:
            self._critical_cache[key] = self.model.critical_dt(free, anchors=anchors)
        return self._critical_cache[key]

    def plan_substeps(self) -> None:
        """Substeps of the explicit integrator for the current region, or the implicit fall-back
        (solvers.stepper.plan_substeps)."""
        self._graphs = None
        plan = plan_substeps(self.solver.integrator, self.dt, self.region_critical_dt, self._fixed_substeps, "the palpation")
        if plan.integrator != self.solver.integrator:
            self.notes.append(plan.note)
            self.solver = make_solver(self.model, plan.integrator, **self._solver_kw)
            if self.region is not None:
                self.solver.set_region(self.region)
            else:
                self.solver.set_global(anchors=(self.rings == "global"))
        if math.isfinite(plan.critical_dt):
            self.critical_dt = plan.critical_dt
        n = max(plan.substeps, self._substeps_floor) if self.solver.conditionally_stable else plan.substeps
        self.substeps, self._parity = n, n & 1

    # -- stepping ------------------------------------------------------------------------------
    def _launch_step(self, a, b):
        n, control = self.substeps, self.control
        if not self._cpu:
            wp.copy(control.probe_target, self._pinned["target"])
            wp.copy(control.probe_force, self._pinned["force"])
            wp.copy(control.probe_mode, self._pinned["mode"])
            if n > 1:
                wp.copy(control.probe_move, self._pinned["move"])
        h = self.dt / n
        for s in range(n):  # a -> b, b -> a, ...: the frame ends in b for an odd count
            if n > 1:  # a first-order hold: substep s drives the probe (s + 1) / n of the way through the frame's move
                hold_probe(control, s, n)
            self.solver.step(a, b, control, h)
            a, b = b, a
        if n > 1:  # the last substep's reaction into the frame's peak
            hold_probe(control, n, n)
        if not self._cpu:
            wp.copy(self._pinned["reaction"], control.probe_reaction)
            if n > 1:
                wp.copy(self._pinned["peak"], control.probe_reaction_peak)

    def _capture(self):
        replays = capture_step_pair(self._launch_step, self.states, self.device)
        if self.substeps > 1:  # the next frame starts where this one's target left the probe
            replays = [self._holding(replay) for replay in replays]
        self._graphs = replays

    def _holding(self, replay):
        move = self._move

        def frame():
            replay()
            move[0] = move[1]

        return frame

    def step(self) -> np.ndarray:
        """One frame of dt; returns the feedback force [N]: a view that every step updates in place.

        Raises SimulationDiverged when that force is not finite or beyond force_bound."""
        replays = self._graphs
        if replays is not None:
            replay = replays[self._cur]
            self._cur ^= self._parity
            replay()
            w = self._force_words  # a sum of the components: inf or nan once any one runs away
            if not -self._bound < w[0] + w[1] + w[2] < self._bound:
                self.diverged()
            return self._force_view
        return self._step_setup()

    def diverged(self, step_index=None) -> None:
        """Raise SimulationDiverged for a feedback force that is not finite or beyond force_bound."""
        f = np.asarray(self._force_view, dtype=np.float64)
        at = "" if step_index is None else f" at step {step_index}"
        raise diverged(self.solver.integrator, f"{at}: the feedback force {f.tolist()} N is not finite or more than "
                                              f"{self._bound:.3g} N", self.dt, self.substeps, self.critical_dt)

    def _step_setup(self) -> np.ndarray:
        if self.vertex < 0:
            raise RuntimeError("touch(vertex) first: the probe is on no vertex")
        # the first step runs uncaptured: it compiles and loads the kernels outside any capture
        self._launch_step(self.states[self._cur], self.states[1 - self._cur])
        self._cur ^= self._parity
        if self.capture:
            self._capture()
        if not self._cpu:
            wp.synchronize_device(self.device)
        self._move[0] = self._move[1]
        w = self._force_words
        if not -self._bound < w[0] + w[1] + w[2] < self._bound:
            self.diverged()
        return self._force_view

    def set_probe(self, mode: int, target=None, start=None) -> None:
        """Probe mode (PROBE_OFF / PROBE_DISPLACEMENT / PROBE_FORCE / PROBE_SPHERE) and target [m] (the
        sphere's centre in sphere mode), through host views.

        With substeps, the next frame moves the probe from its start to `target` in even steps (a
        first-order hold). start [m]: that start; default the last frame's target, or where the mode
        changes, `target` itself (no move from a stale target)."""
        if isinstance(mode, (bool, np.bool_)) or mode not in PROBE_MODES:
            raise ValueError(f"mode must be one of {', '.join(f'{n} ({v})' for v, n in PROBE_MODES.items())}, got {mode!r}")
        if target is not None:
            check_point(target, "target [m]")
        if start is not None:
            check_point(start, "start [m]")
        self._drive(mode, target, start)

    def _drive(self, mode: int, target=None, start=None) -> None:
        """set_probe without its checks (the press's own targets, made from checked values)."""
        if target is not None:
            self._move[1] = target
            if mode != self._mode[0]:
                self._move[0] = target
            self._target[0] = target
        self._mode[0] = mode
        if start is not None:
            self._move[0] = start

    def set_probe_force(self, force) -> None:
        """Force-controlled probe: push the contact vertex with `force` [N] (a 3-vector)."""
        check_point(force, "force [N]")
        self._mode[0] = PROBE_FORCE
        self._force[0] = force

    @property
    def probe_mode(self) -> int:
        """PROBE_OFF / PROBE_DISPLACEMENT / PROBE_FORCE / PROBE_SPHERE, as the next step will see it."""
        return int(self._mode[0])

    @property
    def probe_target(self) -> np.ndarray:
        """The probe's target [m] as the next step will see it (the sphere's centre in sphere mode), a copy."""
        return np.array(self._target[0], dtype=np.float64)

    @property
    def feedback_force(self) -> np.ndarray:
        """The last step's feedback force [N], a view every step updates (stale while the probe is off)."""
        return self._force_view

    def rest_position(self, vertex=None) -> np.ndarray:
        """Rest position [m] as the device holds it (float32), so that full recovery reads 0."""
        v = self.vertex if vertex is None else vertex
        return self.mesh.vertices[v].astype(np.float32).astype(np.float64)

    def inward_normal(self, vertex=None) -> np.ndarray:
        v = self.vertex if vertex is None else vertex
        return -self.model.vertex_normal_rest[v]

    def positions(self) -> np.ndarray:
        """Current positions of every vertex [m] (host copy)."""
        return self.state.particle_q.numpy().astype(np.float64)

    def check_finite(self, step_index: int) -> None:
        """Raise SimulationDiverged if the region's state is not finite or has run away."""
        q = self.state.particle_q.numpy()
        if runaway(q, self.state.particle_qd.numpy(), self.model.particle_q_rest.numpy(), self.mesh_size):
            self.raise_runaway(step_index)

    @functools.cached_property
    def mesh_size(self) -> float:
        """The mesh's largest extent [m]: a vertex twice as far from rest has run away (check_finite)."""
        return float(np.ptp(self.mesh.vertices, axis=0).max())

    def raise_runaway(self, step_index: int):
        """The SimulationDiverged for a state that ran away at step `step_index` (check_finite found it)."""
        free = self.region.vertices()[: self.region.free_count] if self.region is not None else None
        crit = self.model.critical_dt(free, anchors=self.solver.anchor_scale > 0)
        if self.solver.conditionally_stable and self.step_dt > crit:
            raise SimulationDiverged(
                f"the {self.solver.integrator} integrator diverged at step {step_index} "
                f"(t = {step_index * self.dt:.4g} s): its step {self.step_dt * 1e3:.4g} ms exceeds the critical "
                f"step of about {crit * 1e3:.4g} ms; use a smaller --dt-ms or --integrator implicit"
            )
        raise SimulationDiverged(  # under the critical step at rest: a deep press stiffens the tissue past it
            f"the {self.solver.integrator} integrator ran away at step {step_index} "
            f"(t = {step_index * self.dt:.4g} s): a vertex is not finite or more than twice the mesh's size "
            f"({self.mesh_size * 1e3:.4g} mm) from rest, with a step of {self.step_dt * 1e3:.4g} ms under the critical step at rest "
            f"(about {crit * 1e3:.4g} ms), which a deep press shortens; {remedies(self.solver.integrator)}"
        )

    # -- the press protocol --------------------------------------------------------------------
    def _begin_press(self, ramp, hold, settle, record, record_every, **amplitude):
        """The checked press's schedule, the contact's rest position [m] and inward normal."""
        check_press(**amplitude, ramp=ramp, hold=hold, settle=settle)
        if record is not None and not (isinstance(record_every, (int, np.integer)) and record_every >= 1):
            raise ValueError(f"record_every must be an int >= 1, got {record_every!r}")
        return PressSchedule.from_times(self.dt, ramp, hold, settle), self.rest_position(), self.inward_normal()

    def press(self, depth=0.01, ramp=0.1, hold=0.2, settle=1.0, *, check_every=50, record=None, record_every=1) -> PressResult:
        """Displacement-controlled press at the touched vertex: ramp to `depth` [m] along the inward
        normal over `ramp` [s], hold `hold` [s], release and settle `settle` [s].
        With n substeps a frame the probe moves in n even steps (as the batch's press), and the peak
        force is the largest over every substep (the continuous press's peak, which frame ends can
        miss); `force` holds the frame ends. A press that diverges where its substeps were planned
        (substeps "auto", the explicit integrator) is pressed again from where it began at twice the
        substeps, up to REPRESSES times, as a batch's is (PressResult.substeps; the contact keeps them).

        record: called as ``record(k, total)`` after step k (1..total) of the press when k is a
        multiple of `record_every`, and after the last step; it reads the state itself (a USD
        recorder, say; a press pressed again records its steps again). None (the default) costs one
        test per step."""
        if self.probe_radius > 0 and self.region is not None and self.patch_depth != depth:
            self.touch(self.vertex, depth)  # the patch the sphere covers at this depth, before the snapshot
        start = snapshot_states(self.states, self._cur) if self._may_press_again(REPRESSES) else None
        diverged_at = []
        for left in range(REPRESSES, -1, -1):
            try:
                result = self._press(depth, ramp, hold, settle, check_every, record, record_every)
                result.diverged_at = tuple(diverged_at)
                return result
            except SimulationDiverged:
                if start is None or not self._may_press_again(left):
                    raise
                diverged_at.append(int(self.substeps))
                self._cur = restore_states(self.states, start)
                self._substeps_floor = 2 * self.substeps
                self.plan_substeps()

    def _may_press_again(self, left: int) -> bool:
        # a planned explicit press with re-presses left and room for twice the substeps
        return self._fixed_substeps is None and may_press_again(left, self.solver.integrator, self.substeps)

    def _press(self, depth, ramp, hold, settle, check_every, record, record_every) -> PressResult:
        # press()'s protocol at the current substeps
        schedule, rest, direction = self._begin_press(ramp, hold, settle, record, record_every, depth=depth)
        drive, start = PROBE_DISPLACEMENT, rest
        if self.probe_radius > 0:  # (its region is the patch's at this depth: press() made it)
            travel = depth / max(schedule.ramp_n, 1)
            if travel >= self.probe_radius:
                raise ValueError(f"the sphere would move {travel * 1e3:.3g} mm a step, not less than its radius "
                                 f"{self.probe_radius * 1e3:g} mm: it would pass through vertices; ramp longer or use a smaller dt")
            # the sphere's centre, touching the surface at the contact at rest, then along the inward normal
            drive, start = PROBE_SPHERE, rest - direction * self.probe_radius
        dt, v = self.dt, self.vertex
        total, release = schedule.total, schedule.release_step
        force = np.zeros(total)
        disp = np.zeros(total)
        peak, inverted = 0.0, None
        # the largest reaction over a frame's substeps (the frame's own where it has one step)
        peak_view = self._peak[0] if self.substeps > 1 else self._force_view
        for s in range(total):
            if s < release:
                # the first frame moves from rest (the sphere touching it), as every later one from the last
                self._drive(drive, start + direction * depth * schedule.fraction(s), start if s == 0 else None)
            else:
                self.set_probe(PROBE_OFF)
            f = self.step()
            if s < release:
                force[s] = math.sqrt(float(f[0]) ** 2 + float(f[1]) ** 2 + float(f[2]) ** 2)
                if not math.isfinite(force[s]):
                    self.check_finite(s + 1)
                p = peak_view
                peak = max(peak, math.sqrt(float(p[0]) ** 2 + float(p[1]) ** 2 + float(p[2]) ** 2))
                if s == release - 1 and self.mesh.tet_count:  # the deepest frame: are tets turned inside out?
                    inverted = inverted_tets(self.mesh.vertices, self.positions(), self.mesh.tetrahedra)
            if s >= release or s % check_every == 0:
                pos = self.state.particle_q.numpy()[v] if self._cpu else self.state.particle_q[v : v + 1].numpy()[0]
                disp[s] = float(np.linalg.norm(pos - rest))
                if not math.isfinite(disp[s]) or (s % check_every == 0 and s):
                    self.check_finite(s + 1)
            else:
                disp[s] = depth * schedule.fraction(s)
            if record is not None and ((s + 1) % record_every == 0 or s + 1 == total):
                record(s + 1, total)
        self.check_finite(total)
        return PressResult(vertex=v, depth=float(depth), dt=dt, release_step=release, force=force, displacement=disp,
                           step_peak=peak, inverted_tets=inverted, ring_gap=self._ring_gap(start + direction * depth, drive),
                           substeps=int(self.substeps))

    def _ring_gap(self, centre, drive) -> float | None:
        # PressResult.ring_gap: the fixed ring's vertices stay at rest, so their distance from the centre at full depth
        if drive != PROBE_SPHERE or self.region is None:
            return None
        ring = self.region.boundary()
        if len(ring) == 0:
            return None
        return float(np.linalg.norm(self.mesh.vertices[ring] - centre, axis=1).min()) - self.probe_radius

    def press_force(self, force=2.4, ramp=0.1, hold=0.2, settle=1.0, *, check_every=50, record=None, record_every=1) -> PressResult:
        """Force-controlled press: push the touched vertex along the inward normal with a force
        ramped to `force` [N] over `ramp` [s], held `hold` [s], then released for `settle` [s].
        The result's `force` is the applied force; its `depth` the deepest displacement reached.
        record, record_every: as in :meth:`press`. The paper's probe only (probe_radius 0)."""
        if self.probe_radius > 0:
            raise ValueError(f"press_force pushes the contact vertex; a spherical probe (probe_radius "
                             f"{self.probe_radius:g} m) presses by displacement (press)")
        schedule, rest, direction = self._begin_press(ramp, hold, settle, record, record_every, force=force)
        dt, v = self.dt, self.vertex
        total, release = schedule.total, schedule.release_step
        applied = np.zeros(total)
        disp = np.zeros(total)
        q_view = self.state.particle_q
        for s in range(total):
            if s < release:
                applied[s] = force * schedule.fraction(s)
                self.set_probe_force(direction * applied[s])
            else:
                self.set_probe(PROBE_OFF)
            self.step()
            q_view = self.state.particle_q
            pos = q_view.numpy()[v] if self._cpu else q_view[v : v + 1].numpy()[0]
            disp[s] = float(np.linalg.norm(pos - rest))
            if not math.isfinite(disp[s]) or (s % check_every == 0 and s):
                self.check_finite(s + 1)
            if record is not None and ((s + 1) % record_every == 0 or s + 1 == total):
                record(s + 1, total)
        self.check_finite(total)
        depth = float(disp[:release].max(initial=0.0))
        return PressResult(vertex=v, depth=depth, dt=dt, release_step=release, force=applied, displacement=disp)

