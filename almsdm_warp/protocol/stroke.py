"""A probe that moves: rigid spheres driven along a path, the local region following their contact.

`ProbeStroke.step(centres)` puts each sphere's centre where the path says and returns the tissue's
force on each. Contact is found on the device, from the current surface, by one pass over the
region after each integrator step (kernels/probes/stroke.py), which also flags a sphere that
comes within `guard` of the region's outer rings. The region is then rebuilt, between two steps,
as `rings` rings around the patches the spheres may cover soon (the surface vertices at rest
within `radius + lead` of each centre) and every vertex still moving (the trailing wake: its
displacement from rest above `tol`, or its speed above `tol` per `WAKE_TIME`), without touching
the state: a vertex in both regions keeps its position and velocity, a vertex left behind is put at
rest only once it is within `tol` of it (so no visible pop). `lead` is the hysteresis: the sphere
slides about `lead` between two relocations.

The implicit integrator holds sphere 0 in its own solve (the Control's sphere, the pressing sphere's
law): a backward-Euler step run without the contact and projected after it relaxes the pushed
vertices inside the sphere, and its force fell a third short of the static equilibrium's
(docs/stroke.md). The explicit integrator's step is short enough that the projection after it is
the contact (its reaction is the internal force at the projected positions).

The explicit integrator's substeps are planned once, from the critical step of the whole mesh's
free vertices, which bounds every region's (a region's stiffness is a principal submatrix of the
mesh's: Cauchy's interlacing), so a relocation solves no eigenproblem. Nor does it capture a graph:
the explicit frame reads the region's counts from a device array (kernels/explicit/step.py), and the
graphs captured at the first step, one per region buffer and state, serve every region.
"""

from __future__ import annotations

import functools
import itertools
import math
from typing import NamedTuple

import numpy as np
import warp as wp

from ..kernels.region import state as region_state
from ..kernels.region.state import reset_vertices_left_behind
from ..kernels.arrays import struct_from
from ..kernels.probes.stroke import StrokeSpheres, constrain_spheres
from ..kernels.explicit.step import integrate_explicit
from ..kernels.probes.stroke import STROKE_COUNTS
from ..kernels.arrays import ProbeArrays
from ..region.region import Region
from ..sim.model import PROBE_SPHERE
from ..solvers.stepper import diverged, replayer
from .palpation import Palpation, check_probe_radius, runaway

WAKE_TIME = 0.01
"""[s] A vertex faster than tol / WAKE_TIME is still moving: it stays free when the region moves."""
CHECK_EVERY = 50
"""Steps in which the whole state is checked (finite, within twice the mesh's size of rest: check_finite)
beside the force's bound every step: a stroke whose tissue ran away while the force read 0 raises."""


class StrokePath(NamedTuple):
    """A probe's path: times [s], shape [n]; sphere centres [m], shape [n, 3]; phase of each step
    (0 touch-down and press, 1 slide, 2 lift), shape [n], int."""

    t: np.ndarray
    centre: np.ndarray
    phase: np.ndarray


class _Spheres:
    """The spheres' centres [m] in, reactions [N], contact counts and near-the-edge flags out, with host views."""

    def __init__(self, count, device):
        self.count = int(count)
        d = device
        self.centre = wp.zeros(count, dtype=wp.vec3, device=d)
        self.previous = wp.zeros(count, dtype=wp.vec3, device=d)  # the last frame's, kept by the kernel
        self.reaction = wp.zeros(count, dtype=wp.vec3, device=d)
        self.touching = wp.zeros(count, dtype=wp.int32, device=d)
        self.near_edge = wp.zeros(count, dtype=wp.int32, device=d)
        self.cpu = wp.get_device(d).is_cpu
        names = ("centre", "reaction", "touching", "near_edge")
        if self.cpu:
            self.host = {n: getattr(self, n).numpy() for n in names}
        else:  # pinned host buffers, copied inside the captured graph
            self.pinned = {n: wp.zeros(count, dtype=getattr(self, n).dtype, device="cpu", pinned=True) for n in names}
            self.host = {n: a.numpy() for n, a in self.pinned.items()}
        self.arrays = struct_from(StrokeSpheres, self)

    def copy_in(self):
        if not self.cpu:
            wp.copy(self.centre, self.pinned["centre"])

    def copy_out(self):
        if not self.cpu:
            for n in ("reaction", "touching", "near_edge"):
                wp.copy(self.pinned[n], getattr(self, n))


class _Slot:
    """One region buffer as the stroke's frame reads it: arrays whose addresses never change and the
    counts (kernels/probes/stroke.STROKE_COUNTS) in a device array, so that a frame captured once serves
    every region built into this buffer. `own`: the free vertices and local indices are copied here
    (a model with supports, whose solver reorders them into new arrays at each region); otherwise the
    region's (or the global solver's) own arrays, which are never replaced."""

    def __init__(self, region_vertex, vertex_ring, free_vertex, vertex_local, device, own):
        d = wp.get_device(device)
        self.region_vertex, self.vertex_ring = region_vertex, vertex_ring
        self.own = own
        if own:
            free_vertex = wp.zeros(region_vertex.shape[0], dtype=wp.int32, device=d)
            vertex_local = wp.zeros(vertex_ring.shape[0], dtype=wp.int32, device=d)
        self.free_vertex, self.vertex_local = free_vertex, vertex_local
        self.counts = wp.zeros(len(STROKE_COUNTS), dtype=wp.int32, device=d)
        self._pinned = None if d.is_cpu else wp.zeros(len(STROKE_COUNTS), dtype=wp.int32, device="cpu", pinned=True)
        self._host = (self.counts if d.is_cpu else self._pinned).numpy()

    def load(self, solver, vertex_count, near_ring) -> None:
        """Take the solver's free set (just set to this buffer's region) and the region's counts."""
        if self.own:
            wp.copy(self.free_vertex, solver.free_vertex, count=int(solver.free_vertex.shape[0]))
            wp.copy(self.vertex_local, solver.vertex_local)
        self._host[:] = (solver.free_count, vertex_count, near_ring)
        if self._pinned is not None:  # stream-ordered: the next frame reads the new counts
            wp.copy(self.counts, self._pinned)


class ProbeStroke(Palpation):
    """Rigid spheres of `probe_radius` [m] driven along a path over an organ; the region follows them.

    rings: an int (the local model: `rings` rings around the spheres' patches and the wake, the
    outer one fixed) or "global" (every vertex free, anchored: the reference). probes: how many
    spheres (two fingers: 2). integrator, dt [s], device, fixed_below [m], tissue, substeps, capture,
    edge_scale, anchor_scale: as Palpation's. lead [m]: how far beyond its footprint the region is
    built around a sphere (default: twice the mesh's mean edge), margin: a sphere within `guard`
    [m] (default: half the mean edge) of a vertex on ring (outer - margin) or beyond moves the
    region. tol [m]: a vertex left behind goes back to rest once within tol of it.

    step(centres) advances one frame of dt with the spheres at `centres` and returns their forces.
    """

    protocol = "stroke"

    def __init__(self, mesh, tissue=None, *, probe_radius, rings=4, integrator="explicit", dt=1e-3, device=None,
                 fixed_below=None, probes=1, lead=None, margin=2, guard=None, tol=1e-5, capture=True, substeps="auto",
                 edge_scale=None, anchor_scale=None, **solver_kw):
        radius = check_probe_radius(probe_radius, mesh)
        if radius <= 0:
            raise ValueError(f"a stroke drives rigid spheres: probe_radius must be > 0 m, got {probe_radius}")
        if isinstance(rings, str) and rings != "global":
            raise ValueError(f"rings must be an int >= 1 or 'global', got {rings!r}")
        if isinstance(probes, bool) or not isinstance(probes, (int, np.integer)) or probes < 1:
            raise ValueError(f"probes must be an int >= 1, got {probes!r}")
        for name, value in (("lead", lead), ("guard", guard)):
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a length >= 0 [m], got {value!r}")
        if isinstance(margin, bool) or not isinstance(margin, (int, np.integer)) or margin < 1:
            raise ValueError(f"margin must be an int >= 1 (rings), got {margin!r}")
        if not (math.isfinite(tol) and tol > 0):
            raise ValueError(f"tol must be a length > 0 [m], got {tol!r}")
        super().__init__(mesh, tissue, rings=rings, integrator=integrator, dt=dt, device=device, capture=capture,
                         edge_scale=edge_scale, anchor_scale=anchor_scale, fixed_below=fixed_below, substeps=substeps,
                         **solver_kw)
        self.radius = radius
        """The spheres' radius [m] (the Control's own sphere is on only for the implicit solve, which holds sphere 0)."""
        mean_edge = float(self.mesh.edge_rest_length.mean())
        self.lead = 2.0 * mean_edge if lead is None else float(lead)
        self.guard = 0.5 * mean_edge if guard is None else float(guard)
        self.margin = int(margin)
        self.tol = float(tol)
        self.probe_count = int(probes)
        self.relocations = 0
        """How many times the region moved (0 for the global model)."""
        self.spheres = _Spheres(self.probe_count, self.device)
        self._centre = self.spheres.host["centre"]
        self._sphere_force = self.spheres.host["reaction"]
        self._touching = self.spheres.host["touching"]
        self._near = self.spheres.host["near_edge"]
        surface = self.mesh.surface_vertices
        self._surface = surface
        self._surface_rest = self.mesh.vertices[surface]
        from scipy.spatial import cKDTree

        self._tree = cKDTree(self._surface_rest)
        if self.model.support_count:  # the free surface vertices: a region's seeds where only held ones are near
            self._free_surface = surface[~self.model.support_mask[surface]]
            self._free_tree = cKDTree(self.mesh.vertices[self._free_surface])
        self._held = 0
        self._hold_in_solve()
        n = self.model.particle_count
        self._near_ring = 1 << 30
        self._clearance = {}
        """Lifted sphere -> (where it stood [m], its clearance there [m]): _clear_of_outer's bounds."""
        own = bool(self.model.support_count)
        if self.region is None:
            self._ring_of = np.zeros(n, dtype=np.int32)
            solver = self.solver  # the whole mesh, ring 0
            self._slots = [_Slot(solver.free_vertex, wp.zeros(n, dtype=wp.int32, device=self.device), solver.free_vertex,
                                 solver.vertex_local, self.device, False)]
            self._slots[0].load(solver, n, self._near_ring)
            self.vertex = int(surface[0])
        else:
            self._ring_of = np.full(n, -1, dtype=np.int32)
            self._spare = Region(self.model.dmesh)  # the next region is built here while this one steps
            self._slots = [_Slot(r.region_vertex, r.vertex_ring, r.region_vertex, r.vertex_local, self.device, own)
                           for r in (self.region, self._spare)]
            wp.load_module(region_state, device=self.device)  # loaded now, not by the first relocation
        self._slot = 0  # self._slots[_slot] holds the current region
        self._frames = None  # the explicit frames: [slot][state], captured once at the first step
        self._views = {}
        self._state_views = {}  # _check_state's host views, by the current state's index
        self._started = False
        self._last = None  # the spheres' centres [m] at the last step (None before the first)
        self._steps = 0
        self._pending = None  # a relocation under way: ("seeds", seeds), ("grow", rings left), ("built", None)
        self._warm = False  # the first step runs uncaptured: it loads the kernels outside any capture
        self._fresh = False  # (implicit) the first step after a relocation runs uncaptured; the next one captures

    # -- the API -------------------------------------------------------------------------------
    def step(self, centres) -> np.ndarray:
        """One frame of dt with the spheres' centres at `centres` [m] (shape [probes, 3]; a 3-vector
        for one probe); returns the tissue's force on each sphere [N], same shape (a new array).

        Raises ValueError for centres of the wrong shape or not finite, SimulationDiverged when a
        force is not finite or beyond force_bound."""
        c = np.asarray(centres, dtype=np.float64)
        single = c.shape == (3,)
        if single and self.probe_count == 1:
            c = c.reshape(1, 3)
        if c.shape != (self.probe_count, 3):
            raise ValueError(f"centres must have shape ({self.probe_count}, 3) [m]"
                             f"{' or (3,)' if self.probe_count == 1 else ''}, got {c.shape}")
        if not math.isfinite(float(c.sum())):  # a nan or an inf anywhere makes the sum one (a whole-array test costs more)
            raise ValueError(f"centres must be finite [m], got {c.tolist()}")
        self._check_travel(c)
        self._centre[:] = c
        if self.region is not None:
            if not self._started:
                self.relocate(c)
            elif self._pending is not None:
                self._advance_relocation()
            else:
                move = self._needs_move(c)
                if move == "now":
                    self.relocate(c)
                elif move == "soon":
                    self._pending = ("seeds", self.seeds(c))
        self._advance()
        self._steps += 1
        self._check_state()
        f = self._sphere_force.astype(np.float64)
        total = float(np.abs(f).sum())
        if not total < self._bound:
            raise diverged(self.solver.integrator, f": the spheres' forces {f.tolist()} N are not finite or more than "
                                                  f"{self._bound:.3g} N", self.dt, self.substeps, self.critical_dt)
        return f[0] if single and self.probe_count == 1 else f

    def _check_travel(self, c) -> None:
        """ValueError where a sphere would start inside the organ (a stroke touches down from outside), or
        move its radius or more in one step while it touches the organ or onto it (it would pass through
        vertices, as a sweep's press may not). A lifted sphere may jump: a touch-down elsewhere, clear of it.
        The surface's clearance (a tree query, the step's dearest host work) is asked only at the first step
        and for a step of a radius or more."""
        if self._last is None:
            clear = self.clearance(c)
            p = int(np.argmin(clear))
            if clear[p] < self.radius - self.guard:
                raise ValueError(f"the sphere starts {(self.radius - clear[p]) * 1e3:.3g} mm inside the organ (its centre "
                                 f"{np.round(c[p] * 1e3, 3).tolist()} mm, radius {self.radius * 1e3:g} mm, the surface at rest "
                                 f"{clear[p] * 1e3:.3g} mm from it): start the path clear of the organ")
            self._last = c.copy()
            return
        d = c - self._last
        travel2 = np.einsum("ij,ij->i", d, d)
        if travel2.max() >= self.radius * self.radius:  # a step of a radius or more (rare): the full test
            travel = np.sqrt(travel2)
            far = travel >= self.radius
            inside = bool(self.clearance(c).min() < self.radius - self.guard)
            if inside or (self._touching[far] != 0).any():
                p = int(np.argmax(travel))
                raise ValueError(f"the sphere would move {travel[p] * 1e3:.3g} mm in one step of {self.dt * 1e3:g} ms "
                                 f"{'into' if inside else 'while it touches'} the organ, not less than its radius "
                                 f"{self.radius * 1e3:g} mm: it would pass through vertices; slow the path or use a smaller dt")
        self._last[:] = c

    def _check_state(self) -> None:
        # the state's check (Palpation.check_finite: finite, within twice the mesh's size of rest): on the CPU a
        # CHECK_EVERY-th of the vertices every step (host views: no copy, and no step much dearer than the
        # others); on CUDA the whole state every CHECK_EVERY steps (one copy)
        k = self._steps % CHECK_EVERY
        if not self._cpu:
            if k == 0:
                self.check_finite(self._steps)
            return
        views = self._state_views.get(self._cur)
        if views is None:  # the current state's positions and velocities and the rest positions, host views
            state, n = self.state, self.model.particle_count
            views = self._state_views[self._cur] = (self.host(state.particle_q), self.host(state.particle_qd),
                                                    self.host(self.model.particle_q_rest), -(-n // CHECK_EVERY))
        q, qd, rest, chunk = views
        part = slice(k * chunk, (k + 1) * chunk)
        if runaway(q[part], qd[part], rest[part], self.mesh_size):
            self.raise_runaway(self._steps)

    def clearance(self, points) -> np.ndarray:
        """How far [m] each of `points` [n, 3] lies outside the surface at rest, along the outward normal of its
        nearest surface vertex (negative inside); a sphere's centre less than its radius out touches it."""
        _d, k = self._tree.query(points)
        return np.einsum("ij,ij->i", points - self._surface_rest[k], self.model.vertex_normal_rest[self._surface[k]])

    @property
    def touching(self) -> np.ndarray:
        """Vertices each sphere touched in the last step, shape [probes], int (0: lifted off)."""
        return self._touching.astype(np.int64)

    @property
    def relocating(self) -> bool:
        """True while a relocation spread over steps is under way: the next step goes on with it."""
        return self._pending is not None

    def region_vertex_ids(self) -> np.ndarray:
        """Mesh ids of the region's vertices (every vertex for the global model), host copy."""
        if self.region is None:
            return np.arange(self.model.particle_count, dtype=np.int32)
        return self.region.vertices()

    # -- the region follows --------------------------------------------------------------------
    def _needs_move(self, c) -> str | None:
        # "now": a lifted sphere already touches the surface outside the region's inner rings (a jump
        # of the path: it must find free vertices this step); "soon": a sphere nears the outer rings
        # or the surface outside them (the move is spread over the next steps); None: neither
        soon = any(self._near.tolist())  # a few flags: as Python values (a NumPy reduction costs a microsecond)
        if all(self._touching.tolist()):  # every sphere touches: the contact pass's flag says all
            return "soon" if soon else None
        for p in np.flatnonzero(self._touching == 0):
            # lifted: a touch-down outside the region's inner rings moves it (the surface there is at rest)
            if self._clear_of_outer(p, c[p]):
                continue
            d, k = self._tree.query(c[p])
            if d < self.radius + self.guard:
                ring = self._ring_of[self._surface[k]]
                if ring < 0 or ring >= self._near_ring:
                    if d < self.radius:
                        return "now"
                    soon = True
        return "soon" if soon else None

    def _clear_of_outer(self, p: int, c) -> bool:
        # whether lifted sphere p at c is farther than radius + guard from every surface vertex outside the
        # region's inner rings, so that _needs_move's query could find none: from a bound kept for the
        # sphere (where it stood, its clearance there; the surface is at rest, so the clearance falls by
        # at most the distance moved), made again from a ball query once it has moved past it. A hovering
        # sphere then costs no k-d tree query a step (20-25 us on the liver while the stroke lifts).
        bound = self._clearance.get(p)
        if bound is not None:
            moved = c - bound[0]
            if float(moved @ moved) < bound[1] * bound[1]:
                return True
        reach = self.radius + self.guard
        near = self._surface[self._tree.query_ball_point(c, reach + self.lead)]
        ring = self._ring_of[near]
        outer = near[(ring < 0) | (ring >= self._near_ring)]
        closest = float(np.sqrt(((self.mesh.vertices[outer] - c) ** 2).sum(axis=1).min())) if len(outer) else reach + self.lead
        if closest <= reach:
            self._clearance.pop(p, None)
            return False
        self._clearance[p] = (np.array(c, dtype=np.float64), closest - reach)
        return True

    def seeds(self, centres) -> np.ndarray:
        """Ring 0 of the region around `centres`: the surface vertices at rest within radius + lead of a
        centre, and the vertices of the current region still moving (the wake); at least the nearest
        surface vertex of each centre."""
        # the step of a relocation that takes them is a haptic loop's slowest (a few hundred us, each NumPy call
        # cold): as few calls as give the same set
        c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
        near = self._tree.query_ball_point(c, self.radius + self.lead)
        picked = [self._surface[np.fromiter(itertools.chain.from_iterable(near), dtype=np.int64)]]
        lone = [p for p, k in enumerate(near) if not k]  # the nearest is in a centre's ball where the ball has any
        if lone:
            picked.append(self._surface[self._tree.query(c[lone])[1]])
        if self.region is not None and self.region.vertex_count:
            verts = self.host(self.region.region_vertex)[: self.region.free_count]
            d = self.host(self.state.particle_q)[verts] - self.mesh.vertices[verts]
            u = self.host(self.state.particle_qd)[verts]
            moving = (np.sqrt(np.einsum("ij,ij->i", d, d)) > self.tol) | (np.sqrt(np.einsum("ij,ij->i", u, u)) * WAKE_TIME > self.tol)
            picked.append(verts[moving])
        seeds = np.unique(np.concatenate(picked)).astype(np.int32)
        if self.model.support_count:
            self._check_support(c)
            seeds = seeds[~self.model.support_mask[seeds]]
            if not len(seeds):  # only held vertices near: the nearest free surface vertex of each centre
                seeds = np.unique(self._free_surface[self._free_tree.query(c)[1]]).astype(np.int32)
        return seeds

    def _check_support(self, c) -> None:
        """ValueError where a sphere reaches a vertex held by the support (at rest within its radius): it
        would press the rigid support, which no force of the model holds."""
        for p, near in enumerate(self._tree.query_ball_point(c, self.radius)):
            held = [int(v) for v in self._surface[np.asarray(near, dtype=np.int64)] if self.model.support_mask[v]]
            if held:
                raise ValueError(f"the sphere at {np.round(c[p] * 1e3, 3).tolist()} mm reaches vertex {held[0]}, held by "
                                 f"the support (fixed_below): the probe cannot press the support; keep the path above it")

    def relocate(self, centres) -> None:
        """Rebuild the region around `centres` [m] and the wake now, keeping every vertex's state (see
        the module). step() spreads the same work over steps (the seeds; ring 1; the other rings; the
        swap), each under the haptic step's budget."""
        self._pending = ("seeds", self.seeds(centres))
        while self._pending is not None:
            self._advance_relocation()

    def _advance_relocation(self) -> None:
        # the build takes two steps: ring 1, then the others (build_seeds(1) then expand(rings - 1) make
        # the region build_seeds(rings) makes: rings are appended in the same order)
        stage, work = self._pending
        if stage == "seeds":
            # ring 1 only; its local indices and springs are left to the expand that follows
            self._spare.build_seeds(work, 1, contact=int(work[0]), index=self.rings <= 1)
            self._pending = ("grow", self.rings - 1) if self.rings > 1 else ("built", None)
            return
        if stage == "grow":
            self._spare.expand(work)
            self._pending = ("built", None)
            return
        old, region = self.region, self._spare
        if old.vertex_count:
            reset_vertices_left_behind(self.model, old.region_vertex, old.vertex_count, region, self.states)
        self.region, self._spare = region, old
        self.solver.set_region(region)
        if not self._started:
            self.plan_substeps()  # for the whole mesh (region_critical_dt): once; may fall back to implicit
            self._hold_in_solve()
        self._graphs = None  # (implicit) the solver's free count changed: its frame is captured again
        self.vertex = int(region.seed)
        self._ring_of = self.host(region.vertex_ring)
        self._near_ring = max(region.outer_ring - self.margin, 1)
        self._clearance = {}  # the lifted spheres' bounds hold for the old region's rings
        self._slot ^= 1
        self._slots[self._slot].load(self.solver, region.vertex_count, self._near_ring)
        if self.solver.conditionally_stable:  # the frames' explicit step reads the new region's tets (captured once)
            self.solver.built_tets(self.state.particle_q)
        self._near[:] = 0
        self._fresh = True
        self._pending = None
        if self._started:
            self.relocations += 1
        self._started = True

    def _hold_in_solve(self) -> None:
        # the implicit solve holds sphere 0: the Control's sphere, its centre read from the spheres' array
        if self._held or self.solver.integrator != "implicit":
            return
        if self.probe_count > 1:
            raise ValueError(f"the implicit integrator holds one sphere in its solve: probes must be 1 with it, "
                             f"got {self.probe_count} (use integrator='explicit' for several)")
        self._held = 1
        self.control.set_sphere(self.radius)
        self.control.set(mode=PROBE_SPHERE)
        self.control.arrays = struct_from(ProbeArrays, self.control, probe_target=self.spheres.centre)

    def host(self, array) -> np.ndarray:
        """A host view of a device array: on the CPU one view kept per array (free to read), on CUDA a copy."""
        if not self._cpu:
            return array.numpy()
        view = self._views.get(id(array))
        if view is None:
            view = self._views[id(array)] = (array, array.numpy())
        return view[1]

    def region_critical_dt(self) -> float:
        """The critical step [s] of every free vertex of the mesh: a bound under any region's (module doc)."""
        if not hasattr(self, "_mesh_critical_dt"):
            free = np.flatnonzero(~self.model.support_mask)
            self._mesh_critical_dt = self.model.critical_dt(free, anchors=True)
        return self._mesh_critical_dt

    # -- stepping ------------------------------------------------------------------------------
    def _advance(self) -> None:
        # one frame. The explicit frame reads its counts and the region's arrays from the current
        # buffer (_Slot): one graph per buffer and state, captured at the end of the first step, serves
        # every region, so a relocation captures nothing. The implicit solve takes its free count as a
        # scalar (kernels/implicit/step.py): its frame is captured again after each relocation,
        # at the second step (the first runs uncaptured).
        i = self._cur
        if self._frames is not None:
            self._frames[self._slot][i]()
            self._cur ^= self._parity
            return
        graphs = self._graphs
        if graphs is None:
            graphs = self._graphs = [None, None]
        if graphs[i] is not None:
            self._cur ^= self._parity
            graphs[i]()
            return
        frame = self._frame(self.states[i], self.states[1 - i], self._slots[self._slot])
        explicit = self.solver.conditionally_stable
        if not self.capture or not self._warm or self._fresh or explicit:
            frame()
            self._warm, self._fresh = True, False
        else:
            graphs[i] = self._capture(frame)
            graphs[i]()
        self._cur ^= self._parity
        if not self._cpu:
            wp.synchronize_device(self.device)
        if explicit and self.capture:
            self._frames = [[self._capture(self._frame(self.states[k], self.states[1 - k], slot)) for k in (0, 1)]
                            for slot in self._slots]

    def _capture(self, frame):
        with wp.ScopedCapture(device=self.device, force_module_load=False) as cap:
            frame()
        return replayer(cap.graph, self.device)

    def _frame(self, a, b, slot):
        # the frame's launches as one call, from the buffer `slot`'s arrays
        sp = self.spheres
        solver = self.solver
        n = self.substeps
        h = self.dt / n
        calls = []
        if not self._warm:  # the first frame (uncaptured) starts where it is; on CUDA after the centres' copy in
            calls.append(functools.partial(wp.copy, sp.previous, sp.centre))
        threads = 1 if self.device.is_cpu else self.model.particle_count
        for s in range(n):
            if solver.conditionally_stable:
                # the Control is off here (the stroke's spheres are put on by the contact pass below)
                calls.append(functools.partial(integrate_explicit, self.model, slot.free_vertex, slot.counts, threads,
                                               solver.anchor_scale, a, b, self.control, h, solver.built_tets(a.particle_q)))
            else:
                calls.append(functools.partial(solver.step, a, b, self.control, h))
            calls.append(functools.partial(
                constrain_spheres, self.model, slot.region_vertex, slot.counts, slot.vertex_ring, slot.vertex_local,
                self.control.probe_surface, sp.arrays, sp.count, self.radius, self.guard, h, a, b, self._held,
                solver.anchor_scale, (s + 1) / n))
            a, b = b, a
        return functools.partial(self._run_frame, calls)

    def _run_frame(self, calls) -> None:
        self.spheres.copy_in()
        for call in calls:
            call()
        self.spheres.copy_out()

    def touch(self, vertex: int, depth: float | None = None) -> None:
        raise TypeError("a ProbeStroke is driven by its spheres' centres: call step(centres), not touch()")

    def press(self, *args, **kw):
        raise TypeError("a ProbeStroke is driven by its spheres' centres: call step(centres) along a path (builtin_stroke)")

    press_force = press


def builtin_stroke(mesh, probe_radius, depth=8e-3, length=60e-3, speed=20e-3, dt=1e-3, *, vertex=None,
                   direction=(1.0, 0.0, 0.0), clearance=2e-3, hold=0.0, settle=0.0) -> StrokePath:
    """The built-in stroke: touch down at `vertex` (default the top vertex, region.contact.top_vertex),
    press `depth` [m] along the inward normal (and hold there `hold` [s]), slide `length` [m] over the
    surface along `direction` (projected on the tangent plane), lift until `clearance` [m] above it,
    then stay there `settle` [s]; at `speed` [m/s] throughout, one centre every `dt` [s].

    The slide's path is the rest surface walked in small steps (each projected back on it); the
    centre keeps at probe_radius - depth from it along the surface's normal (vertex normals
    interpolated over the triangle: a smooth path). Returns StrokePath(t, centre, phase).
    """
    from ..region.contact import top_vertex

    R = check_probe_radius(probe_radius)
    for name, value in (("depth", depth), ("length", length), ("speed", speed), ("dt", dt)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be > 0, got {value!r}")
    for name, value in (("clearance", clearance), ("hold", hold), ("settle", settle)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be >= 0, got {value!r}")
    surface = RestSurface(mesh)
    v = top_vertex(mesh) if vertex is None else int(vertex)
    x0, n0 = surface.project(mesh.vertices[v][None, :])
    # the slide: walk the surface in steps of at most 0.5 mm, then sample it at speed x dt
    walk = max(int(math.ceil(length / 5e-4)), 1)
    ds = length / walk
    t0 = np.asarray(direction, dtype=np.float64)
    points = [x0[0]]
    normal = n0[0]
    for _ in range(walk):
        tangent = t0 - np.dot(t0, normal) * normal
        size = np.linalg.norm(tangent)
        if size < 1e-12:
            raise ValueError(f"direction {tuple(direction)} is normal to the surface at the contact: no slide along it")
        x, nn = surface.project((points[-1] + ds * tangent / size)[None, :])
        points.append(x[0])
        normal = nn[0]
    points = np.asarray(points)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    press_n = max(int(round(depth / (speed * dt))), 1)
    slide_n = max(int(round(length / (speed * dt))), 1)
    lift_n = max(int(round((depth + clearance) / (speed * dt))), 1)
    settle_n = int(round(settle / dt))
    s = np.arange(1, slide_n + 1) * (arc[-1] / slide_n)
    along = np.stack([np.interp(s, arc, points[:, k]) for k in range(3)], axis=1)
    xs, ns = surface.project(along)
    press_d = np.minimum(np.arange(1, press_n + int(round(hold / dt)) + 1) / press_n, 1.0) * depth
    press = x0 + n0 * (R - press_d[:, None])
    slide = xs + ns * (R - depth)
    lift_d = depth - (depth + clearance) * np.arange(1, lift_n + 1) / lift_n
    lift = xs[-1] + ns[-1] * (R - lift_d[:, None])
    rest = np.repeat(lift[-1:], settle_n, axis=0)
    centre = np.concatenate([press, slide, lift, rest])
    phase = np.concatenate([np.zeros(len(press)), np.ones(slide_n), np.full(lift_n + settle_n, 2)]).astype(np.int32)
    t = np.arange(1, len(centre) + 1) * dt
    return StrokePath(t, centre, phase)


class RestSurface:
    """A mesh's surface at rest: closest points (region.contact's query) and smooth normals (vertex
    normals interpolated over the triangle)."""

    def __init__(self, mesh, device="cpu"):
        from ..region.contact import ContactQuery
        from ..sim.model import vertex_normals

        self.query = ContactQuery(mesh, device)
        self.vertices = np.asarray(mesh.vertices, dtype=np.float64)
        self.triangles = np.asarray(mesh.triangles)
        self.vertex_normal = vertex_normals(mesh.vertices, mesh.triangles)

    def project(self, points):
        """(closest points on the surface [m], their unit normals), shapes [k, 3]."""
        from ..mesh.io import import_trimesh

        points_to_barycentric = import_trimesh().triangles.points_to_barycentric
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        hit = self.query(points)
        tri = self.triangles[hit.face]
        bary = points_to_barycentric(self.vertices[tri], hit.point)
        n = np.einsum("kj,kjd->kd", bary, self.vertex_normal[tri])
        return hit.point, n / np.linalg.norm(n, axis=1, keepdims=True)
