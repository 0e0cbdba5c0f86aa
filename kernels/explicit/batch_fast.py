"""A batch of presses on CUDA, fast: one block per palpation, the springs spread over its threads.

The same step as kernels/explicit/batch.py (and the one-region step), arranged for a GPU: a layout of
the springs law (kernels/laws/springs.py), not a re-write of its physics. The same pieces
(the spring force, the anchor, `advance`, the sphere's contact, the force record's squares) and the
same order of every sum:
- the region's state lives in shared memory for the whole launch, each vertex's position and
  velocity in 24 bytes (x, y, z, vx | vy, vz: one 16- and one 8-byte load);
- thread `lane` owns free vertex `lane`: its position, velocity, degree and constants (rest
  position, anchor terms, dt / m) stay in registers across steps; free vertices beyond the
  block's threads take the shared-memory path;
- each thread holds, in registers loaded once, up to `per_thread` of the region's springs (their
  two local ends packed in one register, k_ij, d_ij, rest length);
- a step is two phases between block barriers: (A) every spring's force along its edge,
  eqs. (4)-(6), into shared memory, each spring once (the entry j -> i of a spring between two
  free vertices reads the entry i -> j's force negated, its exact value); (B) each free vertex
  sums its anchor term, eq. (3), then its springs in mesh CSR order (codes stored transposed,
  code[k * cf + i], so a warp's k-th codes are one conflict-free read), and integrates by
  semi-implicit Euler.
Fewer instructions than the exact kernel: an approximate reciprocal square root for each spring's
length and its inverse (one MUFU.RSQ where sqrt.rn and div.rn take ~20 instructions); dt / m and
the anchor constants precomputed (no division a step); each CSR entry adds its spring's force
times +-1 without a branch; the probe's bookkeeping without float64 sqrt and division (the peak
compared as a squared magnitude, the ramp fraction by a reciprocal). Results differ from the
exact kernel's by rounding (forces within 5e-6 relative: scripts/check_batch_bits.py,
tests/test_batch.py); a run repeats its bits on one device. On the CPU (for tests of its logic)
the reciprocal square root is exact to a rounding.
"""

import functools

import warp as wp

from ..block_memory import add_entry16, block_sync, cpu_blocks, load2, load4, load_xyz, named, rsqrt_approx, shared_array, store_xyz, work_array
from ..laws.springs import EPS_LENGTH, anchor_force, spring_force_along
from ..arrays import BatchRecords
from ..probes.press import force_square, record_curve
from ..probes.sphere import sphere_project
from .step import advance

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

__all__ = ["MAX_REGISTERS", "SPHERE_MAX_REGISTERS", "SPHERE_THREADS", "press_batch_fast", "press_kernel_fast", "shared_bytes_fast"]

EPS_LENGTH2 = EPS_LENGTH * EPS_LENGTH

MAX_REGISTERS = 80
"""Registers a thread (12 blocks of 64 threads an SM): 9.55e8 region-steps/s against 9.23e8 at 64 on an H200."""

SPHERE_THREADS = 128
SPHERE_MAX_REGISTERS = 64
"""The sphere variant's threads a block and registers a thread: on the shipped stomach scene (1 ring,
113 / 184 region vertices median / max, 268 / 464 springs) on an H200, 4.90e8 region-steps/s at 128
threads and 64 registers (every free vertex of up to 128 in registers, 4 springs a thread, 8 blocks
an SM) against 4.21e8 at the paper probe's 64 and 80; 128 threads with 56 / 72 / 80 / 96 / 128
registers 3.95e8 / 4.86e8 / 4.58e8 / 4.49e8 / 4.06e8, 64 threads with 64 / 96 / 128 3.74e8 / 4.55e8 /
4.46e8, 256 threads with 56-96 2.6e8-3.5e8 (scripts/ab_batch_cuda.py --threads --max-registers;
docs/performance.md)."""


def shared_bytes_fast(vertex_capacity: int, free_capacity: int, spring_capacity: int, max_degree: int = 16, sphere_threads: int = 0) -> int:
    """Shared memory a block of the fast kernel takes [bytes]: packed state per vertex, constants
    and transposed int16 codes per free vertex, a force per spring, the probe's records; with a
    sphere of `sphere_threads` threads a block, each warp's sum of contact reactions, the sphere's
    centre and an int16 surface flag per free vertex."""
    sphere = 16 * part_slots(sphere_threads) + 16 + 2 * free_capacity if sphere_threads else 0
    return 32 * vertex_capacity + 24 * free_capacity + 2 * (free_capacity + 1 + max_degree * free_capacity) + 16 * spring_capacity + 116 + sphere


def part_slots(threads: int) -> int:
    """Partial sums of the contact reactions a block keeps in shared memory on CUDA: one a warp (of
    32 threads) where the block is whole warps, else one a thread."""
    return threads // 32 if threads % 32 == 0 else threads


def contact_parts(threads: int):
    """The block's partial sums of the contact reactions: `part_slots` float4s on CUDA, one a thread on
    the CPU (where a block's fibers have no shuffles and lane 0 replays the warps' tree)."""
    T = int(threads)
    snippet = f"""
#if defined(__CUDA_ARCH__)
    __shared__ __align__(16) wp::vec_t<4, wp::float32> buf[{part_slots(T)}];
    return wp::array_t<wp::vec_t<4, wp::float32>>(buf, {part_slots(T)});
#else
    alignas(16) static unsigned char raw[sizeof(wp::vec_t<4, wp::float32>) * {T}];
    return wp::array_t<wp::vec_t<4, wp::float32>>(reinterpret_cast<wp::vec_t<4, wp::float32>*>(raw), {T});
#endif
"""

    @named.func_native(snippet, f"contact_parts_{T}")
    def parts() -> wp.array(dtype=wp.vec4): ...

    return parts


def store_contact_part(threads: int):
    """`store(parts, lane, c)`: thread `lane`'s contact reaction c into the block's partial sums. On CUDA,
    with whole warps, a warp's 32 values are added by shuffles (lane l takes l + 16, then l + 8, ...,
    a tree) and the warp's first lane stores the sum; every thread of the block must call it. Else
    (the CPU, or a block of part warps) each thread stores its own value."""
    T = int(threads)
    snippet = f"""
#if defined(__CUDA_ARCH__) && {int(T % 32 == 0)}
    float x = c[0], y = c[1], z = c[2];
    #pragma unroll
    for (int o = 16; o > 0; o >>= 1) {{
        x += __shfl_down_sync(0xffffffffu, x, o);
        y += __shfl_down_sync(0xffffffffu, y, o);
        z += __shfl_down_sync(0xffffffffu, z, o);
    }}
    if ((lane & 31) == 0)
        reinterpret_cast<float4*>(parts.data)[lane >> 5] = make_float4(x, y, z, 0.0f);
#else
    parts.data[lane] = wp::vec_t<4, wp::float32>(c[0], c[1], c[2], 0.0f);
#endif
"""

    @named.func_native(snippet, f"store_contact_part_{T}")
    def store(parts: wp.array(dtype=wp.vec4), lane: int, c: wp.vec3): ...

    return store


def sum_contact_parts(threads: int):
    """`total(parts)`: the block's sum of contact reactions (lane 0, after a barrier): the warps' sums
    in warp order; on the CPU the same tree replayed over each warp's 32 values, so that both devices
    add in one order (a block of part warps: every thread's value in thread order)."""
    T = int(threads)
    snippet = f"""
    wp::vec_t<3, wp::float32> f(0.0f, 0.0f, 0.0f);
#if {int(T % 32 == 0)} && defined(__CUDA_ARCH__)
    for (int w = 0; w < {T // 32}; ++w) {{
        const float4 v = reinterpret_cast<const float4*>(parts.data)[w];
        f = wp::vec_t<3, wp::float32>(f[0] + v.x, f[1] + v.y, f[2] + v.z);
    }}
#elif {int(T % 32 == 0)}
    for (int w = 0; w < {T // 32}; ++w) {{
        float x[32], y[32], z[32];
        for (int l = 0; l < 32; ++l) {{
            const wp::vec_t<4, wp::float32>& v = parts.data[w * 32 + l];
            x[l] = v[0]; y[l] = v[1]; z[l] = v[2];
        }}
        for (int o = 16; o > 0; o >>= 1)
            for (int l = 0; l < o; ++l) {{ x[l] += x[l + o]; y[l] += y[l + o]; z[l] += z[l + o]; }}
        f = wp::vec_t<3, wp::float32>(f[0] + x[0], f[1] + y[0], f[2] + z[0]);
    }}
#else
    for (int l = 0; l < {T}; ++l) {{
        const wp::vec_t<4, wp::float32>& v = parts.data[l];
        f = wp::vec_t<3, wp::float32>(f[0] + v[0], f[1] + v[1], f[2] + v[2]);
    }}
#endif
    return f;
"""

    @named.func_native(snippet, f"sum_contact_parts_{T}")
    def total(parts: wp.array(dtype=wp.vec4)) -> wp.vec3: ...

    return total


@wp.func
def record_force_fast(f: wp.vec3, hold: bool, p64: wp.array(dtype=wp.float64), pv: wp.array(dtype=wp.vec4)):
    # the feedback force's records in shared memory: the largest squared magnitude (p64[7]) and its
    # force (pv[0]); the force at the end of the hold (pv[2])
    mag2 = force_square(f)
    if mag2 > p64[7]:
        p64[7] = mag2
        store_xyz(pv, 0, f)
    if hold:
        store_xyz(pv, 2, f)


@functools.cache
def press_kernel_fast(threads: int, per_thread: int, vertex_capacity: int, free_capacity: int, spring_capacity: int, max_degree: int = 16,
                      sphere: bool = False, curve: bool = False):
    """The fast kernel for blocks of `threads` threads with `per_thread` springs each, regions of up
    to `vertex_capacity` vertices, `free_capacity` free ones of degree up to `max_degree`, and
    `spring_capacity` springs (compile-time sizes: registers are unrolled, shared arrays static).
    `sphere`: the probe is a sphere (no vertex driven; after each pressed step every free surface
    vertex inside it goes onto it and the feedback force is the sum of the contact reactions), a
    variant of its own, so that the paper's probe runs none of it. `curve`: the force curve of the
    learning records (BatchRecords, kernels/probes/press.py's record_curve), a variant of its own too."""
    T, P, cv, cf, cs, cd = int(threads), int(per_thread), int(vertex_capacity), int(free_capacity), int(spring_capacity), max(int(max_degree), 1)
    SPHERE = bool(sphere)
    CURVE = bool(curve)
    w_qa = work_array("oqa4", wp.vec4, cv, True)  # x, y, z, vx
    w_qb = shared_array("oqb2", wp.vec2, cv)  # vy, vz
    w_rest = work_array("orest4", wp.vec4, cf, True)  # rest position, anchor stiffness
    w_kda = work_array("okda", wp.float32, cf, True)
    w_dtm = work_array("odtm", wp.float32, cf, True)
    w_off = shared_array("ooff16", wp.int16, cf + 1)
    w_code = shared_array("ocodet16", wp.int16, cd * cf)
    w_f = work_array("of4", wp.vec4, cs, True)
    w_p64 = work_array("op64", wp.float64, 8, True)
    w_pv = work_array("opv4", wp.vec4, 4 if SPHERE else 3, True)  # peak, full-depth target and 1/dt, hold; the centre
    w_part = contact_parts(T)  # (sphere) each warp's sum of contact reactions
    store_part = store_contact_part(T)
    sum_parts = sum_contact_parts(T)
    w_surf = shared_array("osurf16", wp.int16, cf)  # (sphere) whether each free vertex may touch it
    vec_i = wp.types.vector(length=P, dtype=wp.int32)
    vec_f = wp.types.vector(length=P, dtype=wp.float32)

    @wp.kernel(module="unique", enable_backward=False, cuda_max_registers=SPHERE_MAX_REGISTERS if SPHERE else MAX_REGISTERS)
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
        # the sphere's (read by its variant only): who may touch, each contact vertex's local index, R [m]
        probe_surface: wp.array(dtype=wp.int32), contact_local: wp.array(dtype=wp.int32), radius: float, radius64: wp.float64,
        records: BatchRecords,
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
        fe = w_f(scratch, 0)
        p64 = w_p64(peak_force, 0)
        pv = w_pv(scratch, 0)
        # the region into shared memory: state, per-vertex constants, CSR offsets, transposed codes
        for i in range(lane, n, T):
            x = q_state[b, i]
            u = qd_state[b, i]
            qa[i] = wp.vec4(x[0], x[1], x[2], u[0])
            qb[i] = wp.vec2(u[1], u[2])
        for i in range(lane, nf, T):
            v = region_vertex[b, i]
            x0 = q_rest[v]
            # the anchor constants negated (scale -1 in anchor_force): one multiply-add a step
            rest4[i] = wp.vec4(x0[0], x0[1], x0[2], -anchor_scale * anchor_ke[v])
            kda[i] = -anchor_scale * anchor_kd[v]
            dtm[i] = dt / particle_mass[v]
            if wp.static(SPHERE):
                w_surf()[i] = wp.int16(probe_surface[v])
            k0 = local_offsets[b, i]
            for k in range(k0, local_offsets[b, i + 1]):
                code[(k - k0) * cf + i] = wp.int16(local_spring[b, k])
        for i in range(lane, nf + 1, T):
            off[i] = wp.int16(local_offsets[b, i])
        # the owned vertex (lane < nf): state, degree and constants in registers
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
        so = int(0)
        if wp.static(SPHERE):
            so = probe_surface[vo]
        # this lane's springs (each spring of the region once), in registers for the whole launch
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
            # the probe's constants and running records (only lane 0 reads them)
            rest0 = wp.vec3d(q_rest[region_vertex[b, 0]])
            if wp.static(SPHERE):
                # the sphere's centre at rest: touching the surface at the contact vertex
                rest0 = wp.vec3d(q_rest[region_vertex[b, contact_local[b]]]) - press_direction[b] * radius64
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
            if wp.static(SPHERE):
                if lane == 0 and s < press_steps:
                    # the sphere's centre this step, read by every thread after the barrier
                    tc = load4(pv, 1)
                    if s < ramp_steps:
                        r0 = wp.vec3d(p64[0], p64[1], p64[2])
                        d0 = wp.vec3d(p64[3], p64[4], p64[5])
                        store_xyz(pv, 3, wp.vec3(r0 + d0 * (wp.float64(s + 1) * p64[6])))
                    else:
                        store_xyz(pv, 3, wp.vec3(tc[0], tc[1], tc[2]))
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
                        c = spring_force_along(r, dv, l2 * inv_l, inv_l, ke[m], kd[m], l0[m])
                    store_xyz(fe, sp, c)
            block_sync()
            # (B) each free vertex: anchor, eq. (3), then its springs in mesh CSR order; the owned
            # vertex first (registers), then any beyond the block's threads (shared memory)
            part = wp.vec3(0.0)
            centre = wp.vec3(0.0)
            if wp.static(SPHERE):
                if s < press_steps:
                    centre = load_xyz(pv, 3)
            if own:
                i = lane
                f = anchor_force(xo, uo, ro, kao, kdo, -1.0)  # the constants are stored negated
                for k in range(deg):
                    f = add_entry16(f, fe, code, k * cf + i)
                if wp.static(SPHERE):
                    # every free vertex steps; then the sphere's contact (kernels/probes/sphere.py)
                    x0 = xo
                    xo, uo = advance(x0, uo, f * dto, dt)
                    if s < press_steps and so != 0:
                        xo, uo, c, touched = sphere_project(x0, xo, uo, f, centre, radius, dt)
                        part += c
                elif i == 0 and s < press_steps:
                    # the feedback force, then displacement control (lane 0; its state in shared memory)
                    record_force_fast(f, s == press_steps - 1, p64, pv)
                    if wp.static(CURVE):
                        record_curve(records, b, s, ramp_steps, f)
                    tf = load4(pv, 1)
                    target = wp.vec3(tf[0], tf[1], tf[2])
                    if s < ramp_steps:
                        r0 = wp.vec3d(p64[0], p64[1], p64[2])
                        d0 = wp.vec3d(p64[3], p64[4], p64[5])
                        target = wp.vec3(r0 + d0 * (wp.float64(s + 1) * p64[6]))
                    uo = (target - xo) * tf[3]
                    xo = target
                else:
                    xo, uo = advance(xo, uo, f * dto, dt)  # eq. (3), semi-implicit Euler
                qa[i] = wp.vec4(xo[0], xo[1], xo[2], uo[0])
                qb[i] = wp.vec2(uo[1], uo[2])
            for i in range(lane + T, nf, T):
                av = load4(qa, i)
                bv = load2(qb, i)
                x = wp.vec3(av[0], av[1], av[2])
                u = wp.vec3(av[3], bv[0], bv[1])
                c4 = load4(rest4, i)
                f = anchor_force(x, u, wp.vec3(c4[0], c4[1], c4[2]), c4[3], kda[i], -1.0)
                for k in range(wp.int32(off[i + 1]) - wp.int32(off[i])):
                    f = add_entry16(f, fe, code, k * cf + i)
                x1, u1 = advance(x, u, f * dtm[i], dt)
                if wp.static(SPHERE):
                    if s < press_steps and w_surf()[i] != wp.int16(0):
                        x1, u1, c, touched = sphere_project(x, x1, u1, f, centre, radius, dt)
                        part += c
                qa[i] = wp.vec4(x1[0], x1[1], x1[2], u1[0])
                qb[i] = wp.vec2(u1[1], u1[2])
            if wp.static(SPHERE):
                if s < press_steps:  # the same for every thread of the block: all of them reach the shuffles
                    store_part(w_part(), lane, part)
            block_sync()
            if wp.static(SPHERE):
                if lane == 0 and s < press_steps:
                    # the feedback force: the sum of the contact reactions (a tree in each warp, then the warps in order)
                    fs = sum_parts(w_part())
                    record_force_fast(fs, s == press_steps - 1, p64, pv)
                    if wp.static(CURVE):
                        record_curve(records, b, s, ramp_steps, fs)
        for i in range(lane, n, T):
            av = load4(qa, i)
            bv = load2(qb, i)
            q_state[b, i] = wp.vec3(av[0], av[1], av[2])
            qd_state[b, i] = wp.vec3(av[3], bv[0], bv[1])
        if lane == 0:
            peak_force[b] = p64[7]
            peak_reaction[b] = load_xyz(pv, 0)
            hold_reaction[b] = load_xyz(pv, 2)

    return press_batch_explicit_fast


def press_batch_fast(batch, step_begin, step_count):
    """Advance every palpation of `batch` (a BatchPalpation) `step_count` steps with the fast kernel (batch.fast_plan)."""
    m, r, p = batch.model, batch.regions, batch
    threads = p.fast_plan[0]
    with cpu_blocks(m.device):
        wp.launch(
            press_kernel_fast(*p.fast_plan, sphere=p.probe_radius > 0, curve=p.records.on),
            dim=p.batch_size * threads,
            block_dim=threads,
            inputs=[
                r.region_vertex, r.region_count, r.free_count, r.local_offsets, r.local_neighbour, r.local_edge, r.local_owner,
                r.local_spring, r.spring_entry, r.spring_count,
                m.particle_q_rest, m.particle_mass, m.anchor_ke, m.anchor_kd, 1.0, m.spring_ke, m.spring_kd, m.spring_rest_length,
                p.press_direction, p.depth, p.ramp_steps, p.press_steps, p.dt, int(step_begin), int(step_count),
            ],
            outputs=[p.q_state, p.qd_state, p.peak_force, p.peak_reaction, p.hold_reaction, p.scratch_wide,
                     p.probe_surface, p.contact_local, p.sphere_arrays.radius, p.sphere_arrays.radius64, p.records.arrays],
            device=m.device,
        )
