"""Force slots of the "fast" kernel's lean = 11 (kernels/batch_fast_owned.py): springs numbered so
that a warp's reads of spring forces in the vertex phase spread over the shared-memory banks.

In the vertex phase the lanes of a quarter-warp (8 free vertices) read the forces of their k-th
springs, 16 bytes each: one wavefront if their slots fall in 8 different 16-byte columns (slot mod
8), more if two of them share a column. Springs numbered in order (lean 5) collide there ~43
wavefronts a region-step on the stomach mesh (of ~81; a model of the banks that gives ncu's 74
conflicts a region-step). Here one lane gives each spring, in order, the lowest free slot of a
column that no other spring read in the same (quarter-warp, k) cells uses yet (8 x row + column:
slots stay close to the spring order, so the spring phase's reads keep their pattern); the model
predicts 50 wavefronts (-31 of ~250 a region-step) and a few slots left empty. Only the slots move:
the sums keep their CSR order, the same bits as lean 2.
"""

import warp as wp

wp.set_module_options({"enable_backward": False})

vec8i = wp.types.vector(length=8, dtype=wp.int32)


@wp.func
def greedy_slots(
    code: wp.array(dtype=wp.int16), off: wp.array(dtype=wp.int16), slot_of: wp.array(dtype=wp.int16),
    spring_at: wp.array(dtype=wp.int16), cell1: wp.array(dtype=wp.int16), cell2: wp.array(dtype=wp.int16),
    mask: wp.array(dtype=wp.int32), nf: int, ns: int, cf: int, cd: int, limit: int,
) -> int:
    # one lane: cells of each spring (quarter-warp of a free end, CSR level there), then the slots;
    # spring_at[] is -1 and cell1/2[] -1 and mask[] 0 on entry. Returns the slots' end (highest + 1).
    for i in range(nf):
        for k in range(wp.int32(off[i + 1]) - wp.int32(off[i])):
            e = wp.abs(wp.int32(code[k * cf + i])) - 1
            cell = (i // 8) * cd + k
            if wp.int32(cell1[e]) < 0:
                cell1[e] = wp.int16(cell)
            else:
                cell2[e] = wp.int16(cell)
    nxt = vec8i(0)
    top = int(0)
    for s in range(ns):
        a = wp.int32(cell1[s])
        b = wp.int32(cell2[s])
        bad = int(0)
        if a >= 0:
            bad = mask[a]
        if b >= 0:
            bad = bad | mask[b]
        best = int(-1)
        slot = int(1 << 30)
        for c in range(8):
            t = 8 * nxt[c] + c
            if ((bad >> c) & 1) == 0 and t < limit and t < slot:
                best = c
                slot = t
        if best < 0:  # every column taken in these cells: the lowest free slot, a conflict
            for c in range(8):
                t = 8 * nxt[c] + c
                if t < limit and t < slot:
                    best = c
                    slot = t
        nxt[best] = nxt[best] + 1
        slot_of[s] = wp.int16(slot)
        spring_at[slot] = wp.int16(s)
        if a >= 0:
            mask[a] = mask[a] | (1 << best)
        if b >= 0:
            mask[b] = mask[b] | (1 << best)
        top = wp.max(top, slot + 1)
    return top
