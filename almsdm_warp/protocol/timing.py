"""The wall time of a step (DESIGN.md, speed): the median of blocks of steps, after a warm-up.

One timer for the command line's speed line, the evaluation and the benchmarks. The device is
synchronized (`sync`) before the clock is read; a Palpation's step already waits for its graph.
"""

from __future__ import annotations

import statistics
import time
from typing import NamedTuple


class StepTimes(NamedTuple):
    """Wall time per step [s] of each timed block, and the steps in a block."""

    per_step: list
    block_steps: int

    @property
    def median(self) -> float:
        """Median wall time of one step [s]."""
        return statistics.median(self.per_step)

    @property
    def steps(self) -> int:
        """Steps timed, all blocks together."""
        return len(self.per_step) * self.block_steps


def time_steps(step, blocks: int, steps: int | None = None, *, warmup: int = 5, budget_s: float = 1.0,
               max_steps: int = 5000, sync=None) -> StepTimes:
    """Time `blocks` blocks of `steps` calls of ``step()``, after `warmup` calls (which compile,
    load and capture what the first steps need).

    steps None: sized from the warm-up's time per call so that the blocks together take about
    `budget_s` [s] (at least 1 step a block, at most `max_steps`). sync: called before each read
    of the clock (``wp.synchronize_device``), or None."""
    sync = sync if sync is not None else _nothing
    t0 = time.perf_counter()
    for _ in range(warmup):
        step()
    sync()
    first = (time.perf_counter() - t0) / max(warmup, 1)
    if steps is None:
        steps = int(min(max(budget_s / blocks / max(first, 1e-9), 1), max_steps))
    per_step = []
    for _ in range(blocks):
        sync()
        t0 = time.perf_counter()
        for _ in range(steps):
            step()
        sync()
        per_step.append((time.perf_counter() - t0) / steps)
    return StepTimes(per_step, steps)


def time_palpation(pal, blocks: int, steps: int | None = None, *, read_force: bool = False, **kw) -> StepTimes:
    """:func:`time_steps` (its keywords) of ``pal.step()`` with the probe as it is set; read_force:
    read the feedback force every step, as a haptic loop does. Raises SimulationDiverged if the
    palpation ran away while timed."""
    if read_force:
        def step():
            return pal.step()[2]
    else:
        step = pal.step
    times = time_steps(step, blocks, steps, **kw)
    pal.check_finite(times.steps)
    return times


def _nothing():
    return None
