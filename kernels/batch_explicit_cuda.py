"""A batch of presses on CUDA: one block per palpation, spring work spread over the block's threads.

The same step as kernels/batch_explicit.py (and the one-palpation step), arranged for a GPU:
- the region's state (positions, velocities) lives in shared memory for the whole launch;
- each thread holds, in registers loaded once, up to `per_thread` of the region's springs
  (owner, neighbour, k_ij, d_ij, rest length); per-vertex constants and each CSR entry's spring
  (and sign) are in shared memory too;
- a step is two phases between block barriers: (A) every spring's force along its edge,
  eqs. (4)-(6), into shared memory (the work of the step, balanced over all threads); (B) each free
  vertex sums the anchor term, eq. (3), and then its springs in mesh CSR order (the one-palpation
  order), and integrates by semi-implicit Euler in place.
Each spring is computed once: the entry j -> i of a spring between two free vertices reads the
entry i -> j's force negated, which is its exact value (r, and the velocity difference, change
sign exactly; the length and the dot product do not change), so the sums are the same bits.
"""

import contextlib
import functools

import warp as wp

from .batch_explicit import _C_TYPES, _native, _work_array, block_sync
from .forces import EPS_LENGTH

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    const float4 v = reinterpret_cast<const float4*>(a.data)[i];  // one 16-byte shared load
    return wp::vec_t<3, wp::float32>(v.x, v.y, v.z);
#else
    const wp::vec_t<4, wp::float32>& v = a.data[i];
    return wp::vec_t<3, wp::float32>(v[0], v[1], v[2]);
#endif
"""
)
def load_xyz(a: wp.array(dtype=wp.vec4), i: int) -> wp.vec3: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    reinterpret_cast<float4*>(a.data)[i] = make_float4(v[0], v[1], v[2], 0.0f);  // one 16-byte store
#else
    a.data[i] = wp::vec_t<4, wp::float32>(v[0], v[1], v[2], 0.0f);
#endif
"""
)
def store_xyz(a: wp.array(dtype=wp.vec4), i: int, v: wp.vec3): ...


@wp.func
def load_xyz3(a: wp.array(dtype=wp.vec3), i: int):
    return a[i]


@wp.func
def store_xyz3(a: wp.array(dtype=wp.vec3), i: int, v: wp.vec3):
    a[i] = v


def shared_bytes(vertex_capacity: int, entry_capacity: int, spring_capacity: int) -> int:
    """Shared memory a block of this kernel takes [bytes]: state and constants per vertex, a code
    per CSR entry, a force per spring."""
    return 60 * vertex_capacity + 4 + 4 * entry_capacity + 16 * spring_capacity  # vec4 state and forces


@functools.cache
def press_kernel_cuda(threads: int, per_thread: int, vertex_capacity: int, entry_capacity: int, max_registers: int = 0, wide: bool = True):
    """The kernel for blocks of `threads` threads with `per_thread` springs each, regions of up to
    `vertex_capacity` vertices and `entry_capacity` CSR entries (compile-time sizes: registers are
    unrolled, shared arrays static); `max_registers` > 0 caps registers per thread (occupancy);
    `wide`: positions, velocities and spring forces stored as 16-byte vec4 (one shared load each)."""
    T, P, cv, ce = int(threads), int(per_thread), int(vertex_capacity), int(entry_capacity)
    cs = T * P
    sv = wp.vec4 if wide else wp.vec3
    ld, st = (load_xyz, store_xyz) if wide else (load_xyz3, store_xyz3)
    w_q = _work_array("cq" + "4" * wide, sv, cv, True)
    w_qd = _work_array("cqd" + "4" * wide, sv, cv, True)
    w_rest = _work_array("crest", wp.vec3, cv, True)
    w_mass = _work_array("cmass", wp.float32, cv, True)
    w_ka = _work_array("cka", wp.float32, cv, True)
    w_kda = _work_array("ckda", wp.float32, cv, True)
    w_off = _work_array("coff", wp.int32, cv + 1, True)
    w_code = _work_array("ccode", wp.int32, ce, True)
    w_f = _work_array("cf" + "4" * wide, sv, cs, True)
    vec_i = wp.types.vector(length=P, dtype=wp.int32)
    vec_f = wp.types.vector(length=P, dtype=wp.float32)
    options = {"cuda_max_registers": int(max_registers)} if max_registers else {}

    @wp.kernel(module="unique", enable_backward=False, **options)
    def press_batch_explicit_cuda(
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
        scratch: wp.array(dtype=sv),
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
        rest = w_rest(q_rest, 0)
        mass = w_mass(particle_mass, 0)
        ka = w_ka(particle_mass, 0)
        kda = w_kda(particle_mass, 0)
        off = w_off(region_count, 0)
        code = w_code(region_count, 0)
        fe = w_f(scratch, 0)
        # the region into shared memory: state, per-vertex constants, CSR offsets and entry codes
        for i in range(lane, n, T):
            v = region_vertex[b, i]
            st(q, i, q_state[b, i])
            st(qd, i, qd_state[b, i])
            rest[i] = q_rest[v]
            mass[i] = particle_mass[v]
            ka[i] = anchor_ke[v]
            kda[i] = anchor_kd[v]
        for i in range(lane, nf + 1, T):
            off[i] = local_offsets[b, i]
        for k in range(lane, ne, T):
            code[k] = local_spring[b, k]
        # this lane's springs (each spring of the region once), in registers for the whole launch
        own = vec_i(0)
        nbr = vec_i(0)
        ke = vec_f(0.0)
        kd = vec_f(0.0)
        l0 = vec_f(0.0)
        for m in range(P):
            sp = lane + m * T
            if sp < ns:
                k = spring_entry[b, sp]
                own[m] = local_owner[b, k]
                nbr[m] = local_neighbour[b, k]
                e = local_edge[b, k]
                ke[m] = spring_ke[e]
                kd[m] = spring_kd[e]
                l0[m] = spring_rest_length[e]
        rest0 = wp.vec3d(q_rest[region_vertex[b, 0]])
        direction = press_direction[b]
        peak = peak_force[b]
        peak_f = peak_reaction[b]
        block_sync()
        for s in range(step_begin, step_begin + step_count):
            # (A) each spring: elastic force along the edge, eqs. (4)-(5), and damping along it, eq. (6)
            for m in range(P):
                sp = lane + m * T
                if sp < ns:
                    i = own[m]
                    j = nbr[m]
                    x = ld(q, i)
                    r = ld(q, j) - x
                    l = wp.length(r)
                    c = wp.vec3(0.0)
                    if l > EPS_LENGTH:
                        inv_l = 1.0 / l
                        sf = ke[m] * (l - l0[m]) + kd[m] * wp.dot(ld(qd, j) - ld(qd, i), r) * inv_l
                        c = (sf * inv_l) * r
                    st(fe, sp, c)
            block_sync()
            # (B) each free vertex: anchor first, eq. (3), then its springs in mesh CSR order (the
            # entry j -> i of a spring i -> j is its exact negation)
            for i in range(lane, nf, T):
                x = ld(q, i)
                u = ld(qd, i)
                f = -anchor_scale * (ka[i] * (x - rest[i]) + kda[i] * u)
                for k in range(off[i], off[i + 1]):
                    sc = code[k]
                    if sc > 0:
                        f += ld(fe, sc - 1)
                    else:
                        f += -ld(fe, -sc - 1)
                if i == 0 and s < press_steps:
                    # the feedback force, then displacement control: the vertex is where the probe puts it
                    fx = wp.float64(f[0])
                    fy = wp.float64(f[1])
                    fz = wp.float64(f[2])
                    mag = wp.sqrt(fx * fx + fy * fy + fz * fz)
                    if mag > peak:
                        peak = mag
                        peak_f = f
                    if s == press_steps - 1:
                        hold_reaction[b] = f
                    frac = wp.min(wp.float64(s + 1) / wp.float64(ramp_steps), wp.float64(1.0))
                    target = wp.vec3(rest0 + direction * depth * frac)
                    st(q, i, target)
                    st(qd, i, (target - x) / dt)
                else:
                    # m u'' + d u' + k u = F, eq. (3), by semi-implicit Euler: velocity first, then position
                    u1 = u + dt * f / mass[i]
                    st(q, i, x + dt * u1)
                    st(qd, i, u1)
            block_sync()
        for i in range(lane, n, T):
            q_state[b, i] = ld(q, i)
            qd_state[b, i] = ld(qd, i)
        if lane == 0:
            peak_force[b] = peak
            peak_reaction[b] = peak_f

    return press_batch_explicit_cuda


def press_batch_cuda(batch, step_begin, step_count):
    """Advance every palpation of `batch` `step_count` steps with the CUDA kernel (batch.cuda_plan)."""
    m, r, p = batch.model, batch.regions, batch
    with _cpu_blocks(m.device):
        _launch(m, r, p, p.cuda_plan, step_begin, step_count)


@contextlib.contextmanager
def _cpu_blocks(device):
    # On the CPU a block of several threads runs as fibers with a real barrier only while Warp's
    # enable_cpu_blocks is on (off by default: its block_dim would otherwise be 1, with no barrier).
    # Switched on for this launch alone, and back, so no other launch sees it (tests run this path).
    if not device.is_cpu:
        yield
        return
    saved = wp.config.enable_cpu_blocks
    wp.config.enable_cpu_blocks = True
    try:
        yield
    finally:
        wp.config.enable_cpu_blocks = saved


def _launch(m, r, p, plan, step_begin, step_count):
    threads = plan[0]
    # on the CPU "fast" runs the exact kernel (FAST_ON_CPU: the fast one, for checking its logic)
    fast = p.kernel == "fast" and (m.device.is_cuda or FAST_ON_CPU)
    if fast:
        plan = p.fast_plan
        threads = plan[0]
    wp.launch(
        press_kernel_fast(*plan) if fast else press_kernel_cuda(*plan),
        dim=p.batch_size * threads,
        block_dim=threads,
        inputs=[
            r.region_vertex, r.region_count, r.free_count, r.local_offsets, r.local_neighbour, r.local_edge, r.local_owner,
            r.local_spring, r.spring_entry, r.spring_count,
            m.particle_q_rest, m.particle_mass, m.anchor_ke, m.anchor_kd, 1.0, m.spring_ke, m.spring_kd, m.spring_rest_length,
            p.press_direction, p.depth, p.ramp_steps, p.press_steps, p.dt, int(step_begin), int(step_count),
        ],
        outputs=[p.q_state, p.qd_state, p.peak_force, p.peak_reaction, p.hold_reaction, p.scratch_wide if fast or plan[5] else p.scratch_vec3],
        device=m.device,
    )


# -- the "fast" kernel: the same step with fewer instructions (CUDA only) -------------------------
# Versus press_kernel_cuda: an approximate reciprocal square root for each spring's length and
# its inverse (one MUFU.RSQ where sqrt.rn and div.rn took ~20 instructions); per free vertex dt/m
# and the negated anchor constants precomputed (no division a step); each CSR entry adds its
# spring's force times +-1 without a branch; the probe's bookkeeping without float64 sqrt and
# division (the peak compared as a squared magnitude, the ramp fraction by a reciprocal); shared
# arrays sized to this batch's largest free-vertex and spring counts; a spring's two local ends
# packed in one register. Results differ from the CPU's by rounding (forces within 5e-6 relative, by
# scripts/check_batch_bits.py and tests/test_batch.py); a run repeats its bits on one device.

EPS_LENGTH2 = EPS_LENGTH * EPS_LENGTH
FAST_ON_CPU = False


def _shared_array(name, dtype, capacity):
    # a block's working array with no global fallback (__shared__ on CUDA; a static buffer on the
    # CPU, where blocks run one after another): for types no kernel argument has
    ctype = _C_TYPES[dtype]
    snippet = f"""
#if defined(__CUDA_ARCH__)
    __shared__ __align__(16) {ctype} buf[{capacity}];
    return wp::array_t<{ctype}>(buf, {capacity});
#else
    alignas(16) static unsigned char raw[sizeof({ctype}) * {capacity}];
    return wp::array_t<{ctype}>(reinterpret_cast<{ctype}*>(raw), {capacity});
#endif
"""

    @_native.func_native(snippet, f"shared_{name}_{capacity}")
    def stub() -> wp.array(dtype=dtype): ...

    return stub


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    return rsqrtf(x);  // MUFU.RSQ: ~2 ulp
#else
    return 1.0f / sqrtf(x);
#endif
"""
)
def rsqrt_approx(x: float) -> float: ...


@wp.func_native(
    """
    const int e = (c > 0 ? c : -c) - 1;
    const float s = c > 0 ? 1.0f : -1.0f;  // exact: f + s * v is f + v or f - v
#if defined(__CUDA_ARCH__)
    const float4 v = reinterpret_cast<const float4*>(a.data)[e];
    return wp::vec_t<3, wp::float32>(fmaf(s, v.x, f[0]), fmaf(s, v.y, f[1]), fmaf(s, v.z, f[2]));
#else
    const wp::vec_t<4, wp::float32>& v = a.data[e];
    return wp::vec_t<3, wp::float32>(f[0] + s * v[0], f[1] + s * v[1], f[2] + s * v[2]);
#endif
"""
)
def add_entry(f: wp.vec3, a: wp.array(dtype=wp.vec4), c: int) -> wp.vec3: ...


@wp.func_native(
    """
    const int c = code.data[k];
    const int e = (c > 0 ? c : -c) - 1;
    const float s = c > 0 ? 1.0f : -1.0f;  // exact: f + s * v is f + v or f - v
#if defined(__CUDA_ARCH__)
    const float4 v = reinterpret_cast<const float4*>(a.data)[e];
    return wp::vec_t<3, wp::float32>(fmaf(s, v.x, f[0]), fmaf(s, v.y, f[1]), fmaf(s, v.z, f[2]));
#else
    const wp::vec_t<4, wp::float32>& v = a.data[e];
    return wp::vec_t<3, wp::float32>(f[0] + s * v[0], f[1] + s * v[1], f[2] + s * v[2]);
#endif
"""
)
def add_entry16(f: wp.vec3, a: wp.array(dtype=wp.vec4), code: wp.array(dtype=wp.int16), k: int) -> wp.vec3: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    const float4 v = reinterpret_cast<const float4*>(a.data)[i];
    return wp::vec_t<4, wp::float32>(v.x, v.y, v.z, v.w);
#else
    return a.data[i];
#endif
"""
)
def load4(a: wp.array(dtype=wp.vec4), i: int) -> wp.vec4: ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    const float2 v = reinterpret_cast<const float2*>(a.data)[i];  // one 8-byte shared load
    return wp::vec_t<2, wp::float32>(v.x, v.y);
#else
    return a.data[i];
#endif
"""
)
def load2(a: wp.array(dtype=wp.vec2), i: int) -> wp.vec2: ...


def shared_bytes_fast(vertex_capacity: int, free_capacity: int, entry_capacity: int, spring_capacity: int, lean: int = 2, max_degree: int = 16) -> int:
    """Shared memory a block of the "fast" kernel takes [bytes]."""
    if int(lean) >= 4:  # codes transposed: max_degree rows of free_capacity (lean 6: two slot maps)
        maps = 4 * spring_capacity if int(lean) == 6 else 4
        return 32 * vertex_capacity + 24 * free_capacity + 2 * (free_capacity + 1 + max_degree * free_capacity) + 16 * spring_capacity + 112 + maps
    if int(lean) == 3:
        return 32 * vertex_capacity + 24 * free_capacity + 2 * (free_capacity + 1 + spring_capacity) + 16 * entry_capacity + 112
    index = 2 if lean else 4
    return 32 * vertex_capacity + 24 * free_capacity + index * (free_capacity + 1 + entry_capacity) + 16 * spring_capacity + 112 * bool(lean)


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
    pairs (one 4-byte read for two entries)."""
    if int(lean) >= 4:
        w_qa = _work_array("oqa4", wp.vec4, int(vertex_capacity), True)
        w_qb = _shared_array("oqb2", wp.vec2, int(vertex_capacity))
        return _press_kernel_owned(
            int(threads), int(per_thread), int(vertex_capacity), int(free_capacity), int(entry_capacity), int(spring_capacity),
            max_registers, w_qa, w_qb, max(int(max_degree), 1), int(lean) >= 5, int(lean) == 6, int(lean) == 7,
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


def _press_kernel_slots(T, P, cv, cf, ce, cs, max_registers, w_qa, w_qb):
    # the packed kernel with a force slot per CSR entry: a spring writes its force to its own entry
    # and the negation to its mirror's, so a free vertex sums its entries in order, with no code
    # lookup or sign and contiguous slots (fewer shared-memory wavefronts and bank conflicts)
    ld, st = load_xyz, store_xyz
    w_rest = _work_array("srest4", wp.vec4, cf, True)
    w_kda = _work_array("skda", wp.float32, cf, True)
    w_dtm = _work_array("sdtm", wp.float32, cf, True)
    w_off = _shared_array("soff16", wp.int16, cf + 1)
    w_mir = _shared_array("smir16", wp.int16, cs)
    w_f = _work_array("sf4", wp.vec4, ce, True)
    w_p64 = _work_array("sp64", wp.float64, 8, True)
    w_pv = _work_array("spv4", wp.vec4, 3, True)
    vec_i = wp.types.vector(length=P, dtype=wp.int32)
    vec_f = wp.types.vector(length=P, dtype=wp.float32)
    options = {"cuda_max_registers": int(max_registers)} if max_registers else {}

    @wp.kernel(module="unique", enable_backward=False, **options)
    def press_batch_explicit_slots(
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
        mir = w_mir()
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
        # each spring's mirror entry (the entry j -> i that reads it negated), or -1
        for sp in range(lane, ns, T):
            mir[sp] = wp.int16(-1)
        block_sync()
        for k in range(lane, ne, T):
            cd = local_spring[b, k]
            if cd < 0:
                mir[-cd - 1] = wp.int16(k)
        block_sync()
        slots = vec_i(0)
        ends = vec_i(0)
        ke = vec_f(0.0)
        kd = vec_f(0.0)
        l0 = vec_f(0.0)
        for m in range(P):
            sp = lane + m * T
            if sp < ns:
                k = spring_entry[b, sp]
                ends[m] = local_owner[b, k] | (local_neighbour[b, k] << 16)
                slots[m] = k | ((wp.int32(mir[sp]) + 1) << 16)
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
                    # the force into its entry's slot, and negated (exact) into its mirror entry's
                    st(fe, slots[m] & 0xFFFF, c)
                    k2 = (slots[m] >> 16) - 1
                    if k2 >= 0:
                        st(fe, k2, -c)
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
                    f += ld(fe, k)
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

    return press_batch_explicit_slots


def _press_kernel_owned(T, P, cv, cf, ce, cs, max_registers, w_qa, w_qb, cd, constants_in_registers, levels=False, pairs=False):
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
    # in each 4-byte word (entries 2p and 2p + 1 of a vertex: half the code reads). Same arithmetic,
    # same order as lean = 2 (the same bits).
    ld, st = load_xyz, store_xyz
    w_rest = _work_array("orest4", wp.vec4, cf, True)
    w_kda = _work_array("okda", wp.float32, cf, True)
    w_dtm = _work_array("odtm", wp.float32, cf, True)
    w_off = _shared_array("ooff16", wp.int16, cf + 1)
    w_code = _shared_array("ocodet16", wp.int16, cd * cf if not pairs else 2)
    w_pair = _shared_array("ocodep32", wp.int32, (cd + 1) // 2 * cf if pairs else 1)
    w_f = _work_array("of4", wp.vec4, cs, True)
    w_p64 = _work_array("op64", wp.float64, 8, True)
    w_pv = _work_array("opv4", wp.vec4, 3, True)
    w_slot = _shared_array("oslot16", wp.int16, cs if levels else 1)  # a spring's slot
    w_spring = _shared_array("ospring16", wp.int16, cs if levels else 1)  # a slot's spring
    vec_i = wp.types.vector(length=P, dtype=wp.int32)
    vec_f = wp.types.vector(length=P, dtype=wp.float32)
    options = {"cuda_max_registers": int(max_registers)} if max_registers else {}
    regs = bool(constants_in_registers)
    lev = bool(levels)
    two = bool(pairs)

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
            rest4[i] = wp.vec4(x0[0], x0[1], x0[2], -anchor_scale * anchor_ke[v])
            kda[i] = -anchor_scale * anchor_kd[v]
            dtm[i] = dt / particle_mass[v]
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
        for m in range(P):
            sp = lane + m * T
            if sp < ns:
                k = int(0)
                if wp.static(lev):
                    k = spring_entry[b, wp.int32(spring_at[sp])]
                else:
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
                    tf = load4(pv, 1)
                    target = wp.vec3(tf[0], tf[1], tf[2])
                    if s < ramp_steps:
                        r0 = wp.vec3d(p64[0], p64[1], p64[2])
                        d0 = wp.vec3d(p64[3], p64[4], p64[5])
                        target = wp.vec3(r0 + d0 * (wp.float64(s + 1) * p64[6]))
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
                c4 = load4(rest4, i)
                f = c4[3] * (x - wp.vec3(c4[0], c4[1], c4[2])) + kda[i] * u
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

    return press_batch_explicit_owned
