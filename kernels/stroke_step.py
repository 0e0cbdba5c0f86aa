"""The stroke's explicit step with its counts on the device: one captured frame serves every region.

The shared explicit step (kernels/integrate_explicit.py) takes the free count as a scalar, which a
graph capture records: each relocation of a stroke's region then needed a new capture (about 10 us
of CPU time a launch argument, 200-500 us a launch). Here the free count is read from a device array
(`counts`, see STROKE_COUNTS), which the host rewrites when the region moves; the region's arrays
are sized for the whole mesh and never replaced, so a frame captured once replays for every region.

Semi-implicit Euler, eqs. (3)-(8), over the free vertices (the stroke never drives a vertex: its
spheres are put on by kernels/stroke_contact.py after the step). A grid-stride loop: one thread per
mesh vertex on CUDA (those past the free count return), a single thread on the CPU. The force is
kernels/forces.gather_vertex_force (the one copy of the gather), on the Model's TissueArrays: a
struct's members keep a run-time stride on the CPU, which costs the shared step 3.7%
(docs/performance.md) but this one only a few tenths of a microsecond on a region of a few hundred
vertices; and a struct argument costs the capture more, which runs here once.
"""

import warp as wp

from .arrays import TissueArrays
from .forces import gather_vertex_force

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

STROKE_COUNTS = ("free_count", "vertex_count", "near_ring")
"""The entries of a stroke's counts array (int32, device): the free vertices the step moves, the
region's vertices the contact pass goes over, the first ring whose vertices near a sphere move the region."""

_INT = wp.array(dtype=wp.int32)
_VEC = wp.array(dtype=wp.vec3)


@wp.kernel
def integrate_stroke_explicit(
    free_vertex: _INT, counts: _INT, stride: int, tissue: TissueArrays, anchor_scale: float, dt: float,
    q_in: _VEC, qd_in: _VEC, q_out: _VEC, qd_out: _VEC,
):
    for i in range(wp.tid(), counts[0], stride):
        v = free_vertex[i]
        x = q_in[v]
        u = qd_in[v]
        f = gather_vertex_force(v, x, u, tissue, anchor_scale, q_in, qd_in)  # eqs. (3)-(6)
        # m u'' + d u' + k u = F by semi-implicit Euler: velocity first, then position
        u1 = u + dt * f / tissue.particle_mass[v]
        qd_out[v] = u1
        q_out[v] = x + dt * u1


def integrate_stroke(model, free_vertex, counts, anchor_scale, state_in, state_out, dt):
    """Advance the first counts[0] vertices of `free_vertex` by one semi-implicit Euler step of `dt` [s]
    (counts: a device int32 array laid out as STROKE_COUNTS, read when the launch runs)."""
    threads = 1 if model.device.is_cpu else model.particle_count
    wp.launch(
        integrate_stroke_explicit,
        dim=threads,
        inputs=[free_vertex, counts, threads, model.arrays, float(anchor_scale), dt, state_in.particle_q,
                state_in.particle_qd],
        outputs=[state_out.particle_q, state_out.particle_qd],
        device=model.device,
    )
