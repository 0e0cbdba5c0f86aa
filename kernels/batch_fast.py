"""The "fast" batch kernel on CUDA (CUDA's default): its builder, and the lean = 0/1 variants.

See press_kernel_fast; the packed, slots and owned variants are in batch_fast_variants.py and
batch_fast_owned.py, the shared helpers in batch_fast_common.py.
"""

import functools

import warp as wp

from .batch_explicit import _work_array, block_sync
from .batch_explicit_cuda import load_xyz, store_xyz
from .batch_fast_common import _shared_array, add_entry, add_entry16, EPS_LENGTH2, load4, rsqrt_approx
from .batch_fast_owned import _press_kernel_owned
from .batch_fast_variants import _press_kernel_packed, _press_kernel_slots

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@functools.cache
def press_kernel_fast(threads: int, per_thread: int, vertex_capacity: int, free_capacity: int, entry_capacity: int, spring_capacity: int, max_registers: int = 0, lean: int = 2, max_degree: int = 16):
    """The "fast" kernel for blocks of `threads` threads with `per_thread` springs each, regions of up
    to `vertex_capacity` vertices, `free_capacity` free ones, `entry_capacity` CSR entries and
    `spring_capacity` springs (compile-time sizes); `max_registers` > 0 caps registers per thread.
    lean: the probe's constants and running peak in shared memory rather than registers (only lane 0
    reads them), CSR offsets and entry codes as int16 (less shared memory a block); lean = 2: also
    a vertex's position and velocity in 24 bytes (x, y, z, vx | vy, vz: one 16- and one 8-byte
    load) rather than two 16-byte slots (fewer shared-memory wavefronts); lean = 3: also a force
    slot per CSR entry rather than per spring (the mirror entry's written negated); lean = 4: as 2,
    with each thread owning a free vertex (its position, velocity and degree in registers across
    steps) and CSR codes stored transposed (`max_degree` rows); lean = 5: as 4, with the owned
    vertex's constants in registers too; lean = 6: as 5, with the force slots numbered by CSR level
    (conflict-free reads of a warp's own springs in the sums); lean = 7: as 5, with the codes in
    pairs (one 4-byte read for two entries); lean = 8: as 5, the springs' end indices not hoisted
    out of the step loop (fewer live registers); lean = 9: as 5, each thread's last spring slot in shared memory;
    lean = 10: as 5, all spring constants in shared memory (fewer registers); lean = 11: as 5, force slots spread over
    the shared-memory banks (kernels/batch_fast_slots.py)."""
    if int(lean) >= 4:
        w_qa = _work_array("oqa4", wp.vec4, int(vertex_capacity), True)
        w_qb = _shared_array("oqb2", wp.vec2, int(vertex_capacity))
        return _press_kernel_owned(
            int(threads), int(per_thread), int(vertex_capacity), int(free_capacity), int(entry_capacity), int(spring_capacity),
            max_registers, w_qa, w_qb, max(int(max_degree), 1), int(lean) >= 5, int(lean) == 6, int(lean) == 7, int(lean) == 8, {9: 1, 10: 2}.get(int(lean), 0), int(lean) == 11,
        )
    if lean:
        return _press_kernel_lean(threads, per_thread, vertex_capacity, free_capacity, entry_capacity, spring_capacity, max_registers, int(lean) if int(lean) >= 2 else 0)
    T, P, cv, cf, ce, cs = int(threads), int(per_thread), int(vertex_capacity), int(free_capacity), int(entry_capacity), int(spring_capacity)
    ld, st = load_xyz, store_xyz
    w_q = _work_array("fq4", wp.vec4, cv, True)
    w_qd = _work_array("fqd4", wp.vec4, cv, True)
    w_rest = _work_array("frest4", wp.vec4, cf, True)  # rest position, -anchor_scale * k_i
    w_kda = _work_array("fkda", wp.float32, cf, True)  # -anchor_scale * d_i
    w_dtm = _work_array("fdtm", wp.float32, cf, True)  # dt / m_i
    w_off = _work_array("foff", wp.int32, cf + 1, True)
    w_code = _work_array("fcode", wp.int32, ce, True)
    w_f = _work_array("ff4", wp.vec4, cs, True)
    vec_i = wp.types.vector(length=P, dtype=wp.int32)
    vec_f = wp.types.vector(length=P, dtype=wp.float32)
    options = {"cuda_max_registers": int(max_registers)} if max_registers else {}

    @wp.kernel(module="unique", enable_backward=False, **options)
    def press_batch_explicit_fast(
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
        ne = local_offsets[b, nf]
        ns = spring_count[b]
        q = w_q(scratch, 0)
        qd = w_qd(scratch, 0)
        rest4 = w_rest(scratch, 0)
        kda = w_kda(particle_mass, 0)
        dtm = w_dtm(particle_mass, 0)
        off = w_off(region_count, 0)
        code = w_code(region_count, 0)
        fe = w_f(scratch, 0)
        for i in range(lane, n, T):
            st(q, i, q_state[b, i])
            st(qd, i, qd_state[b, i])
        for i in range(lane, nf, T):
            v = region_vertex[b, i]
            x0 = q_rest[v]
            rest4[i] = wp.vec4(x0[0], x0[1], x0[2], -anchor_scale * anchor_ke[v])
            kda[i] = -anchor_scale * anchor_kd[v]
            dtm[i] = dt / particle_mass[v]
        for i in range(lane, nf + 1, T):
            off[i] = local_offsets[b, i]
        for k in range(lane, ne, T):
            code[k] = local_spring[b, k]
        # this lane's springs: both local ends in one register (16 bits each), k_ij, d_ij, rest length
        ends = vec_i(0)
        ke = vec_f(0.0)
        kd = vec_f(0.0)
        l0 = vec_f(0.0)
        for m in range(P):
            sp = lane + m * T
            if sp < ns:
                k = spring_entry[b, sp]
                ends[m] = local_owner[b, k] | (local_neighbour[b, k] << 16)
                e = local_edge[b, k]
                ke[m] = spring_ke[e]
                kd[m] = spring_kd[e]
                l0[m] = spring_rest_length[e]
        rest0 = wp.vec3d(q_rest[region_vertex[b, 0]])
        dd = press_direction[b] * depth
        target_full = wp.vec3(rest0 + dd)
        inv_ramp = wp.float64(1.0) / wp.float64(ramp_steps)
        inv_dt = 1.0 / dt
        peak2 = peak_force[b]  # this kernel keeps the squared magnitude there
        peak_f = peak_reaction[b]
        block_sync()
        for s in range(step_begin, step_begin + step_count):
            # (A) each spring: elastic force along the edge, eqs. (4)-(5), and damping along it, eq. (6)
            for m in range(P):
                sp = lane + m * T
                if sp < ns:
                    i = ends[m] & 0xFFFF
                    j = ends[m] >> 16
                    x = ld(q, i)
                    r = ld(q, j) - x
                    l2 = wp.dot(r, r)
                    c = wp.vec3(0.0)
                    if l2 > EPS_LENGTH2:
                        inv_l = rsqrt_approx(l2)
                        sf = ke[m] * (l2 * inv_l - l0[m]) + kd[m] * wp.dot(ld(qd, j) - ld(qd, i), r) * inv_l
                        c = (sf * inv_l) * r
                    st(fe, sp, c)
            block_sync()
            # (B) each free vertex: anchor, eq. (3), then its springs in mesh CSR order
            for i in range(lane, nf, T):
                x = ld(q, i)
                u = ld(qd, i)
                c4 = load4(rest4, i)
                f = c4[3] * (x - wp.vec3(c4[0], c4[1], c4[2])) + kda[i] * u
                for k in range(off[i], off[i + 1]):
                    f = add_entry(f, fe, code[k])
                if i == 0 and s < press_steps:
                    # the feedback force, then displacement control (float64 products, no sqrt or division)
                    fx = wp.float64(f[0])
                    fy = wp.float64(f[1])
                    fz = wp.float64(f[2])
                    mag2 = fx * fx + fy * fy + fz * fz
                    if mag2 > peak2:
                        peak2 = mag2
                        peak_f = f
                    if s == press_steps - 1:
                        hold_reaction[b] = f
                    target = target_full
                    if s < ramp_steps:
                        target = wp.vec3(rest0 + dd * (wp.float64(s + 1) * inv_ramp))
                    st(q, i, target)
                    st(qd, i, (target - x) * inv_dt)
                else:
                    # m u'' + d u' + k u = F, eq. (3), semi-implicit Euler: velocity first, then position
                    u1 = u + f * dtm[i]
                    st(q, i, x + dt * u1)
                    st(qd, i, u1)
            block_sync()
        for i in range(lane, n, T):
            q_state[b, i] = ld(q, i)
            qd_state[b, i] = ld(qd, i)
        if lane == 0:
            peak_force[b] = peak2
            peak_reaction[b] = peak_f

    return press_batch_explicit_fast


@functools.cache
def _press_kernel_lean(threads, per_thread, vertex_capacity, free_capacity, entry_capacity, spring_capacity, max_registers, packed=False):
    T, P, cv, cf, ce, cs = int(threads), int(per_thread), int(vertex_capacity), int(free_capacity), int(entry_capacity), int(spring_capacity)
    ld, st = load_xyz, store_xyz
    if packed:
        w_qa = _work_array("pqa4", wp.vec4, cv, True)  # x, y, z, vx
        w_qb = _shared_array("pqb2", wp.vec2, cv)  # vy, vz
        make = _press_kernel_slots if packed == 3 else _press_kernel_packed
        return make(T, P, cv, cf, ce, cs, max_registers, w_qa, w_qb)
    w_q = _work_array("lq4", wp.vec4, cv, True)
    w_qd = _work_array("lqd4", wp.vec4, cv, True)
    w_rest = _work_array("lrest4", wp.vec4, cf, True)  # rest position, -anchor_scale * k_i
    w_kda = _work_array("lkda", wp.float32, cf, True)  # -anchor_scale * d_i
    w_dtm = _work_array("ldtm", wp.float32, cf, True)  # dt / m_i
    w_off = _shared_array("loff16", wp.int16, cf + 1)
    w_code = _shared_array("lcode16", wp.int16, ce)
    w_f = _work_array("lf4", wp.vec4, cs, True)
    w_p64 = _work_array("lp64", wp.float64, 8, True)  # probe: rest (3), depth x direction (3), 1 / ramp steps, peak^2
    w_pv = _work_array("lpv4", wp.vec4, 3, True)  # probe: peak reaction; full-depth target and 1 / dt; hold reaction
    vec_i = wp.types.vector(length=P, dtype=wp.int32)
    vec_f = wp.types.vector(length=P, dtype=wp.float32)
    options = {"cuda_max_registers": int(max_registers)} if max_registers else {}

    @wp.kernel(module="unique", enable_backward=False, **options)
    def press_batch_explicit_lean(
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
        ne = local_offsets[b, nf]
        ns = spring_count[b]
        q = w_q(scratch, 0)
        qd = w_qd(scratch, 0)
        rest4 = w_rest(scratch, 0)
        kda = w_kda(particle_mass, 0)
        dtm = w_dtm(particle_mass, 0)
        off = w_off()
        code = w_code()
        fe = w_f(scratch, 0)
        p64 = w_p64(peak_force, 0)
        pv = w_pv(scratch, 0)
        for i in range(lane, n, T):
            st(q, i, q_state[b, i])
            st(qd, i, qd_state[b, i])
        for i in range(lane, nf, T):
            v = region_vertex[b, i]
            x0 = q_rest[v]
            rest4[i] = wp.vec4(x0[0], x0[1], x0[2], -anchor_scale * anchor_ke[v])
            kda[i] = -anchor_scale * anchor_kd[v]
            dtm[i] = dt / particle_mass[v]
        for i in range(lane, nf + 1, T):
            off[i] = wp.int16(local_offsets[b, i])
        for k in range(lane, ne, T):
            code[k] = wp.int16(local_spring[b, k])
        ends = vec_i(0)
        ke = vec_f(0.0)
        kd = vec_f(0.0)
        l0 = vec_f(0.0)
        for m in range(P):
            sp = lane + m * T
            if sp < ns:
                k = spring_entry[b, sp]
                ends[m] = local_owner[b, k] | (local_neighbour[b, k] << 16)
                e = local_edge[b, k]
                ke[m] = spring_ke[e]
                kd[m] = spring_kd[e]
                l0[m] = spring_rest_length[e]
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
            for m in range(P):
                sp = lane + m * T
                if sp < ns:
                    i = ends[m] & 0xFFFF
                    j = ends[m] >> 16
                    x = ld(q, i)
                    r = ld(q, j) - x
                    l2 = wp.dot(r, r)
                    c = wp.vec3(0.0)
                    if l2 > EPS_LENGTH2:
                        inv_l = rsqrt_approx(l2)
                        sf = ke[m] * (l2 * inv_l - l0[m]) + kd[m] * wp.dot(ld(qd, j) - ld(qd, i), r) * inv_l
                        c = (sf * inv_l) * r
                    st(fe, sp, c)
            block_sync()
            # (B) each free vertex: anchor, eq. (3), then its springs in mesh CSR order
            for i in range(lane, nf, T):
                x = ld(q, i)
                u = ld(qd, i)
                c4 = load4(rest4, i)
                f = c4[3] * (x - wp.vec3(c4[0], c4[1], c4[2])) + kda[i] * u
                for k in range(wp.int32(off[i]), wp.int32(off[i + 1])):
                    f = add_entry16(f, fe, code, k)
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
                    tf = load4(pv, 1)
                    target = wp.vec3(tf[0], tf[1], tf[2])
                    if s < ramp_steps:
                        r0 = wp.vec3d(p64[0], p64[1], p64[2])
                        d0 = wp.vec3d(p64[3], p64[4], p64[5])
                        target = wp.vec3(r0 + d0 * (wp.float64(s + 1) * p64[6]))
                    st(q, i, target)
                    st(qd, i, (target - x) * tf[3])
                else:
                    # m u'' + d u' + k u = F, eq. (3), semi-implicit Euler: velocity first, then position
                    u1 = u + f * dtm[i]
                    st(q, i, x + dt * u1)
                    st(qd, i, u1)
            block_sync()
        for i in range(lane, n, T):
            q_state[b, i] = ld(q, i)
            qd_state[b, i] = ld(qd, i)
        if lane == 0:
            peak_force[b] = p64[7]
            peak_reaction[b] = ld(pv, 0)
            hold_reaction[b] = ld(pv, 2)

    return press_batch_explicit_lean
