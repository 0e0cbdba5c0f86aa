"""lean = 11's force-slot numbering (kernels/batch_fast_slots.py), run on the CPU against the
uniform numbering it replaces: every spring gets its own slot below the limit, and a quarter-warp's
reads of its springs' forces at one CSR level fall in the same 16-byte bank column less often."""

import numpy as np
import warp as wp

from almsdm_warp.batch.batch_palpation import BatchPalpation
from almsdm_warp.kernels.batch_fast_slots import greedy_slots
from conftest import SCENES, load_cached

CF, CD, CS = 128, 16, 512


@wp.kernel
def _slots(code: wp.array2d(dtype=wp.int16), off: wp.array2d(dtype=wp.int16), slot_of: wp.array2d(dtype=wp.int16),
           spring_at: wp.array2d(dtype=wp.int16), cell1: wp.array2d(dtype=wp.int16), cell2: wp.array2d(dtype=wp.int16),
           mask: wp.array2d(dtype=wp.int32), nf: wp.array(dtype=wp.int32), ns: wp.array(dtype=wp.int32), top: wp.array(dtype=wp.int32)):
    b = wp.tid()
    top[b] = greedy_slots(code[b], off[b], slot_of[b], spring_at[b], cell1[b], cell2[b], mask[b], nf[b], ns[b], CF, CD, CS)


def _collisions(codes, slot_of):
    # (quarter-warp, level) cells: reads beyond the first in a 16-byte column, summed
    n = 0
    for k in range(CD):
        for q in range(0, CF, 8):
            cols = [int(slot_of[abs(c) - 1]) % 8 for c in codes[k, q : q + 8] if c != 0]
            n += len(cols) - len(set(cols))
    return n


def test_greedy_slots_unique_bounded_fewer_collisions():
    bp = BatchPalpation(load_cached(SCENES / "stomach.obj"), rings=4, device="cpu").touch(list(range(0, 1002, 50)))
    r = bp.regions
    offs, ls = r.local_offsets.numpy(), r.local_spring.numpy()
    nfs, nss = r.free_count.numpy(), r.spring_count.numpy()
    B = len(nfs)
    code = np.zeros((B, CD * CF), np.int16)
    off = np.zeros((B, CF + 1), np.int16)
    for b in range(B):
        off[b, : nfs[b] + 1] = offs[b, : nfs[b] + 1]
        for i in range(nfs[b]):
            for k in range(offs[b, i + 1] - offs[b, i]):
                code[b, k * CF + i] = ls[b, offs[b, i] + k]
    arr = lambda a, t: wp.array(a, dtype=t, device="cpu")
    slot_of, spring_at = arr(np.zeros((B, CS), np.int16), wp.int16), arr(-np.ones((B, CS), np.int16), wp.int16)
    cell1, cell2 = arr(-np.ones((B, CS), np.int16), wp.int16), arr(-np.ones((B, CS), np.int16), wp.int16)
    mask, top = arr(np.zeros((B, (CF // 8 + 1) * CD), np.int32), wp.int32), wp.zeros(B, dtype=wp.int32, device="cpu")
    wp.launch(_slots, B, [arr(code, wp.int16), arr(off, wp.int16), slot_of, spring_at, cell1, cell2, mask, arr(nfs, wp.int32), arr(nss, wp.int32), top], device="cpu")
    so, sa, tops = slot_of.numpy(), spring_at.numpy(), top.numpy()
    before = after = 0
    for b in range(B):
        ns = nss[b]
        s = so[b, :ns].astype(int)
        assert len(set(s)) == ns and s.max() + 1 == tops[b] and tops[b] <= ns + 32
        np.testing.assert_array_equal(sa[b, s], np.arange(ns))
        codes = code[b].reshape(CD, CF)
        before += _collisions(codes, np.arange(ns))
        after += _collisions(codes, s)
    print(f"column collisions: {before} uniform, {after} greedy")
    assert after < 0.5 * before, (before, after)
