"""A batch of presses on CUDA: one block per palpation, spring work spread over the block's threads.

The same step as kernels/batch_explicit.py (and the one-palpation step), arranged for a GPU:
- the region's state (positions, velocities) lives in shared memory for the whole launch;
- each thread holds, in registers loaded once, up to `per_thread` CSR entries of the region's
  free vertices (owner, neighbour, k_ij, d_ij, rest length) and, if its lane is a free vertex,
  that vertex's rest position, mass and anchor;
- a step is two phases between block barriers: (A) every entry's spring force along its edge,
  eqs. (4)-(6), into shared memory (the work of the step, balanced over all threads); (B) each free
  vertex sums the anchor term, eq. (3), and then its entries in mesh CSR order (the one-palpation
  order), and integrates by semi-implicit Euler in place.
Requires a block of at least as many threads as the largest region's free vertices (<= 1024).
"""

import contextlib
import functools

import warp as wp

from .batch_explicit import _work_array, block_sync
from .forces import EPS_LENGTH

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


def shared_bytes(vertex_capacity: int, entry_capacity: int) -> int:
    """Shared memory a block of this kernel takes [bytes]: q, qd per vertex, a force per entry."""
    return 24 * vertex_capacity + 12 * entry_capacity


@functools.cache
def press_kernel_cuda(threads: int, per_thread: int, vertex_capacity: int):
    """The kernel for blocks of `threads` threads, `per_thread` entries each, regions of up to
    `vertex_capacity` vertices (compile-time sizes: registers are unrolled, shared arrays static)."""
    T, P, cv = int(threads), int(per_thread), int(vertex_capacity)
    ce = T * P
    w_q = _work_array("cq", wp.vec3, cv, True)
    w_qd = _work_array("cqd", wp.vec3, cv, True)
    w_f = _work_array("cf", wp.vec3, ce, True)
    vec_i = wp.types.vector(length=P, dtype=wp.int32)
    vec_f = wp.types.vector(length=P, dtype=wp.float32)

    @wp.kernel(module="unique", enable_backward=False)
    def press_batch_explicit_cuda(
        region_vertex: wp.array2d(dtype=wp.int32),
        region_count: wp.array(dtype=wp.int32),
        free_count: wp.array(dtype=wp.int32),
        local_offsets: wp.array2d(dtype=wp.int32),
        local_neighbour: wp.array2d(dtype=wp.int32),
        local_edge: wp.array2d(dtype=wp.int32),
        local_owner: wp.array2d(dtype=wp.int32),
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
    ):
        tid = wp.tid()
        b = tid // T
        lane = tid - b * T
        n = region_count[b]
        nf = free_count[b]
        ne = local_offsets[b, nf]
        q = w_q(q_rest, 0)
        qd = w_qd(q_rest, 0)
        fe = w_f(q_rest, 0)
        for i in range(lane, n, T):
            q[i] = q_state[b, i]
            qd[i] = qd_state[b, i]
        # this lane's entries, in registers for the whole launch
        own = vec_i(0)
        nbr = vec_i(0)
        ke = vec_f(0.0)
        kd = vec_f(0.0)
        l0 = vec_f(0.0)
        for m in range(P):
            k = lane + m * T
            if k < ne:
                own[m] = local_owner[b, k]
                nbr[m] = local_neighbour[b, k]
                e = local_edge[b, k]
                ke[m] = spring_ke[e]
                kd[m] = spring_kd[e]
                l0[m] = spring_rest_length[e]
        # this lane's vertex (local index = lane), if it is free
        i = lane
        rest_i = wp.vec3(0.0)
        mass_i = float(1.0)
        ka_i = float(0.0)
        kda_i = float(0.0)
        k0 = int(0)
        k1 = int(0)
        if i < nf:
            v = region_vertex[b, i]
            rest_i = q_rest[v]
            mass_i = particle_mass[v]
            ka_i = anchor_ke[v]
            kda_i = anchor_kd[v]
            k0 = local_offsets[b, i]
            k1 = local_offsets[b, i + 1]
        rest0 = wp.vec3d(q_rest[region_vertex[b, 0]])
        direction = press_direction[b]
        peak = peak_force[b]
        peak_f = peak_reaction[b]
        block_sync()
        for s in range(step_begin, step_begin + step_count):
            # (A) each entry: elastic force along the edge, eqs. (4)-(5), and damping along it, eq. (6)
            for m in range(P):
                k = lane + m * T
                if k < ne:
                    x = q[own[m]]
                    j = nbr[m]
                    r = q[j] - x
                    l = wp.length(r)
                    c = wp.vec3(0.0)
                    if l > EPS_LENGTH:
                        inv_l = 1.0 / l
                        sf = ke[m] * (l - l0[m]) + kd[m] * wp.dot(qd[j] - qd[own[m]], r) * inv_l
                        c = (sf * inv_l) * r
                    fe[k] = c
            block_sync()
            # (B) each free vertex: anchor first, eq. (3), then its entries in mesh CSR order
            if i < nf:
                x = q[i]
                u = qd[i]
                f = -anchor_scale * (ka_i * (x - rest_i) + kda_i * u)
                for k in range(k0, k1):
                    f += fe[k]
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
                    q[i] = target
                    qd[i] = (target - x) / dt
                else:
                    # m u'' + d u' + k u = F, eq. (3), by semi-implicit Euler: velocity first, then position
                    u1 = u + dt * f / mass_i
                    q[i] = x + dt * u1
                    qd[i] = u1
            block_sync()
        for i2 in range(lane, n, T):
            q_state[b, i2] = q[i2]
            qd_state[b, i2] = qd[i2]
        if lane == 0:
            peak_force[b] = peak
            peak_reaction[b] = peak_f

    return press_batch_explicit_cuda


def press_batch_cuda(batch, step_begin, step_count):
    """Advance every palpation of `batch` `step_count` steps with the CUDA kernel (batch.cuda_plan)."""
    m, r, p = batch.model, batch.regions, batch
    threads, per_thread, cv = p.cuda_plan
    with _cpu_blocks(m.device):
        _launch(m, r, p, threads, per_thread, cv, step_begin, step_count)


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


def _launch(m, r, p, threads, per_thread, cv, step_begin, step_count):
    wp.launch(
        press_kernel_cuda(threads, per_thread, cv),
        dim=p.batch_size * threads,
        block_dim=threads,
        inputs=[
            r.region_vertex, r.region_count, r.free_count, r.local_offsets, r.local_neighbour, r.local_edge, r.local_owner,
            m.particle_q_rest, m.particle_mass, m.anchor_ke, m.anchor_kd, 1.0, m.spring_ke, m.spring_kd, m.spring_rest_length,
            p.press_direction, p.depth, p.ramp_steps, p.press_steps, p.dt, int(step_begin), int(step_count),
        ],
        outputs=[p.q_state, p.qd_state, p.peak_force, p.peak_reaction, p.hold_reaction],
        device=m.device,
    )
