"""Semi-implicit (symplectic) Euler on the region's free vertices: the paper's explicit scheme.

One launch per step: gather the forces from `state_in`, integrate, write `state_out`. A
grid-stride loop over the free vertices: one thread per vertex on CUDA, a single thread on the
CPU, where each thread's prologue (copying every array descriptor) would otherwise cost more than
the vertex's physics. The probe's vertex is driven (displacement mode) or pushed (force mode), and
its thread writes the reaction, so the feedback force needs no second kernel.

A spherical probe (sphere mode) is a second launch, made only for a Control with a sphere, so the
paper's probe runs the step as it was: one thread goes over the free vertices in local order,
puts each surface vertex that the step left inside the sphere on its surface (kernels/probe_contact.py)
and sums the contact reactions (a gather in a fixed order: the same bits every run). The internal
force it needs is the step's own, f = m (v_out - v_in) / dt.

Its arrays are direct arguments, not the structs of kernels/arrays.py that the other kernels
take: on the CPU Warp compiles direct array arguments for unit stride, and a struct's members
keep a stride read at run time; with the structs this step took 3.7% longer (docs/performance.md).
"""

import warp as wp

from .arrays import ProbeArrays, ProbeSphereArrays
from .forces import add_spring_force, anchor_force
from .probe_contact import sphere_project

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.kernel
def integrate_region_explicit(
    free_vertex: wp.array(dtype=wp.int32),
    free_count: int,
    stride: int,
    adj_offsets: wp.array(dtype=wp.int32),
    adj_vertex: wp.array(dtype=wp.int32),
    adj_spring: wp.array(dtype=wp.vec3),
    q_rest: wp.array(dtype=wp.vec3),
    particle_mass: wp.array(dtype=wp.float32),
    anchor_ke: wp.array(dtype=wp.float32),
    anchor_kd: wp.array(dtype=wp.float32),
    anchor_scale: float,
    probe_vertex: wp.array(dtype=wp.int32),
    probe_mode: wp.array(dtype=wp.int32),
    probe_target: wp.array(dtype=wp.vec3),
    probe_force: wp.array(dtype=wp.vec3),
    dt: float,
    q_in: wp.array(dtype=wp.vec3),
    qd_in: wp.array(dtype=wp.vec3),
    q_out: wp.array(dtype=wp.vec3),
    qd_out: wp.array(dtype=wp.vec3),
    probe_reaction: wp.array(dtype=wp.vec3),
):
    # the gather written out in the kernel (a wp.func taking the arrays would copy every descriptor a call)
    pv = probe_vertex[0]
    mode = probe_mode[0]
    for i in range(wp.tid(), free_count, stride):
        v = free_vertex[i]
        x = q_in[v]
        u = qd_in[v]
        f = anchor_force(x, u, q_rest[v], anchor_ke[v], anchor_kd[v], anchor_scale)
        for k in range(adj_offsets[v], adj_offsets[v + 1]):
            j = adj_vertex[k]
            spring = adj_spring[k]  # (k_ij, d_ij, rest length)
            f = add_spring_force(f, x, u, q_in[j], qd_in[j], spring[0], spring[1], spring[2])
        if v == pv and mode != 0:
            probe_reaction[0] = f  # the feedback force: the tissue's internal forces on the probe
        if v == pv and mode == 1:
            # displacement control: the vertex is where the probe puts it
            target = probe_target[0]
            q_out[v] = target
            qd_out[v] = (target - x) / dt
        else:
            if v == pv and mode == 2:
                f += probe_force[0]
            # m u'' + d u' + k u = F, eq. (3), by semi-implicit Euler: velocity first, then position
            u1 = u + dt * f / particle_mass[v]
            q_out[v] = x + dt * u1
            qd_out[v] = u1


@wp.kernel
def constrain_sphere_explicit(
    free_vertex: wp.array(dtype=wp.int32),
    free_count: int,
    particle_mass: wp.array(dtype=wp.float32),
    probe: ProbeArrays,
    sphere: ProbeSphereArrays,
    dt: float,
    q_in: wp.array(dtype=wp.vec3),
    qd_in: wp.array(dtype=wp.vec3),
    q_out: wp.array(dtype=wp.vec3),
    qd_out: wp.array(dtype=wp.vec3),
):
    # one thread: the sphere (centre probe_target) after the step; the feedback force is the sum of
    # the contact reactions, in local order
    if probe.probe_mode[0] != 3:
        return
    centre = probe.probe_target[0]
    radius = sphere.probe_radius[0]
    total = wp.vec3(0.0)
    for i in range(free_count):
        v = free_vertex[i]
        contact = wp.vec3(0.0)
        if sphere.probe_surface[v] != 0:
            f = particle_mass[v] * (qd_out[v] - qd_in[v]) / dt  # the internal force of the step
            x1, u1, c, touched = sphere_project(q_in[v], q_out[v], qd_out[v], f, centre, radius, dt)
            if touched:
                q_out[v] = x1
                qd_out[v] = u1
                contact = c
                total += contact
        sphere.probe_contact[v] = contact
    probe.probe_reaction[0] = total


@wp.kernel
def hold_probe_target(
    probe_move: wp.array(dtype=wp.vec3d),
    alpha: wp.float64,
    probe_reaction: wp.array(dtype=wp.vec3),
    fold: int,
    first: int,
    probe_target: wp.array(dtype=wp.vec3),
    probe_reaction_peak: wp.array(dtype=wp.vec3),
):
    # a first-order hold over a frame's substeps: substep s of n drives the probe to the fraction
    # alpha = (s + 1) / n of the frame's move (its start and target in float64, so the point rounds
    # to the float32 a host computing it in float64 gets; alpha = 1 rounds the target itself)
    start = probe_move[0]
    probe_target[0] = wp.vec3(start + alpha * (probe_move[1] - start))
    if fold != 0:
        # the last substep's reaction if it is the frame's first or the largest so far (magnitudes
        # in float64, as the host and the batch compare them)
        f = probe_reaction[0]
        p = probe_reaction_peak[0]
        fx = wp.float64(f[0])
        fy = wp.float64(f[1])
        fz = wp.float64(f[2])
        px = wp.float64(p[0])
        py = wp.float64(p[1])
        pz = wp.float64(p[2])
        if first != 0 or fx * fx + fy * fy + fz * fz > px * px + py * py + pz * pz:
            probe_reaction_peak[0] = f


def hold_probe(control, s: int, n: int) -> None:
    """Before substep `s` of `n` (s = n: after the last): the probe's target (the sphere's centre)
    (s + 1) / n of the way through the frame's move, control.probe_move; the reaction of substep
    s - 1 kept in control.probe_reaction_peak if it is the frame's largest. Only frames of n > 1
    substeps make it: one step a frame reads probe_target as the host wrote it."""
    wp.launch(
        hold_probe_target, dim=1,
        inputs=[control.probe_move, min((s + 1) / n, 1.0), control.probe_reaction, int(s > 0), int(s == 1)],
        outputs=[control.probe_target, control.probe_reaction_peak], device=control.device,
    )


def integrate_explicit(model, free_vertex, free_count, anchor_scale, state_in, state_out, control, dt):
    """Advance the free vertices by one semi-implicit Euler step of `dt` [s]; a Control with a sphere
    adds the sphere's contact (a second, one-thread launch)."""
    dm = model.dmesh
    threads = 1 if model.device.is_cpu else free_count
    wp.launch(
        integrate_region_explicit,
        dim=threads,
        inputs=[
            free_vertex, free_count, threads, dm.adj_offsets, dm.adj_vertex, model.adj_spring, model.particle_q_rest,
            model.particle_mass, model.anchor_ke, model.anchor_kd, anchor_scale,
            control.probe_vertex, control.probe_mode, control.probe_target, control.probe_force, dt,
            state_in.particle_q, state_in.particle_qd,
        ],
        outputs=[state_out.particle_q, state_out.particle_qd, control.probe_reaction],
        device=model.device,
    )
    if control.sphere:
        wp.launch(
            constrain_sphere_explicit,
            dim=1,
            inputs=[
                free_vertex, free_count, model.particle_mass, control.arrays, control.sphere_arrays, dt,
                state_in.particle_q, state_in.particle_qd,
            ],
            outputs=[state_out.particle_q, state_out.particle_qd],
            device=model.device,
        )
