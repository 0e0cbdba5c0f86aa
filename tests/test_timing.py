"""The step timer: how many calls it makes and what it returns (never the times themselves)."""

from almsdm_warp.protocol.timing import time_steps


def test_blocks_of_steps_after_the_warm_up():
    calls, syncs = [], []
    times = time_steps(lambda: calls.append(1), 7, 3, warmup=4, sync=lambda: syncs.append(1))
    assert len(calls) == 4 + 7 * 3 and len(syncs) == 1 + 2 * 7
    assert len(times.per_step) == 7 and times.block_steps == 3 and times.steps == 21
    assert min(times.per_step) <= times.median <= max(times.per_step)


def test_blocks_sized_by_the_budget_stay_within_the_limits():
    calls = []
    times = time_steps(lambda: calls.append(1), 2, warmup=1, budget_s=1e9, max_steps=5)
    assert times.block_steps == 5 and len(calls) == 1 + 2 * 5
    assert time_steps(lambda: None, 2, warmup=1, budget_s=0.0).block_steps == 1
