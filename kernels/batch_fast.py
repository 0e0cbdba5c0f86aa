"""The "fast" batch kernel on CUDA (CUDA's default): its builder, and the packed variant (lean = 2,
the bit reference of the owned ones on the CPU).

The owned-vertex variants (lean 4-11) are in batch_fast_owned.py, the shared helpers in
batch_fast_common.py.
"""


import functools

import warp as wp

from .batch_explicit import _work_array, block_sync
from .batch_explicit_cuda import load_xyz, store_xyz
from .batch_fast_common import EPS_LENGTH2, _shared_array, add_entry16, load2, load4, rsqrt_approx
from .batch_fast_owned import _press_kernel_owned

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@functools.cache
def press_kernel_fast(threads: int, per_thread: int, vertex_capacity: int, free_capacity: int, entry_capacity: int, spring_capacity: int, max_registers: int = 0, lean: int = 2, max_degree: int = 16):
    """The "fast" kernel for blocks of `threads` threads with `per_thread` springs each, regions of up
    to `vertex_capacity` vertices, `free_capacity` free ones, `entry_capacity` CSR entries and
    `spring_capacity` springs (compile-time sizes); `max_registers` > 0 caps registers per thread.
    lean = 2: the probe's constants and running peak in shared memory (only lane 0 reads them), CSR
    offsets and entry codes as int16, a vertex's position and velocity in 24 bytes (x, y, z, vx |
    vy, vz: one 16- and one 8-byte load); lean = 4: as 2,
    with each thread owning a free vertex (its position, velocity and degree in registers across
    steps) and CSR codes stored transposed (`max_degree` rows); lean = 5: as 4, with the owned
    vertex's constants in registers too; lean = 6: as 5, with the force slots numbered by CSR level
    (conflict-free reads of a warp's own springs in the sums); lean = 7: as 5, with the codes in
    pairs (one 4-byte read for two entries); lean = 8: as 5, the springs' end indices not hoisted
    out of the step loop (fewer live registers); lean = 9: as 5, each thread's last spring slot in shared memory;
    lean = 10: as 5, all spring constants in shared memory (fewer registers); lean = 11: as 5, force slots spread over
    the shared-memory banks (kernels/batch_fast_slots.py). (Lean 0, 1 and 3, slower, were removed:
    docs/performance.md keeps their measurements; git history their code.)"""
    lean = int(lean)
    if lean >= 4:
        w_qa = _work_array("oqa4", wp.vec4, int(vertex_capacity), True)
        w_qb = _shared_array("oqb2", wp.vec2, int(vertex_capacity))
        return _press_kernel_owned(
            int(threads), int(per_thread), int(vertex_capacity), int(free_capacity), int(entry_capacity), int(spring_capacity),
            max_registers, w_qa, w_qb, max(int(max_degree), 1), lean >= 5, lean == 6, lean == 7, lean == 8, {9: 1, 10: 2}.get(lean, 0), lean == 11,
        )
    if lean != 2:
        raise ValueError(f"lean must be 2 or 4..11, got {lean}")
    cv = int(vertex_capacity)
    w_qa = _work_array("pqa4", wp.vec4, cv, True)  # x, y, z, vx
    w_qb = _shared_array("pqb2", wp.vec2, cv)  # vy, vz
    return _press_kernel_packed(int(threads), int(per_thread), cv, int(free_capacity), int(entry_capacity), int(spring_capacity), max_registers, w_qa, w_qb)


def _press_kernel_packed(T, P, cv, cf, ce, cs, max_registers, w_qa, w_qb):
    # the lean kernel with each vertex's position and velocity packed in 24 bytes (see press_kernel_fast)
    ld, st = load_xyz, store_xyz
    w_rest = _work_array("prest4", wp.vec4, cf, True)
    w_kda = _work_array("pkda", wp.float32, cf, True)
    w_dtm = _work_array("pdtm", wp.float32, cf, True)
    w_off = _shared_array("poff16", wp.int16, cf + 1)
    w_code = _shared_array("pcode16", wp.int16, ce)
    w_f = _work_array("pf4", wp.vec4, cs, True)
    w_p64 = _work_array("pp64", wp.float64, 8, True)
    w_pv = _work_array("ppv4", wp.vec4, 3, True)
    vec_i = wp.types.vector(length=P, dtype=wp.int32)
    vec_f = wp.types.vector(length=P, dtype=wp.float32)
    options = {"cuda_max_registers": int(max_registers)} if max_registers else {}

    @wp.kernel(module="unique", enable_backward=False, **options)
    def press_batch_explicit_packed(
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
        qa = w_qa(scratch, 0)
        qb = w_qb()
        rest4 = w_rest(scratch, 0)
        kda = w_kda(particle_mass, 0)
        dtm = w_dtm(particle_mass, 0)
        off = w_off()
        code = w_code()
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
            block_sync()
            # (B) each free vertex: anchor, eq. (3), then its springs in mesh CSR order
            for i in range(lane, nf, T):
                av = load4(qa, i)
                bv = load2(qb, i)
                x = wp.vec3(av[0], av[1], av[2])
                u = wp.vec3(av[3], bv[0], bv[1])
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
                    u1 = (target - x) * tf[3]
                    qa[i] = wp.vec4(target[0], target[1], target[2], u1[0])
                    qb[i] = wp.vec2(u1[1], u1[2])
                else:
                    # m u'' + d u' + k u = F, eq. (3), semi-implicit Euler: velocity first, then position
                    u1 = u + f * dtm[i]
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

    return press_batch_explicit_packed
