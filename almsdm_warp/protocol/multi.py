"""Several probes at once, each with its own region; regions that touch merge into one.

The same Model, States and solver as one Palpation: a *patch* is a region with its own
solver, and every patch's step (plus the drive of its probes' vertices) goes into one captured
graph. Regions are grown from several seeds (kernels/region/rings.py), so merging two patches is
rebuilding one region from both probes' vertices with the larger ring count, which holds both.
With `tol` and no `rings`, each patch grows as AdaptivePalpation's region does (the criterion in
almsdm_warp.adaptive) and, once all its probes are off and it is back within `tol` of rest, is
retired. Probes are displacement-controlled (PROBE_DISPLACEMENT) or off (PROBE_OFF).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import warp as wp

from .adaptive import FORCE_TOL, MARGIN, coherent_count, fixed_ring_estimate, force_error_estimate, vertex_stiffness
from ..mesh.device_mesh import check_vertex
from ..kernels.arrays import ProbeArrays, struct_from
from ..kernels.probes.multi import drive_probe_vertices
from ..kernels.region.state import clear_region
from ..kernels.region.ring_motion import eval_region_motion
from ..sim.model import PROBE_DISPLACEMENT, PROBE_OFF, Model
from ..solvers.stepper import (REPRESSES, SimulationDiverged, capture_step_pair, check_results, force_bound, may_press_again,
                               plan_substeps, restore_states, snapshot_states)
from .palpation import PressResult
from ..region.region import Region, check_rings
from ..solvers import make_solver, solver_class
from .schedule import PressSchedule, check_press
from ..checks import rings_text


class MultiRegion(Region):
    """A Region grown from one or more seed vertices: ring r holds the vertices r hops from the nearest."""


class _Probes:
    """Per-probe vertex, mode, target [m] and reaction [N] on the device, with host views."""

    def __init__(self, vertices, device):
        n = len(vertices)
        self.probe_vertex = wp.array(np.asarray(vertices, dtype=np.int32), dtype=wp.int32, device=device)
        self.probe_mode = wp.zeros(n, dtype=wp.int32, device=device)
        self.probe_target = wp.zeros(n, dtype=wp.vec3, device=device)
        self.probe_reaction = wp.zeros(n, dtype=wp.vec3, device=device)
        self.arrays = struct_from(ProbeArrays, self, probe_force=wp.zeros(n, dtype=wp.vec3, device=device))
        self.cpu = wp.get_device(device).is_cpu
        if self.cpu:
            self.mode, self.target, self.reaction = (a.numpy() for a in (self.probe_mode, self.probe_target, self.probe_reaction))
        else:
            self.pinned = [wp.zeros(n, dtype=t, device="cpu", pinned=True) for t in (wp.int32, wp.vec3, wp.vec3)]
            self.mode, self.target, self.reaction = (a.numpy() for a in self.pinned)

    def copy_in(self):
        if not self.cpu:
            wp.copy(self.probe_mode, self.pinned[0])
            wp.copy(self.probe_target, self.pinned[1])

    def copy_out(self):
        if not self.cpu:
            wp.copy(self.pinned[2], self.probe_reaction)


class Patch:
    """One region, the probes in it, and the solver that steps it."""

    def __init__(self, owner, probes, rings):
        self.probes = sorted(probes)
        seeds = owner.vertices[self.probes]
        self.region = MultiRegion(owner.model.dmesh).build_seeds(seeds, rings)
        self.solver = make_solver(owner.model, owner.integrator, **owner.solver_kw)
        self.patch_probe = wp.array(np.asarray(self.probes, dtype=np.int32), dtype=wp.int32, device=owner.device)
        self.motion = wp.zeros(owner.max_rings + 3, dtype=wp.float32, device=owner.device)
        self.rings_chosen = self.region.outer_ring
        self.reason = "not pressed yet"
        self.events = []
        self.force_over = False
        """Whether the last check's force-error estimate was over the bound."""
        self.coherent = (-1, 1.0)
        """(region vertices, coherent_count) of the fixed ring when it was last read."""

    def vertices(self) -> np.ndarray:
        return self.region.vertices()

    def set_driven(self, model, driven_vertices):
        """Give the solver the region's free vertices but the driven ones (which it then holds)."""
        region = self.region
        verts = region.vertices()
        nfree = region.free_count
        held = np.isin(verts[:nfree], driven_vertices)
        free, driven = verts[:nfree][~held], verts[:nfree][held]  # the region's ring order kept
        order = np.concatenate([free, driven, verts[nfree:]]).astype(np.int32)
        local = np.full(model.particle_count, -1, dtype=np.int32)
        local[order] = np.arange(len(order), dtype=np.int32)
        d = model.device
        self.view = SimpleNamespace(
            region_vertex=wp.array(order, dtype=wp.int32, device=d),
            free_count=len(free),
            vertex_local=wp.array(local, dtype=wp.int32, device=d),
            vertex_count=len(order),
        )
        self.solver.set_region(self.view)


class MultiPalpation:
    """Several probes on one organ: a region per probe, merged where they touch.

    rings: an int (every region that many rings, no growth) or None with `tol` [m] (adaptive).
    The other parameters are AdaptivePalpation's. Probe i holds ``vertices[i]``. As Palpation's,
    the explicit integrator takes each frame of dt in `substeps` under 0.9 x the critical step of
    the patches' free vertices together (re-planned whenever the patches change); past
    LIMITS["substeps"] it runs the implicit integrator instead and says so in `notes`
    (solvers.stepper.plan_substeps). A press that diverges (a force or a displacement not finite,
    or running away) where its substeps were planned, begun right after touch(), is pressed again from
    that state at twice the substeps, up to REPRESSES times, as Palpation's is (PressResult.substeps;
    the probes keep them until the next touch()); otherwise it raises SimulationDiverged.
    """

    def __init__(self, mesh, tissue=None, *, tol=1e-4, rings=None, integrator="explicit", dt=1e-3, device=None,
                 start_rings=1, max_rings=64, check_interval=0.01, retire=True, force_tol=FORCE_TOL, margin=MARGIN,
                 capture=True, law=None, **solver_kw):
        if rings is not None:
            start_rings = check_rings(rings)
            if start_rings < 1:
                raise ValueError(f"rings must be >= 1, got {rings}")
        if not (math.isfinite(tol) and tol > 0):
            raise ValueError(f"tol must be a length > 0 [m], got {tol!r}")
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be > 0, got {dt}")
        self.model = Model(mesh, tissue, device, law=law)
        self.model.law_entry.require(integrator=integrator, path="multi")
        self.device = self.model.device
        self.mesh = self.model.mesh
        self.integrator = integrator
        solver_class(integrator)  # checks the integrator's name now, not at the first touch
        self.solver_kw = solver_kw
        self.adaptive = rings is None
        self.tol, self.dt = float(tol), float(dt)
        self.start_rings, self.max_rings = int(start_rings), int(max(max_rings, start_rings))
        self.force_tol, self.margin, self.retire = float(force_tol), float(margin), bool(retire)
        self.capture = bool(capture)
        self.check_steps = max(int(round(check_interval / self.dt)), 1)
        self.states = [self.model.state(), self.model.state()]
        self._cur = 0
        self._off = self.model.control()  # every solver's own probe is off: drive_probes holds the probes
        self.patches = []
        self.retired = []
        """dict(probes, rings, events) of each patch retired since touch()."""
        self.vertices = np.zeros(0, dtype=np.int32)
        self._graphs = None
        self._dirty = True
        self.substeps, self._parity = 1, 1
        """Explicit steps in each frame of dt (1 for the implicit integrator)."""
        self._substeps_floor = 1  # the fewest substeps a plan takes for these probes (raised by a press pressed again)
        self.critical_dt = math.inf
        """Critical step [s] of the explicit integrator over the patches' free vertices (inf: not asked)."""
        self.notes = []
        """What the palpation changed on its own (a fall-back to the implicit integrator), one line each."""
        self._bound = force_bound(self.model)
    @property
    def state(self):
        return self.states[self._cur]

    # -- probes --------------------------------------------------------------------------------
    def touch(self, vertices) -> None:
        """Put probe i on `vertices[i]` (all off), each with a fresh region; touching regions merge."""
        vertices = np.asarray([check_vertex(self.mesh, int(v), "contact vertex") for v in vertices], dtype=np.int32)
        if len(vertices) == 0 or len(np.unique(vertices)) != len(vertices):
            raise ValueError(f"touch() needs one or more distinct contact vertices, got {vertices.tolist()}")
        for patch in list(self.patches):
            self._retire(patch)
        self.vertices = vertices
        self.probes = _Probes(vertices, self.device)
        self.reaction = self.probes.reaction  # a view that every step updates
        self._stiffness = vertex_stiffness(self.model)
        self._driven = np.zeros(len(vertices), dtype=bool)
        self._countdown = self.check_steps
        self._steps = 0
        self._substeps_floor = 1
        self.retired = []
        for i in range(len(vertices)):
            self.patches.append(Patch(self, [i], self.start_rings))
        self._merge()
        self._dirty = True

    def set_probes(self, modes, targets=None) -> None:
        """Every probe's mode (PROBE_OFF / PROBE_DISPLACEMENT; one or one per probe) and target [m]."""
        mode = self.probes.mode
        mode[:] = modes
        if not np.all((mode == PROBE_OFF) | (mode == PROBE_DISPLACEMENT)):
            bad = mode[(mode != PROBE_OFF) & (mode != PROBE_DISPLACEMENT)]
            mode[:] = PROBE_OFF
            raise ValueError(f"probe modes are PROBE_OFF (0) or PROBE_DISPLACEMENT (1) here, got {bad.tolist()}")
        if targets is not None:
            self.probes.target[:] = targets
        driven = self.probes.mode == PROBE_DISPLACEMENT
        if not np.array_equal(driven, self._driven):
            self._driven = driven
            self._dirty = True

    def patch_of(self, probe: int):
        """The patch holding probe `probe`, or None when its region is retired."""
        return next((p for p in self.patches if probe in p.probes), None)

    def rest_positions(self) -> np.ndarray:
        return self.mesh.vertices[self.vertices].astype(np.float32).astype(np.float64)

    def inward_normals(self) -> np.ndarray:
        return -self.model.vertex_normal_rest[self.vertices]

    def positions(self) -> np.ndarray:
        return self.state.particle_q.numpy().astype(np.float64)

    # -- patches -------------------------------------------------------------------------------
    def _retire(self, patch):
        region = patch.region
        clear_region(self.model, region, self.states)
        self.patches.remove(patch)
        self._dirty = True

    def _merge(self):
        """Rebuild any two patches whose regions share a vertex as one, until none do."""
        merged = True
        while merged:
            merged = False
            sets = [p.vertices() for p in self.patches]
            for a in range(len(self.patches)):
                for b in range(a + 1, len(self.patches)):
                    if len(np.intersect1d(sets[a], sets[b], assume_unique=True)):
                        pa, pb = self.patches[a], self.patches[b]
                        rings = max(pa.region.outer_ring, pb.region.outer_ring)
                        both = Patch(self, pa.probes + pb.probes, rings)
                        merge = {"step": self._steps, "event": "merged", "rings": int(rings), "probes": both.probes}
                        both.events = pa.events + pb.events + [merge]
                        both.rings_chosen = max(pa.rings_chosen, pb.rings_chosen, rings)
                        self.patches = [p for p in self.patches if p is not pa and p is not pb] + [both]
                        merged = True
                        break
                if merged:
                    break
        self._dirty = True

    def _rebuild(self):
        # a pressed probe whose region was retired gets a fresh one
        held = {i for p in self.patches for i in p.probes}
        for i in np.flatnonzero(self._driven):
            if int(i) not in held:
                self.patches.append(Patch(self, [int(i)], self.start_rings))
        self._merge()
        self._plan_substeps()
        driven = self.vertices[self._driven]
        for p in self.patches:
            p.set_driven(self.model, driven)
        self._graphs = None
        self._dirty = False

    def _plan_substeps(self):
        """Substeps of the explicit integrator for the patches as they are now, or the implicit
        fall-back (solvers.stepper.plan_substeps: every patch's solver then made anew)."""
        self.substeps, self._parity = 1, 1
        if not self.patches:
            return

        def critical():
            free = np.unique(np.concatenate([p.region.vertices()[: p.region.free_count] for p in self.patches]))
            return self.model.critical_dt(free)

        plan = plan_substeps(self.integrator, self.dt, critical, None, "the palpation")
        if plan.integrator != self.integrator:
            self.notes.append(plan.note)
            self.integrator = plan.integrator
            for p in self.patches:
                p.solver = make_solver(self.model, self.integrator, **self.solver_kw)
        self.critical_dt = plan.critical_dt
        n = max(plan.substeps, self._substeps_floor) if solver_class(self.integrator).conditionally_stable else plan.substeps
        self.substeps, self._parity = n, n & 1

    # -- stepping ------------------------------------------------------------------------------
    def _launch_step(self, a, b):
        self.probes.copy_in()
        h = self.dt / self.substeps
        for _ in range(self.substeps):  # a -> b, b -> a, ...: the frame ends in b for an odd count
            for p in self.patches:
                p.solver.step(a, b, self._off, h)
                drive_probe_vertices(self.model, p.patch_probe, self.probes, h, a, b)
            a, b = b, a
        self.probes.copy_out()

    def step(self) -> np.ndarray:
        """One step of dt for every patch; returns the reactions [N], shape [probes, 3] (a view)."""
        if self._dirty:
            self._rebuild()
        if not self.patches:
            self.probes.reaction[:] = 0.0
        elif self._graphs is not None:
            self._graphs[self._cur]()
            self._cur ^= self._parity
        else:
            self._launch_step(self.states[self._cur], self.states[1 - self._cur])  # loads the modules uncaptured
            self._cur ^= self._parity
            if self.capture:
                self._graphs = capture_step_pair(self._launch_step, self.states, self.device)
            if not self.device.is_cpu:
                wp.synchronize_device(self.device)
        self._steps += 1
        self._countdown -= 1
        if self._countdown <= 0:
            self._countdown = self.check_steps
            self._check()
        return self.probes.reaction

    def _check(self):
        grew = False
        for patch in list(self.patches):
            eval_region_motion(self.model, patch.region, self.state, patch.motion)
            m = patch.motion.numpy()
            n = patch.region.outer_ring
            pressed = [i for i in patch.probes if self._driven[i]]
            if not pressed:
                moved = float(m[1 : n + 1].max(initial=0.0)) if n else float(m[1])
                if self.retire and moved <= self.tol:
                    patch.events.append(
                        {"step": self._steps, "event": "retired", "rings": int(n), "estimate_mm": round(moved * 1e3, 6)}
                    )
                    self.retired.append({"probes": patch.probes, "rings": int(patch.rings_chosen), "events": patch.events})
                    self._retire(patch)
                continue
            if not self.adaptive or n == 0:
                continue
            est, lam = fixed_ring_estimate(float(m[0]), float(m[n]))
            work = float(np.linalg.norm(self.probes.reaction[pressed], axis=1).sum()) * float(m[1])
            if patch.coherent[0] != patch.region.vertex_count:  # the fixed ring read back once per region size
                patch.coherent = (patch.region.vertex_count, coherent_count(self._stiffness, patch.region.boundary()))
            ferr = force_error_estimate(float(m[-1]), work, patch.coherent[1])
            over = ferr > 0.5 * self.force_tol  # grows on the force when two checks in a row agree (adaptive.py)
            if est * self.margin <= self.tol and (not over or not patch.force_over):
                patch.force_over = over
                patch.reason = (f"ring {n} (fixed) would move {est * 1e3:.3g} mm if freed (estimated), force error "
                                f"{ferr:.2%}: within tol {self.tol * 1e3:g} mm")
                continue
            if n >= self.max_rings:
                patch.reason = f"stopped at max_rings {self.max_rings}"
                continue
            grow = 1
            if 0.0 < lam < 1.0 and math.isfinite(est) and est * self.margin > self.tol:
                grow = min(max(int(math.ceil(math.log(self.tol / (self.margin * est)) / math.log(lam))), 1), 3)
            grow = min(grow, self.max_rings - n)
            size = patch.region.vertex_count
            patch.region.expand(grow)
            if patch.region.vertex_count == size:
                self.max_rings = min(self.max_rings, patch.region.outer_ring)
            patch.rings_chosen = max(patch.rings_chosen, patch.region.outer_ring)
            patch.reason = f"grew to {rings_text(patch.region.outer_ring)}: ring {n} would have moved {est * 1e3:.3g} mm"
            patch.events.append({"step": self._steps, "event": f"+{grow}", "rings": int(patch.region.outer_ring),
                                 "estimate_mm": round(est * 1e3, 6) if math.isfinite(est) else None})
            grew = True
        if grew:
            self._merge()

    # -- the press protocol --------------------------------------------------------------------
    def press(self, depth=0.01, ramp=0.1, hold=0.2, settle=1.0) -> list:
        """Every probe pressed at once: driven `depth` [m] along its inward normal over `ramp` [s],
        held `hold` [s], released for `settle` [s]; one PressResult per probe. A press begun right after
        touch() that diverges at its planned substeps is pressed again from there at twice them (the
        class's docstring)."""
        check_press(depth=depth, ramp=ramp, hold=hold, settle=settle)
        start = snapshot_states(self.states, self._cur) if self._steps == 0 and may_press_again(REPRESSES, self.integrator, self.substeps) else None
        diverged_at = []
        for left in range(REPRESSES, -1, -1):
            try:
                results = self._press(depth, ramp, hold, settle)
                for r in results:
                    r.diverged_at = tuple(diverged_at)
                return results
            except SimulationDiverged:
                if start is None or not may_press_again(left, self.integrator, self.substeps):
                    raise
                diverged_at.append(int(self.substeps))
                floor = 2 * self.substeps
                self.touch(self.vertices)  # the patches a fresh touch makes, as the press began with them
                self._cur = restore_states(self.states, start)
                self._substeps_floor = floor

    def _press(self, depth, ramp, hold, settle) -> list:
        # press()'s protocol at the current substeps
        schedule = PressSchedule.from_times(self.dt, ramp, hold, settle)
        total, release = schedule.total, schedule.release_step
        rest, normal = self.rest_positions(), self.inward_normals()
        count = len(self.vertices)
        force, disp = np.zeros((count, total)), np.zeros((count, total))
        for s in range(total):
            if s < release:
                self.set_probes(PROBE_DISPLACEMENT, rest + normal * depth * schedule.fraction(s))
            else:
                self.set_probes(PROBE_OFF)
            f = self.step()
            q = self.state.particle_q.numpy()
            with np.errstate(over="ignore", invalid="ignore"):  # a press running away: check_results says so, once
                force[:, s] = np.linalg.norm(f, axis=1)
                disp[:, s] = np.linalg.norm(q[self.vertices] - rest, axis=1)
        size = float(np.ptp(self.mesh.vertices, axis=0).max())
        check_results(self.integrator, self.vertices, force.max(axis=1), disp.max(axis=1), self._bound, size, self.dt,
                      self.substeps, self.critical_dt)
        return [
            PressResult(
                vertex=int(v), depth=float(depth), dt=self.dt, release_step=release, force=force[i], displacement=disp[i],
                substeps=self.substeps,
            )
            for i, v in enumerate(self.vertices)
        ]
