"""The paper's integrator: semi-implicit (symplectic) Euler, eqs. (3)-(8)."""

from __future__ import annotations

from ..kernels.explicit.step import integrate_explicit
from .base import SolverBase


class SolverExplicit(SolverBase):
    """Semi-implicit Euler: velocities from the forces at the start of the step, then positions.
    Stable below the critical step (Model.critical_dt)."""

    integrator = "explicit"
    conditionally_stable = True

    def integrate(self, state_in, state_out, control, dt: float) -> None:
        threads = 1 if self.model.device.is_cpu else self.free_count
        integrate_explicit(self.model, self.free_vertex, self.counts, threads, self.anchor_scale, state_in, state_out, control, dt)
