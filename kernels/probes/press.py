"""The press, once: its schedule, the driven vertex, the force record, the frame's first-order hold.

Functions of values, inlined by Warp, composed by every step kernel that presses (one region, a
batch, explicit or implicit). The probe's target is computed in float64, as the host computes it
(almsdm_warp.protocol.schedule), then rounded to float32, so that every path drives the probe to the
same bits.
"""

import warp as wp

from ..arrays import BatchRecords

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.func
def press_target(start: wp.vec3d, direction: wp.vec3d, depth: wp.float64, step: int, ramp_steps: int):
    # the probe's target after step `step` of a press: a linear ramp from `start` along `direction`
    # to `depth` over ramp_steps steps, then held (float64, then float32)
    frac = wp.min(wp.float64(step + 1) / wp.float64(ramp_steps), wp.float64(1.0))
    return wp.vec3(start + direction * depth * frac)


@wp.func
def drive_vertex(x: wp.vec3, target: wp.vec3, dt: float):
    # displacement control: the driven vertex is where the probe puts it, at the velocity that took it there
    return target, (target - x) / dt


@wp.func
def force_square(f: wp.vec3):
    # |f|^2 in float64, as the host takes it (each float32 component squared in float64)
    fx = wp.float64(f[0])
    fy = wp.float64(f[1])
    fz = wp.float64(f[2])
    return fx * fx + fy * fy + fz * fz


@wp.func
def record_peak(peak2: wp.float64, peak_f: wp.vec3, f: wp.vec3):
    # the force record: the largest |feedback force|^2 so far and that force (squares compared: the
    # host takes the peak's magnitude from the force it keeps)
    m2 = force_square(f)
    if m2 > peak2:
        return m2, f
    return peak2, peak_f


@wp.func
def curve_slot(step: int, ramp_steps: int, points: int):
    # the force curve's sample taken after `step`, or -1: sample k at the first step of the ramp whose
    # depth reaches (k + 1) / points of the press's (points <= ramp_steps: at most one a step)
    if step >= ramp_steps:
        return -1
    crossed = (step + 1) * points // ramp_steps
    if crossed > step * points // ramp_steps:
        return crossed - 1
    return -1


@wp.func
def record_curve(records: BatchRecords, b: int, step: int, ramp_steps: int, f: wp.vec3):
    # the force record's samples along the ramp (the same force record_peak takes)
    k = curve_slot(step, ramp_steps, records.curve_points)
    if k >= 0:
        records.force_curve[b, k] = f


@wp.func
def footprint_frame(direction: wp.vec3):
    # the tactile grid's axes (e1, e2), both normal to the press direction: e1 = direction x the world
    # axis least aligned with it (x, else y), normalized; e2 = direction x e1
    axis = wp.vec3(1.0, 0.0, 0.0)
    if wp.abs(direction[0]) > 0.9:
        axis = wp.vec3(0.0, 1.0, 0.0)
    e1 = wp.normalize(wp.cross(direction, axis))
    return e1, wp.cross(direction, e1)


@wp.func
def record_contact(records: BatchRecords, b: int, v: int, x: wp.vec3, c: wp.vec3, centre: wp.vec3, direction: wp.vec3, radius: float):
    # a vertex in contact at the end of the hold: its share of the surface into the patch, its contact
    # force along the press (the tissue pushing back) into the grid cell over which it lies
    records.patch_area[b] = records.patch_area[b] + wp.float64(records.vertex_area[v])
    n = records.map_size
    e1, e2 = footprint_frame(direction)
    r = x - centre
    i = wp.clamp(int((wp.dot(r, e1) + radius) / (2.0 * radius) * float(n)), 0, n - 1)
    j = wp.clamp(int((wp.dot(r, e2) + radius) / (2.0 * radius) * float(n)), 0, n - 1)
    records.tactile[b, j * n + i] = records.tactile[b, j * n + i] - wp.float64(wp.dot(c, direction))


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
        # the last substep's reaction if it is the frame's first or the largest so far
        f = probe_reaction[0]
        p = probe_reaction_peak[0]
        if first != 0:
            p = f
        peak2, p = record_peak(force_square(p), p, f)
        probe_reaction_peak[0] = p


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
