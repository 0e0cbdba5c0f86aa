"""The "fast" batch kernel's owned-vertex variants, lean = 4..7 (see batch_fast.py)."""

import warp as wp

from .batch_explicit import _work_array, block_sync
from .batch_explicit_cuda import load_xyz, store_xyz
from .batch_fast_slots import greedy_slots
from .batch_fast_common import _shared_array, add_entry, add_entry16, EPS_LENGTH2, load2, load4, opaque, rsqrt_approx

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


def _press_kernel_owned(T, P, cv, cf, ce, cs, max_registers, w_qa, w_qb, cd, constants_in_registers, levels=False, pairs=False, unhoisted=False, tail=False, greedy=False):
    # the packed kernel (lean = 2) with fewer shared-memory accesses in the vertex phase: thread `lane`
    # owns free vertex `lane` for the whole launch, so its position and velocity live in registers
    # (only the owner writes them; the springs of phase A read the shared copy the owner stores),
    # its degree too (no CSR offsets read a step), and its CSR codes are stored transposed,
    # code[k * cf + i], so a warp's k-th codes are one conflict-free 64-byte read; lean = 5 also keeps
    # the owned vertex's constants (rest position, anchor terms, dt / m) in registers. Free vertices
    # beyond the block's threads (nf > T) take the shared path. lean = 6 also renumbers the force
    # slots by level (the k-th CSR entries of all free vertices, in vertex order, for k = 0, 1, ..),
    # so the lanes of a warp read the own springs of their k-th entries from consecutive slots (no
    # bank conflicts there; the mirror entries stay scattered). lean = 7: as 5, with two int16 codes
    # in each 4-byte word (entries 2p and 2p + 1 of a vertex: half the code reads). lean = 8: as 5,
    # with each spring's packed ends made opaque in the step loop, so that the compiler does not
    # hoist the end indices and their shared addresses out of it (~16 fewer live registers, for
    # 16 blocks of 64 threads an SM at 64 registers without spills). Same arithmetic,
    # same order as lean = 2 (the same bits).
    ld, st = load_xyz, store_xyz
    # lean 9-10: with the owned constants in registers, the shared copies only for vertices T and up
    sh = T if bool(constants_in_registers) and bool(tail) else 0
    w_rest = _work_array("orest4", wp.vec4, max(cf - sh, 1), True)
    w_kda = _work_array("okda", wp.float32, max(cf - sh, 1), True)
    w_dtm = _work_array("odtm", wp.float32, max(cf - sh, 1), True)
    w_off = _shared_array("ooff16", wp.int16, cf + 1)
    w_code = _shared_array("ocodet16", wp.int16, cd * cf if not pairs else 2)
    w_pair = _shared_array("ocodep32", wp.int32, (cd + 1) // 2 * cf if pairs else 1)
    w_f = _work_array("of4", wp.vec4, cs + 32 if bool(greedy) else cs, True)
    w_p64 = _work_array("op64", wp.float64, 8, True)
    w_pv = _work_array("opv4", wp.vec4, 3, True)
    gr = bool(greedy)  # lean = 11: slots spread over the banks (kernels/batch_fast_slots.py)
    cs2 = cs + 32 if gr else cs  # room for the slots it leaves empty
    limit = min(P * T, cs2)
    ncell = (cf // 8 + 1) * cd
    w_slot = _shared_array("oslot16", wp.int16, cs if levels or gr else 1)  # a spring's slot
    w_spring = _shared_array("ospring16", wp.int16, cs2 if levels or gr else 1)  # a slot's spring
    w_cell1 = _shared_array("ocell1", wp.int16, cs if gr else 1)
    w_cell2 = _shared_array("ocell2", wp.int16, cs if gr else 1)
    w_mask = _shared_array("omask", wp.int32, ncell if gr else 1)
    w_nsl = _shared_array("onsl", wp.int32, 1)
    PV = max((P - 1 if int(tail) == 1 else 0) if bool(tail) and P > 1 else P, 1)
    vec_i = wp.types.vector(length=PV, dtype=wp.int32)
    vec_f = wp.types.vector(length=PV, dtype=wp.float32)
    options = {"cuda_max_registers": int(max_registers)} if max_registers else {}
    regs = bool(constants_in_registers)
    lev = bool(levels)
    two = bool(pairs)
    late = bool(unhoisted)
    # lean = 9: the last spring slot of each thread (springs P - 1 x T and up: only the largest
    # regions have them) kept in shared memory, (ke, kd, l0, ends as an exact float), not registers;
    # lean = 10: all slots so (tail = 2)
    tl = bool(tail) and P > 1
    PR = (P - 1 if int(tail) == 1 else 0) if tl else P
    w_tail = _work_array("otail4", wp.vec4, max(cs - PR * T, 1) if tl else 1, True)

    @wp.kernel(module="unique", enable_backward=False, **options)
    def press_batch_explicit_owned(
        region_vertex: wp.array2d(dtype=wp.int32),
        region_count: wp.array(dtype=wp.int32),
        free_count: wp.array(dtype=wp.int32),
        local_offsets: wp.array2d(dtype=wp.int32),
        local_neighbour: wp.array2d(dtype=wp.int32),
        local_edge: wp.array2d(dtype=wp.int32),
        local_owner: wp.array2d(dtype=wp.int32),
        local_spring: wp.array2d(dtype=wp.int32),
        spring_entry: wp.array2d(dtype=wp.int32),
        spring_count: wp.array(dtype=wp.int32),
        q_rest: wp.array(dtype=wp.vec3),
        particle_mass: wp.array(dtype=wp.float32),
        anchor_ke: wp.array(dtype=wp.float32),
        anchor_kd: wp.array(dtype=wp.float32),
        anchor_scale: float,
        spring_ke: wp.array(dtype=wp.float32),
        spring_kd: wp.array(dtype=wp.float32),
        spring_rest_length: wp.array(dtype=wp.float32),
        press_direction: wp.array(dtype=wp.vec3d),
        depth: wp.float64,
        ramp_steps: int,
        press_steps: int,
        dt: float,
        step_begin: int,
        step_count: int,
        q_state: wp.array2d(dtype=wp.vec3),
        qd_state: wp.array2d(dtype=wp.vec3),
        peak_force: wp.array(dtype=wp.float64),
        peak_reaction: wp.array(dtype=wp.vec3),
        hold_reaction: wp.array(dtype=wp.vec3),
        scratch: wp.array(dtype=wp.vec4),
    ):
        tid = wp.tid()
        b = tid // T
        lane = tid - b * T
        n = region_count[b]
        nf = free_count[b]
        ns = spring_count[b]
        qa = w_qa(scratch, 0)
        qb = w_qb()
        rest4 = w_rest(scratch, 0)
        kda = w_kda(particle_mass, 0)
        dtm = w_dtm(particle_mass, 0)
        off = w_off()
        code = w_code()
        pair = w_pair()
        fe = w_f(scratch, 0)
        p64 = w_p64(peak_force, 0)
        pv = w_pv(scratch, 0)
        for i in range(lane, n, T):
            x = q_state[b, i]
            u = qd_state[b, i]
            qa[i] = wp.vec4(x[0], x[1], x[2], u[0])
            qb[i] = wp.vec2(u[1], u[2])
        for i in range(lane, nf, T):
            v = region_vertex[b, i]
            x0 = q_rest[v]
            if i >= sh:
                rest4[i - sh] = wp.vec4(x0[0], x0[1], x0[2], -anchor_scale * anchor_ke[v])
                kda[i - sh] = -anchor_scale * anchor_kd[v]
                dtm[i - sh] = dt / particle_mass[v]
            k0 = local_offsets[b, i]
            k1 = local_offsets[b, i + 1]
            if wp.static(two):
                for p in range((k1 - k0 + 1) // 2):
                    c0 = local_spring[b, k0 + 2 * p]
                    c1 = int(0)
                    if k0 + 2 * p + 1 < k1:
                        c1 = local_spring[b, k0 + 2 * p + 1]
                    pair[p * cf + i] = (c0 & 0xFFFF) | (c1 << 16)
            else:
                for k in range(k0, k1):
                    code[(k - k0) * cf + i] = wp.int16(local_spring[b, k])
        for i in range(lane, nf + 1, T):
            off[i] = wp.int16(local_offsets[b, i])
        slot_of = w_slot()
        spring_at = w_spring()
        if wp.static(lev):
            # force slots by level: one lane numbers the own entries k = 0, 1, .. of all free vertices
            block_sync()
            if lane == 0:
                count = int(0)
                for k in range(cd):
                    for i in range(nf):
                        if k < wp.int32(off[i + 1]) - wp.int32(off[i]):
                            cc = wp.int32(code[k * cf + i])
                            if cc > 0:
                                slot_of[cc - 1] = wp.int16(count)
                                spring_at[count] = wp.int16(cc - 1)
                                count += 1
            block_sync()
            for i in range(lane, nf, T):
                for k in range(wp.int32(off[i + 1]) - wp.int32(off[i])):
                    cc = wp.int32(code[k * cf + i])
                    if cc > 0:
                        code[k * cf + i] = wp.int16(wp.int32(slot_of[cc - 1]) + 1)
                    else:
                        code[k * cf + i] = wp.int16(-wp.int32(slot_of[-cc - 1]) - 1)
        nsl = ns  # the spring slots' end
        if wp.static(gr):
            cell1 = w_cell1()
            cell2 = w_cell2()
            mask = w_mask()
            nslot = w_nsl()
            for xx in range(lane, cs2, T):
                spring_at[xx] = wp.int16(-1)
            for xx in range(lane, cs, T):
                cell1[xx] = wp.int16(-1)
                cell2[xx] = wp.int16(-1)
            for xx in range(lane, ncell, T):
                mask[xx] = 0
            block_sync()
            if lane == 0:
                nslot[0] = greedy_slots(code, off, slot_of, spring_at, cell1, cell2, mask, nf, ns, cf, cd, limit)
            block_sync()
            for i in range(lane, nf, T):
                for k in range(wp.int32(off[i + 1]) - wp.int32(off[i])):
                    cc = wp.int32(code[k * cf + i])
                    if cc > 0:
                        code[k * cf + i] = wp.int16(wp.int32(slot_of[cc - 1]) + 1)
                    else:
                        code[k * cf + i] = wp.int16(-wp.int32(slot_of[-cc - 1]) - 1)
            nsl = nslot[0]
        # the owned vertex (lane < nf): state, degree and (lean = 5) constants in registers
        own = lane < nf
        ow = wp.min(lane, wp.max(nf - 1, 0))
        xo = q_state[b, ow]
        uo = qd_state[b, ow]
        deg = int(0)
        if own:
            deg = local_offsets[b, lane + 1] - local_offsets[b, lane]
        vo = region_vertex[b, ow]
        ro = q_rest[vo]
        kao = -anchor_scale * anchor_ke[vo]
        kdo = -anchor_scale * anchor_kd[vo]
        dto = dt / particle_mass[vo]
        ends = vec_i(0)
        ke = vec_f(0.0)
        kd = vec_f(0.0)
        l0 = vec_f(0.0)
        for m in range(PR):
            sp = lane + m * T
            if sp < nsl:
                k = int(0)
                if wp.static(lev or gr):
                    k = wp.int32(spring_at[sp])  # an empty slot (lean 11): vertex 0 to itself, no force
                    if k >= 0:
                        k = spring_entry[b, k]
                else:
                    k = spring_entry[b, sp]
                if k >= 0:
                    ends[m] = local_owner[b, k] | (local_neighbour[b, k] << 16)
                    e = local_edge[b, k]
                    ke[m] = spring_ke[e]
                    kd[m] = spring_kd[e]
                    l0[m] = spring_rest_length[e]
        tail4 = w_tail(scratch, 0)
        for m in range(PR, P):
            sp = lane + m * T
            if sp < ns:
                k = spring_entry[b, sp]
                e = local_edge[b, k]
                tail4[sp - PR * T] = wp.vec4(spring_ke[e], spring_kd[e], spring_rest_length[e], float(local_owner[b, k] | (local_neighbour[b, k] << 16)))
        if lane == 0:
            rest0 = wp.vec3d(q_rest[region_vertex[b, 0]])
            dd = press_direction[b] * depth
            for a in range(3):
                p64[a] = rest0[a]
                p64[3 + a] = dd[a]
            p64[6] = wp.float64(1.0) / wp.float64(ramp_steps)
            p64[7] = peak_force[b]  # this kernel keeps the squared magnitude there
            t = wp.vec3(rest0 + dd)
            pv[0] = wp.vec4(peak_reaction[b][0], peak_reaction[b][1], peak_reaction[b][2], 0.0)
            pv[1] = wp.vec4(t[0], t[1], t[2], 1.0 / dt)
            pv[2] = wp.vec4(hold_reaction[b][0], hold_reaction[b][1], hold_reaction[b][2], 0.0)
        block_sync()
        for s in range(step_begin, step_begin + step_count):
            # (A) each spring: elastic force along the edge, eqs. (4)-(5), and damping along it, eq. (6)
            nsx = nsl
            if wp.static(late):
                nsx = opaque(ns)  # each slot's `sp < ns` recomputed a step, not held (spilled) as a flag
            for m in range(PR):
                sp = lane + m * T
                if sp < nsx:
                    e2 = ends[m]
                    if wp.static(late and not tl):
                        e2 = opaque(e2)
                    i = e2 & 0xFFFF
                    j = e2 >> 16
                    ai = load4(qa, i)
                    aj = load4(qa, j)
                    bi = load2(qb, i)
                    bj = load2(qb, j)
                    r = wp.vec3(aj[0] - ai[0], aj[1] - ai[1], aj[2] - ai[2])
                    l2 = wp.dot(r, r)
                    c = wp.vec3(0.0)
                    if l2 > EPS_LENGTH2:
                        inv_l = rsqrt_approx(l2)
                        dv = wp.vec3(aj[3] - ai[3], bj[0] - bi[0], bj[1] - bi[1])
                        sf = ke[m] * (l2 * inv_l - l0[m]) + kd[m] * wp.dot(dv, r) * inv_l
                        c = (sf * inv_l) * r
                    st(fe, sp, c)
            for m in range(PR, P):
                sp = lane + m * T
                if sp < nsx:
                    t4 = load4(tail4, sp - PR * T)
                    e2 = int(t4[3])
                    i = e2 & 0xFFFF
                    j = e2 >> 16
                    ai = load4(qa, i)
                    aj = load4(qa, j)
                    bi = load2(qb, i)
                    bj = load2(qb, j)
                    r = wp.vec3(aj[0] - ai[0], aj[1] - ai[1], aj[2] - ai[2])
                    l2 = wp.dot(r, r)
                    c = wp.vec3(0.0)
                    if l2 > EPS_LENGTH2:
                        inv_l = rsqrt_approx(l2)
                        dv = wp.vec3(aj[3] - ai[3], bj[0] - bi[0], bj[1] - bi[1])
                        sf = t4[0] * (l2 * inv_l - t4[2]) + t4[1] * wp.dot(dv, r) * inv_l
                        c = (sf * inv_l) * r
                    st(fe, sp, c)
            block_sync()
            # (B) each free vertex: anchor, eq. (3), then its springs in mesh CSR order; the owned
            # vertex first (registers), then any beyond the block's threads (shared memory)
            if own:
                i = lane
                f = wp.vec3(0.0)
                if wp.static(regs):
                    f = kao * (xo - ro) + kdo * uo
                else:
                    c4 = load4(rest4, i)
                    f = c4[3] * (xo - wp.vec3(c4[0], c4[1], c4[2])) + kda[i] * uo
                if wp.static(two):
                    for p in range((deg + 1) >> 1):
                        w = pair[p * cf + i]
                        f = add_entry(f, fe, (w << 16) >> 16)
                        if 2 * p + 1 < deg:
                            f = add_entry(f, fe, w >> 16)
                else:
                    for k in range(deg):
                        f = add_entry16(f, fe, code, k * cf + i)
                if i == 0 and s < press_steps:
                    # the feedback force, then displacement control (lane 0; its state in shared memory)
                    fx = wp.float64(f[0])
                    fy = wp.float64(f[1])
                    fz = wp.float64(f[2])
                    mag2 = fx * fx + fy * fy + fz * fz
                    if mag2 > p64[7]:
                        p64[7] = mag2
                        st(pv, 0, f)
                    if s == press_steps - 1:
                        st(pv, 2, f)
                    o = int(0)
                    if wp.static(late):
                        o = opaque(0)  # the probe's constants read each step (lane 0), not held in registers
                    tf = load4(pv, o + 1)
                    target = wp.vec3(tf[0], tf[1], tf[2])
                    if s < ramp_steps:
                        r0 = wp.vec3d(p64[o], p64[o + 1], p64[o + 2])
                        d0 = wp.vec3d(p64[o + 3], p64[o + 4], p64[o + 5])
                        target = wp.vec3(r0 + d0 * (wp.float64(s + 1) * p64[o + 6]))
                    uo = (target - xo) * tf[3]
                    xo = target
                else:
                    # m u'' + d u' + k u = F, eq. (3), semi-implicit Euler: velocity first, then position
                    if wp.static(regs):
                        uo = uo + f * dto
                    else:
                        uo = uo + f * dtm[i]
                    xo = xo + dt * uo
                qa[i] = wp.vec4(xo[0], xo[1], xo[2], uo[0])
                qb[i] = wp.vec2(uo[1], uo[2])
            for i in range(lane + T, nf, T):
                av = load4(qa, i)
                bv = load2(qb, i)
                x = wp.vec3(av[0], av[1], av[2])
                u = wp.vec3(av[3], bv[0], bv[1])
                c4 = load4(rest4, i - sh)
                f = c4[3] * (x - wp.vec3(c4[0], c4[1], c4[2])) + kda[i - sh] * u
                d = wp.int32(off[i + 1]) - wp.int32(off[i])
                if wp.static(two):
                    for p in range((d + 1) >> 1):
                        w = pair[p * cf + i]
                        f = add_entry(f, fe, (w << 16) >> 16)
                        if 2 * p + 1 < d:
                            f = add_entry(f, fe, w >> 16)
                else:
                    for k in range(d):
                        f = add_entry16(f, fe, code, k * cf + i)
                u1 = u + f * dtm[i - sh]
                x1 = x + dt * u1
                qa[i] = wp.vec4(x1[0], x1[1], x1[2], u1[0])
                qb[i] = wp.vec2(u1[1], u1[2])
            block_sync()
        for i in range(lane, n, T):
            av = load4(qa, i)
            bv = load2(qb, i)
            q_state[b, i] = wp.vec3(av[0], av[1], av[2])
            qd_state[b, i] = wp.vec3(av[3], bv[0], bv[1])
        if lane == 0:
            peak_force[b] = p64[7]
            peak_reaction[b] = ld(pv, 0)
            hold_reaction[b] = ld(pv, 2)

    return press_batch_explicit_owned
