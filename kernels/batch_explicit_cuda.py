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
This is the "entries" kernel; CUDA's default, "fast", is built in kernels/batch_fast.py.
"""

import contextlib
import functools

import warp as wp

from .batch_explicit import _work_array, block_sync
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


FAST_ON_CPU = False
"""Run the "fast" kernel on the CPU too (it runs the exact "entries" kernel there): for tests of its logic."""


def press_kernel_fast(*args, **kw):
    from .batch_fast import press_kernel_fast as build

    return build(*args, **kw)
