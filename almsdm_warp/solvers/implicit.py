"""Backward Euler with conjugate gradients: stable at any step, where the explicit one diverges."""

from __future__ import annotations

import warp as wp

from ..kernels.implicit.batch import step_batch
from ..kernels.implicit.block_cg import CGScratch
from ..kernels.implicit.step import integrate_implicit
from .base import SolverBase


class SolverImplicit(SolverBase):
    """Backward Euler linearized once a step, (M + dt C + dt^2 K) dv = dt (f0 - dt K v0) (Baraff &
    Witkin; kernels/implicit/step.py), solved by block-Jacobi preconditioned CG (at most
    `cg_max_iterations`, to relative residual `cg_tolerance`), warm-started from the last step's dv."""

    integrator = "implicit"

    def __init__(self, model, *, cg_max_iterations: int = 200, cg_tolerance: float = 1e-6):
        super().__init__(model)
        self.cg_max_iterations = int(cg_max_iterations)
        self.cg_tolerance = float(cg_tolerance)
        self._cg = CGScratch(model.particle_count, 2 * model.spring_count, model.device)

    def reset_warm_start(self) -> None:
        self._cg.dv.zero_()

    @property
    def cg_stats(self):
        """(iterations, relative residual) of the last step (a device-to-host copy)."""
        it, res = self._cg.stats.numpy()
        return int(it), float(res)

    def integrate(self, state_in, state_out, control, dt: float) -> None:
        integrate_implicit(
            self.model,
            (self.free_vertex, self.free_count, self.vertex_local, self.vertex_count),
            self.anchor_scale,
            state_in,
            state_out,
            control,
            dt,
            self._cg,
            self.cg_max_iterations,
            self.cg_tolerance,
        )

    @staticmethod
    def press_batch(batch, total: int, steps_per_launch: int | None, on_launch) -> None:
        # two states (the fixed ring at rest in both) and CG scratch per palpation; one launch a step
        # (a thread a palpation); on_launch every 100 steps
        r = batch.regions
        other = (wp.clone(batch.q_state), wp.clone(batch.qd_state))
        scratch = CGScratch(r.vertex_capacity, r.entry_capacity, batch.device, rows=batch.batch_size)
        states = [(batch.q_state, batch.qd_state), other]
        for s in range(total):
            step_batch(batch, s, states[s % 2], states[1 - s % 2], scratch, batch.cg_max_iterations, batch.cg_tolerance)
            if on_launch is not None and (s % 100 == 99 or s == total - 1):
                on_launch(s % 100 + 1)
        if total % 2 == 1:  # the last step wrote the other state
            wp.copy(batch.q_state, other[0])
            wp.copy(batch.qd_state, other[1])
