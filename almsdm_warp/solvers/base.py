"""What every integrator of the ALMSDM shares: the model, the free vertices it steps, the step's checks."""

from __future__ import annotations

import numpy as np
import warp as wp


class SolverBase:
    """Steps the free vertices of a region (or of the whole mesh) under the ALMSDM's forces.

    The free set comes from :meth:`set_region` (a Region: all but its fixed outer ring) or
    :meth:`set_global` (every vertex; with or without anchors), less the model's supported vertices
    (`Model.support_mask`): those are listed after the free ones, so that their local index is >=
    `free_count` and every step treats them as it treats the fixed outer ring. A subclass names itself
    (`integrator`, its key in solvers.INTEGRATORS) and implements :meth:`integrate`.
    """

    integrator = ""
    """The integrator's name, its key in solvers.INTEGRATORS."""
    conditionally_stable = False
    """True where the step must stay under the critical step (Model.critical_dt) to be stable."""

    def __init__(self, model):
        self.model = model
        n = model.particle_count
        self._identity = wp.array(np.arange(n, dtype=np.int32), dtype=wp.int32, device=model.device)
        self.free_vertex = None
        self.free_count = 0
        self.vertex_local = None
        self.vertex_count = 0
        self.counts = wp.zeros(2, dtype=wp.int32, device=model.device)
        """[free_count, vertex_count] on the device (int32), as the explicit step reads them."""
        self.anchor_scale = 1.0

    def set_region(self, region) -> None:
        """Integrate the region's vertices but its fixed outer ring (local order: ring after ring)."""
        self.set_free(*self.without_supports(region.region_vertex, region.free_count, region.vertex_local, region.vertex_count), 1.0,
                      region.vertex_count)

    def set_global(self, anchors: bool = True) -> None:
        """Integrate every vertex: the global anchored model, or without anchors the paper's free surface."""
        n = self.model.particle_count
        self.set_free(*self.without_supports(self._identity, n, self._identity, n), 1.0 if anchors else 0.0, n)

    def set_free(self, free_vertex, free_count: int, vertex_local, anchor_scale: float, vertex_count: int | None = None) -> None:
        """Step the first `free_count` vertices of `free_vertex` (`vertex_local`: each mesh vertex's
        index in it), anchors scaled by `anchor_scale`; its first `vertex_count` (default: the free
        ones) are the region's, free and fixed ring, whose nodal pressures a volumetric law takes."""
        self.free_vertex, self.free_count, self.vertex_local = free_vertex, int(free_count), vertex_local
        self.vertex_count = self.free_count if vertex_count is None else int(vertex_count)
        self.counts.assign([self.free_count, self.vertex_count])
        self.anchor_scale = anchor_scale
        self.reset_warm_start()

    def without_supports(self, free_vertex, free_count: int, vertex_local, vertex_count: int):
        """(free_vertex, free_count, vertex_local) with the supported vertices moved from the free set to
        just after it (the others keep their order, the region's first `vertex_count` too); unchanged,
        with no copy, where none is free.

        Host work once per region (a copy of the region's arrays), never per step.
        """
        mask = getattr(self.model, "support_mask", None)
        if mask is None or not self.model.support_count or free_count == 0:
            return free_vertex, free_count, vertex_local
        region = free_vertex.numpy()[:vertex_count]
        verts = region[:free_count]
        held = mask[verts]
        if not held.any():
            return free_vertex, free_count, vertex_local
        order = np.concatenate([verts[~held], verts[held], region[free_count:]]).astype(np.int32)
        local = vertex_local.numpy().copy()
        local[order] = np.arange(len(order), dtype=np.int32)
        d = self.model.device
        return wp.array(order, dtype=wp.int32, device=d), int(free_count - held.sum()), wp.array(local, dtype=wp.int32, device=d)

    def reset_warm_start(self) -> None:
        """Forget what the last steps left to start the next from (the free set changed)."""

    @property
    def cg_stats(self):
        """(iterations, relative residual) of the last step's linear solve, or None (no solve)."""
        return None

    def step(self, state_in, state_out, control, dt: float) -> None:
        """Advance `state_in` by `dt` [s] into `state_out` (only the free vertices are written)."""
        if self.free_vertex is None:
            raise RuntimeError("the solver has no region: call set_region() or set_global() first")
        if self.free_count == 0:
            return
        self.integrate(state_in, state_out, control, dt)

    def integrate(self, state_in, state_out, control, dt: float) -> None:
        """One step of the free vertices (there are some): the integrator's own."""
        raise NotImplementedError

    @staticmethod
    def press_batch(batch, total: int, steps_per_launch: int | None, on_launch) -> None:
        """Launch `total` steps of the press `batch` (a BatchPalpation) has scheduled, from its rest
        states to its q_state / qd_state; on_launch(steps) after each launch (or group of steps)."""
        raise NotImplementedError

    @classmethod
    def has_batch(cls) -> bool:
        """Whether the integrator presses a batch too (overrides press_batch)."""
        return cls.press_batch is not SolverBase.press_batch
