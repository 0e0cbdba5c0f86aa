"""The paper's integrator: semi-implicit (symplectic) Euler, eqs. (3)-(8)."""

from __future__ import annotations

from ..kernels.explicit import batch as batch_kernels
from ..kernels.explicit import batch_fast
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
