"""The ALMSDM solver: one step of the region's free vertices, explicit or implicit."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..kernels.integrate_explicit import integrate_explicit
from ..kernels.integrate_implicit import integrate_implicit

INTEGRATORS = ("explicit", "implicit")


class _CGScratch:
    def __init__(self, n, csr, device):
        self.dv = wp.zeros(n, dtype=wp.vec3, device=device)
        self.r = wp.zeros(n, dtype=wp.vec3, device=device)
        self.p = wp.zeros(n, dtype=wp.vec3, device=device)
        self.Ap = wp.zeros(n, dtype=wp.vec3, device=device)
        self.diag = wp.zeros(n, dtype=wp.mat33, device=device)
        self.diag_inv = wp.zeros(n, dtype=wp.mat33, device=device)
        self.csr_block = wp.zeros(max(csr, 1), dtype=wp.mat33, device=device)
        self.csr_local = wp.zeros(max(csr, 1), dtype=wp.int32, device=device)
        self.stats = wp.zeros(2, dtype=wp.float32, device=device)


class SolverALMSDM:
    """Steps the free vertices of a region (or of the whole mesh) under the ALMSDM's forces.

    integrator: "explicit" (semi-implicit Euler, the paper's) or "implicit" (backward Euler, CG).
    The free set comes from :meth:`set_region` (a Region: all but its fixed outer ring) or
    :meth:`set_global` (every vertex; with or without anchors).
    """

    def __init__(self, model, integrator: str = "explicit", *, cg_max_iterations: int = 200, cg_tolerance: float = 1e-6):
        if integrator not in INTEGRATORS:
            raise ValueError(f"unknown integrator {integrator!r} (known: {', '.join(INTEGRATORS)})")
        self.model = model
        self.integrator = integrator
        self.cg_max_iterations = int(cg_max_iterations)
        self.cg_tolerance = float(cg_tolerance)
        n = model.particle_count
        self._identity = wp.array(np.arange(n, dtype=np.int32), dtype=wp.int32, device=model.device)
        self._cg = _CGScratch(n, 2 * model.spring_count, model.device) if integrator == "implicit" else None
        self.free_vertex = None
        self.free_count = 0
        self.vertex_local = None
        self.anchor_scale = 1.0

    def set_region(self, region) -> None:
        """Integrate the region's vertices but its fixed outer ring (local order: ring after ring)."""
        self.free_vertex = region.region_vertex
        self.free_count = region.free_count
        self.vertex_local = region.vertex_local
        self.anchor_scale = 1.0
        self._reset_warm_start()

    def set_global(self, anchors: bool = True) -> None:
        """Integrate every vertex: the global anchored model, or without anchors the paper's free surface."""
        self.free_vertex = self._identity
        self.free_count = self.model.particle_count
        self.vertex_local = self._identity
        self.anchor_scale = 1.0 if anchors else 0.0
        self._reset_warm_start()

    def _reset_warm_start(self):
        if self._cg is not None:
            self._cg.dv.zero_()

    @property
    def cg_stats(self):
        """(iterations, relative residual) of the last implicit step (a device-to-host copy)."""
        if self._cg is None:
            return None
        it, res = self._cg.stats.numpy()
        return int(it), float(res)

    def step(self, state_in, state_out, control, dt: float) -> None:
        """Advance `state_in` by `dt` [s] into `state_out` (only the free vertices are written)."""
        if self.free_vertex is None:
            raise RuntimeError("the solver has no region: call set_region() or set_global() first")
        if self.free_count == 0:
            return
        if self.integrator == "explicit":
            integrate_explicit(self.model, self.free_vertex, self.free_count, self.anchor_scale, state_in, state_out, control, dt)
        else:
            integrate_implicit(
                self.model,
                (self.free_vertex, self.free_count, self.vertex_local),
                self.anchor_scale,
                state_in,
                state_out,
                control,
                dt,
                self._cg,
                self.cg_max_iterations,
                self.cg_tolerance,
            )
