"""The paper's integrator: semi-implicit (symplectic) Euler, eqs. (3)-(8)."""

from __future__ import annotations

from ..kernels.explicit import batch as batch_kernels
from ..kernels.explicit import batch_fast
from ..kernels.explicit.step import integrate_explicit
from ..kernels.region.volumes import RegionTets
from .base import SolverBase


class SolverExplicit(SolverBase):
    """Semi-implicit Euler: velocities from the forces at the start of the step, then positions.
    Stable below the critical step (Model.critical_dt)."""

    integrator = "explicit"
    conditionally_stable = True

    def __init__(self, model):
        super().__init__(model)
        self.tet_pass = "auto"
        """How a volumetric law's step goes over its tets: "tets" (each tet's volume and forces once a
        step, the region's tets listed once a free set: kernels/region/volumes.py), "vertices" (each
        vertex's tets, a tet at each of its corners: kernels/explicit/step.py), or "auto": tets on the
        CPU (one thread, where the repeated tets cost), vertices on CUDA (a thread a vertex there, and the
        listing is one thread)."""
        self.tet_listing = None
        """The RegionTets of the "tets" pass, made at its first step (Palpation.region_tets is their count)."""
        self._tets_built = False

    def set_free(self, *args, **kw) -> None:
        super().set_free(*args, **kw)
        self._tets_built = False

    def built_tets(self, q):
        """The region's RegionTets for the current free set, built at positions `q` (the state the next
        step starts from) once a free set; None where the step goes over each vertex's tets (tet_pass)."""
        m = self.model
        per_tet = m.device.is_cpu if self.tet_pass == "auto" else self.tet_pass == "tets"
        if not (m.law_entry.volumetric and per_tet):
            return None
        if self.tet_listing is None:
            self.tet_listing = RegionTets(m)
        if not self._tets_built:
            self.tet_listing.build(self.free_vertex, self.counts, self.vertex_local, q)
            self._tets_built = True
        return self.tet_listing

    def integrate(self, state_in, state_out, control, dt: float) -> None:
        threads = 1 if self.model.device.is_cpu else self.free_count
        integrate_explicit(self.model, self.free_vertex, self.counts, threads, self.anchor_scale, state_in, state_out, control, dt,
                           self.built_tets(state_in.particle_q))

    @staticmethod
    def press_batch(batch, total: int, steps_per_launch: int | None, on_launch) -> None:
        chunk = total if steps_per_launch is None else max(int(steps_per_launch), 1)
        for begin in range(0, total, chunk):
            count = min(chunk, total - begin)
            SolverExplicit.launch_batch_steps(batch, begin, count)
            if on_launch is not None:
                on_launch(count)

    @staticmethod
    def launch_batch_steps(batch, begin: int, count: int) -> None:
        """Launch steps begin..begin+count of the batch's press (no wait): many steps a launch, a block
        a palpation, with the batch's kernel ("fast" on CUDA where its regions fit, else "exact")."""
        if batch.kernel == "fast":
            batch_fast.press_batch_fast(batch, begin, count)
        else:
            batch_kernels.press_batch(batch, begin, count)
