"""The adaptive region: grown ring by ring during a press to a displacement tolerance, retired at rest.

Criterion (docs/adaptive.md). A region of N rings holds ring N at rest; against the global
anchored model its largest displacement error is then the displacement ring N has in the global
model (measured: equal to 4 digits on the stomach and the liver). Every few steps one kernel
(kernels/region/ring_motion.py) returns the largest displacement of each free ring and a one-step Jacobi
estimate u_J of the fixed ring's (each fixed vertex freed alone, its neighbours held). For a chain
with anchors the Jacobi ratio rho = u_J / u_(N-1) is lambda / (1 + lambda^2), lambda the decay per
ring, and freeing the whole far field multiplies u_J by (1 + lambda^2) / (1 - lambda^2): that is
the estimate e_N of ring N's displacement (0.77-1.05 of the true value on the scenes and the
shared meshes). The region grows while e_N * MARGIN > tol, or while the force error of holding
ring N is over half the force tolerance. That error is exactly r_B . u_B / (F delta) for a linear
model (r_B the fixed ring's reactions, u_B its global displacements, F delta the probe's work); the
kernel sums f . u_J over the fixed ring, and the reactions acting together multiply it by about
sqrt(n), n the fixed-ring vertices within the anchors' reach (all of them with no anchors):
force_error_estimate. A region that covers its mesh component frees its outer ring (the global
model there). With a sphere, ring 0 is the patch it covers (Palpation.touch) and stays so.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..kernels.region.state import clear_region
from ..kernels.region.ring_motion import eval_region_motion
from ..sim.model import PROBE_DISPLACEMENT, PROBE_OFF, PROBE_SPHERE
from ..solvers.stepper import replayer
from .palpation import Palpation
from .schedule import PressSchedule
from ..checks import rings_text

MARGIN = 1.2
"""Safety factor on the fixed-ring estimate (it read 0.77-1.05 of the true value: docs/adaptive.md)."""
COHERENCE = 2.0
"""The force-error estimate's factor on sqrt(n): the fixed ring's reactions act together, and a
continuum's compliance to n of them acting together is ~sqrt(n) times the sum of each vertex's own
(a shell of n vertices); 2 bounds the measured ratio on the tet ball, the liver and the stomach, with
and without anchors (docs/adaptive.md)."""
FORCE_TOL = 0.01
"""Relative peak-force error the region is grown to stay under (the estimate is held to half of it)."""


def fixed_ring_estimate(jacobi: float, outer_free: float) -> tuple[float, float]:
    """(e_N, lambda): ring N's displacement had it been free, from the Jacobi estimate at ring N and
    the largest displacement of ring N - 1 (any unit); lambda = 1 and e_N = inf when they do not decay."""
    if outer_free <= 0.0:
        return (0.0, 0.0) if jacobi <= 0.0 else (math.inf, 1.0)
    rho = jacobi / outer_free
    if rho >= 0.5:
        return math.inf, 1.0
    lam = (1.0 - math.sqrt(1.0 - 4.0 * rho * rho)) / (2.0 * rho) if rho > 0.0 else 0.0
    return jacobi * (1.0 + lam * lam) / (1.0 - lam * lam), lam


def vertex_stiffness(model) -> tuple[np.ndarray, np.ndarray]:
    """(anchor k_a, sum of the springs' k_ij) of every vertex [N/m], float64: how far the fixed ring's
    reactions reach (coherent_count)."""
    ka = model.anchor_ke.numpy().astype(np.float64)
    ks = np.zeros(model.particle_count)
    edges, ke = model.mesh.edges, model.spring_ke.numpy().astype(np.float64)
    np.add.at(ks, edges[:, 0], ke)
    np.add.at(ks, edges[:, 1], ke)
    return ka, ks


def coherent_count(stiffness, boundary) -> float:
    """The fixed ring's vertices whose reactions act together: all n_B of them without anchors; with
    anchors of share s = k_a / (k_a + sum k_ij) of the stiffness, those within the anchors' decay
    length, (1 - s) / (4 s), at least 1 (stiffness: vertex_stiffness())."""
    ka, ks = stiffness
    anchors = float(ka[boundary].sum())
    share = anchors / (anchors + float(ks[boundary].sum())) if len(boundary) else 1.0
    reach = (1.0 - share) / (4.0 * share) if share > 0.0 else math.inf
    return min(max(reach, 1.0), max(len(boundary), 1))


def force_error_estimate(energy: float, work: float, coherent: float) -> float:
    """The relative force error of holding the fixed ring: COHERENCE sqrt(n) S / (F delta), from the
    ring-motion kernel's S = sum f . u_J over the fixed ring [J], the probe's work F delta [J] and n
    (coherent_count)."""
    return COHERENCE * math.sqrt(coherent) * energy / work if work > 0.0 else 0.0


class AdaptivePalpation(Palpation):
    """A Palpation whose region is sized to `tol` [m] as it is pressed (``--rings auto --tol-mm``).

    It starts with `start_rings` rings at touch(); every `check_interval` [s] of simulated time
    it reads the ring motion and expands while the criterion above asks for it (up to
    `max_rings`). With the probe off, a region whose every free vertex is back within `tol` of
    rest is retired (its vertices put at rest, nothing integrated) when `retire` is set; the next
    press rebuilds it. ``rings_chosen`` and ``auto_reason`` say how large it grew and why.
    """

    protocol = "adaptive"

    def __init__(self, mesh, tissue=None, *, tol=1e-4, start_rings=1, max_rings=64, check_interval=0.01, retire=True,
                 force_tol=FORCE_TOL, margin=MARGIN, **kw):
        if "rings" in kw:
            raise TypeError("AdaptivePalpation sizes its own region: give tol (and start_rings), not rings")
        if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
            raise ValueError(f"tol must be a length > 0 [m], got {tol!r}")
        if not (isinstance(start_rings, (int, np.integer)) and 1 <= start_rings <= max_rings):
            raise ValueError(f"start_rings must be an int in 1..max_rings ({max_rings}), got {start_rings!r}")
        if not (math.isfinite(check_interval) and check_interval > 0):
            raise ValueError(f"check_interval must be > 0 [s], got {check_interval}")
        super().__init__(mesh, tissue, rings=int(start_rings), **kw)
        self.tol = float(tol)
        self.start_rings = int(start_rings)
        self.max_rings = int(max_rings)
        self.force_tol = float(force_tol)
        self.margin = float(margin)
        self.retire = bool(retire)
        self.check_steps = max(int(round(check_interval / self.dt)), 1)
        self.retired = False
        self.whole = False
        """True once the region covered its mesh component and every vertex of it was freed."""
        self.rings_chosen = 0
        """The most rings the region had since the last touch()."""
        self._reason = "not pressed yet"
        self._within = None
        self.events = []
        """dict(step, event ("+k" rings or "retired"), rings, estimate_mm) for each since touch(): the
        fixed ring's estimated displacement that made it grow, or the region's largest at retirement."""
        self._countdown = self.check_steps
        self._steps = 0
        self._boundary = 0
        self._coherent = 1.0
        self._force_over = False
        self._stiffness = vertex_stiffness(self.model)
        self._outer = 0
        self._motion_graphs = None
        slots = self.max_rings + 3  # the Jacobi estimate, each ring, the fixed ring's energy
        self._motion = wp.zeros(slots, dtype=wp.float32, device=self.device)
        if self._cpu:
            self._motion_host = self._motion.numpy()  # a view: the kernel writes it in place
        else:
            self._motion_pinned = wp.zeros(slots, dtype=wp.float32, device="cpu", pinned=True)
            self._motion_host = self._motion_pinned.numpy()
        self._zero_force = np.zeros(3, dtype=np.float32)
        self.press_log = []
        """Per press(): dict(rings, reason, events): the rings it grew to and why."""

    # -- the region ----------------------------------------------------------------------------
    def touch(self, vertex: int, depth: float | None = None) -> None:
        """Put the probe on `vertex` with a fresh region of `start_rings` rings (grown, with a sphere, from
        the patch it covers pressed `depth` [m]: Palpation.touch)."""
        self.rings = self.start_rings
        super().touch(vertex, depth)
        self.retired = False
        self.whole = False
        self._outer = self.region.outer_ring  # Region.outer_ring scans the ring sizes: kept here
        self.rings_chosen = self._outer
        self.auto_reason = "not pressed yet"
        self.events = []
        self._countdown = self.check_steps
        self._steps = 0
        self._motion_graphs = None
        self._force_over = False
        self._size_boundary()

    def expand(self, rings: int = 1) -> None:
        super().expand(rings)
        self._motion_graphs = None
        self._outer = self.region.outer_ring
        self._size_boundary()
        self.rings_chosen = max(self.rings_chosen, self._outer)

    @property
    def auto_reason(self) -> str:
        """Why the region has the size it has: the last check's verdict, in words (mm)."""
        if self._within is not None:
            n, est, ferr = self._within
            return (
                f"ring {n} (fixed) would move {est * 1e3:.3g} mm if freed (estimated; x{self.margin:g} <= tol "
                f"{self.tol * 1e3:g} mm) and the force error it implies is {ferr:.2%} (<= {0.5 * self.force_tol:.2%})"
            )
        return self._reason

    @auto_reason.setter
    def auto_reason(self, text: str) -> None:
        self._reason = text
        self._within = None

    def rebuild(self, rings: int, *, retire: bool | None = None) -> None:
        """Touch the same vertex again with a region of `rings` rings (and set `retire`)."""
        self.touch(self.vertex, self.patch_depth)
        if rings > self.region.outer_ring:
            self.expand(rings - self.region.outer_ring)
        if retire is not None:
            self.retire = bool(retire)

    def retire_region(self) -> None:
        """Put the region's vertices at rest in both states and integrate nothing until the next touch."""
        region = self.region
        clear_region(self.model, region, self.states)
        self.solver.set_region(region)
        self._graphs = None
        self._motion_graphs = None
        self.retired = True
        self.whole = False
        self._outer = 0

    # -- stepping ------------------------------------------------------------------------------
    def step(self) -> np.ndarray:
        """One step of dt (nothing once retired); every `check_steps` steps, the ring check."""
        if self.retired:
            return self._zero_force
        replays = self._graphs
        if replays is None:
            force = self._step_setup()
        else:  # Palpation.step written out: one Python call less per step
            replay = replays[self._cur]
            self._cur ^= self._parity
            replay()
            force = self._force_view
            w = self._force_words  # as Palpation.step
            if not -self._bound < w[0] + w[1] + w[2] < self._bound:
                self.diverged()
        self._countdown -= 1
        if self._countdown <= 0:
            self._countdown = self.check_steps
            self._steps += self.check_steps
            self._check()
        return force

    def ring_motion(self) -> np.ndarray:
        """[Jacobi estimate at the fixed ring [m], max displacement of ring 0, ring 1, ... [m], ...,
        sum of f . u_J over the fixed ring [J]] (host view)."""
        graphs = self._motion_graphs
        if graphs is None:
            graphs = self._capture_motion()
        graphs[self._cur]()
        return self._motion_host

    def _launch_motion(self, state):
        eval_region_motion(self.model, self.region, state, self._motion)
        if not self._cpu:
            wp.copy(self._motion_pinned, self._motion)

    def _capture_motion(self):
        self._launch_motion(self.state)  # loads the module outside any capture
        if not self.capture:
            def launcher(state):
                def launch():
                    self._launch_motion(state)
                    if not self._cpu:
                        wp.synchronize_device(self.device)

                return launch

            self._motion_graphs = [launcher(s) for s in self.states]
            return self._motion_graphs
        graphs = []
        for s in self.states:
            with wp.ScopedCapture(device=self.device, force_module_load=False) as cap:
                self._launch_motion(s)
            graphs.append(replayer(cap.graph, self.device))
        self._motion_graphs = graphs
        return graphs

    def estimate(self, motion=None):
        """(e_N [m], force error estimate (relative), lambda) of the current region and state."""
        m = self.ring_motion() if motion is None else motion
        n = self._outer
        if n == 0:  # the region is its seed alone: nothing fixed
            return 0.0, 0.0, 0.0
        est, lam = fixed_ring_estimate(float(m[0]), float(m[n]))
        fx, fy, fz = (float(c) for c in self._force_view)
        work = math.sqrt(fx * fx + fy * fy + fz * fz) * float(m[1])  # F delta: delta, ring 0's largest motion
        return est, force_error_estimate(float(m[-1]), work, self._coherent), lam

    def _size_boundary(self) -> None:
        b = self.region.boundary()
        self._boundary = len(b)
        self._coherent = coherent_count(self._stiffness, b)

    def _check(self) -> None:
        m = self.ring_motion()
        region = self.region
        n = self._outer
        if self._mode[0] == PROBE_OFF:
            moved = float(m[1 : n + 1].max(initial=0.0)) if n else float(m[1])
            if self.retire and moved <= self.tol:
                self._event("retired", n, moved)
                self.retire_region()
            return
        if self.whole:
            return
        est, ferr, lam = self.estimate(m)
        tol, half = self.tol, 0.5 * self.force_tol
        force_over = ferr > half
        if est * self.margin <= tol and (not force_over or not self._force_over):
            # the force estimate, a static identity, reads high in a press's first transient (the
            # ramp's start reaching the fixed ring): it grows the region when two checks in a row agree
            self._force_over = force_over
            self._within = (n, est, ferr)  # formatted only when auto_reason is read
            return
        if n >= self.max_rings:
            self.auto_reason = f"stopped at max_rings {self.max_rings}: ring {n} would move {est * 1e3:.3g} mm"
            return
        grow = 1
        if 0.0 < lam < 1.0 and math.isfinite(est) and est * self.margin > tol:
            # k more rings put the fixed ring at about e_N lambda^k: enough when that x margin <= tol (the
            # decay measured so far only slows outward, so this under-grows rather than over-grows)
            grow = min(max(int(math.ceil(math.log(tol / (self.margin * est)) / math.log(lam))), 1), 3)
        grow = min(grow, self.max_rings - n)
        size = region.vertex_count
        self.expand(grow)
        self._event(f"+{grow}", self.region.outer_ring, est)
        if self.region.vertex_count == size:
            self.free_outer_ring()
        else:
            self.auto_reason = f"grew to {rings_text(self.region.outer_ring)}: ring {n} would have moved {est * 1e3:.3g} mm"

    def free_outer_ring(self) -> None:
        """The region covers its mesh component: free its outer ring too (every vertex of the component
        free, the supports held: the global model there), and stop growing."""
        self.solver.set_global(anchors=True)
        self.plan_substeps()
        self._graphs = None
        self._motion_graphs = None
        self.whole = True
        self.max_rings = self._outer
        self.auto_reason = f"the region covers the mesh component ({self.region.vertex_count} vertices): all of it free"

    def _event(self, what, rings, length):
        estimate = round(length * 1e3, 6) if math.isfinite(length) else None
        self.events.append({"step": self._steps, "event": what, "rings": int(rings), "estimate_mm": estimate})

    # -- the press protocol --------------------------------------------------------------------
    def press(self, *args, **kw):
        """Palpation.press, on a region rebuilt from `start_rings` if the last one was retired."""
        return self._logged(super().press, args, kw)

    def press_force(self, *args, **kw):
        """Palpation.press_force, on a region rebuilt from `start_rings` if the last one was retired."""
        return self._logged(super().press_force, args, kw)

    def _logged(self, press, args, kw):
        if self.vertex < 0:
            raise RuntimeError("touch(vertex) first: the probe is on no vertex")
        if self.retired:
            self.touch(self.vertex, self.patch_depth)
        result = press(*args, **kw)
        self.press_log.append({"rings": int(self.rings_chosen), "reason": self.auto_reason, "events": list(self.events)})
        return result


def make_auto_palpation(mesh, tissue=None, *, integrator="explicit", dt=1e-3, device=None, tol=1e-4):
    """An AdaptivePalpation at tolerance `tol` [m]: the "auto" points of `almsdm evaluate`."""
    return AdaptivePalpation(mesh, tissue, tol=tol, integrator=integrator, dt=dt, device=device)


def hold_press(pal, depth, ramp, hold):
    """Drive the touched vertex to `depth` [m] over `ramp` [s], hold `hold` [s] (no release): (peak
    |force| [N], positions at the end of the hold [m], float64 [vertex_count, 3]).

    The press that sizes an adaptive region (its rings grow only while pressed: sweep_auto) and that
    the accuracy of a region is measured under. Raises SimulationDiverged."""
    schedule = PressSchedule.from_times(pal.dt, ramp, hold)
    total = schedule.release_step
    rest, n = pal.rest_position(), pal.inward_normal()
    mode, start = PROBE_DISPLACEMENT, rest
    if pal.probe_radius > 0:  # a sphere: its centre, touching the contact at rest, and the patch at this depth
        mode, start = PROBE_SPHERE, rest - n * pal.probe_radius
        if pal.region is not None and pal.patch_depth != depth:
            pal.touch(pal.vertex, depth)
    peak = 0.0
    for s in range(total):
        pal.set_probe(mode, start + n * depth * schedule.fraction(s))
        f = pal.step()
        peak = max(peak, float(np.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])))
    pal.check_finite(total)
    return peak, pal.positions()
