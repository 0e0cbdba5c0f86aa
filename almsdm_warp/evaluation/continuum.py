"""The spring model against continuum mechanics, for `almsdm evaluate`: mesh convergence (the same
press at three resolutions) and the issue's ball case against quadratic finite elements and Hertz.

    run_convergence(settings, device, tasks)  # force against resolution, material and paper's constants
    run_against_fem(settings, device, tasks)  # the product's configurations against P2 (fem.py) and Hertz

The presses are the product's (Palpation, implicit, a rigid sphere held until steady); the
references (fem.py, hertz.py) share no code with it. scripts/mesh_independence.py prints the same
presses as tables (docs/calibration.md).
"""

from __future__ import annotations

import time

import numpy as np

from ..mesh import primitives
from ..mesh.tissue_mesh import TissueMesh
from ..region.contact import top_vertex
from ..tissue.material import Material
from ..tissue.params import TissueParams
from . import fem, hertz

SURFACE = Material(10e3, 0.45, 1000.0, thickness=2e-3, foundation=1e6, damping_ratio=1.0)
"""The icosphere's (and the stomach pair's) tissue: E 10 kPa, nu 0.45, t 2 mm, kappa 1 kPa/mm, dampers critical."""
SOLID = Material(10e3, 0.45, 1000.0, rayleigh_beta=0.01)
"""The tet ball's tissue: E 10 kPa, nu 0.45; Rayleigh d = 0.01 s x k (its slowest mode near critical)."""
STEADY = 1e-3
"""A hold is steady when its force changed less than this fraction over the hold's last 10%."""

ICOSPHERE = dict(radius_mm=50.0, sphere=0.01, depth=0.005)
"""Icosphere R 50 mm (a pole vertex every level keeps), a sphere R 10 mm pressed 5 mm at the pole."""
BALL = dict(radius_mm=50.0, refine_top=4.0, z_fix=-0.04, sphere=0.05, depth=0.002, young=10e3, poisson=0.45)
"""The issue's ball: R 50 mm graded x 4 toward the top, fixed below z = -40 mm, a sphere R 50 mm pressed 2 mm."""
BALL_PRESS = dict(dt=2e-3, ramp=0.1, hold=0.5)
"""The ball's press with the material [s]; the paper's constants settle slower (PAPER_BALL_PRESS)."""
PAPER_BALL_PRESS = dict(dt=1e-3, ramp=0.1, hold=1.5)
WITHIN = 0.01
"""A local region "needs" the fewest rings whose force is within this fraction of the global model's."""


def pole_icosphere(radius_mm: float, subdivisions: int):
    """Icosphere (vertices [m], triangles) turned so that one of the icosahedron's 12 vertices, kept by
    every subdivision, is the top pole (0, 0, R): the press starts at the same point at every level."""
    vertices, triangles = primitives.icosphere_arrays(radius_mm, subdivisions)
    a = vertices[0] / np.linalg.norm(vertices[0])
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(a, z), float(a @ z)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    rotation = np.eye(3) + vx + vx @ vx / (1.0 + c)  # Rodrigues: a onto z
    return vertices @ rotation.T, np.asarray(triangles, dtype=np.int64)


def pole_icosphere_mesh(radius_mm: float, subdivisions: int) -> TissueMesh:
    """The pole icosphere as a TissueMesh."""
    vertices, triangles = pole_icosphere(radius_mm, subdivisions)
    return TissueMesh.from_arrays(vertices * 1e3, triangles=triangles, scale=1.0)


def ball_mesh(edge_mm: float, seed: int = 0) -> TissueMesh:
    """The issue's tet ball (BALL) at an edge length [mm]."""
    return primitives.tet_ball(BALL["radius_mm"], edge_mm, seed=seed, refine_top=BALL["refine_top"])


def contact_edge_mm(mesh: TissueMesh, radius_m: float, centre=None) -> float:
    """Mean length [mm] of the surface edges inside the contact disc of `radius_m` around `centre` [m]
    (the top pole unless given; both ends within it): the resolution the probe sees."""
    x = mesh.vertices
    centre = x[top_vertex(mesh)] if centre is None else np.asarray(centre, dtype=np.float64)
    edges = mesh.edges
    surface = np.zeros(len(x), dtype=bool)
    surface[mesh.surface_vertices] = True
    inside = surface & (np.linalg.norm(x - centre, axis=1) <= radius_m)
    e = edges[inside[edges[:, 0]] & inside[edges[:, 1]]]
    return float(np.linalg.norm(x[e[:, 1]] - x[e[:, 0]], axis=1).mean() * 1e3) if len(e) else float("nan")


def overlap_radius(mesh: TissueMesh, point, normal, radius, depth) -> float:
    """The contact radius [m] of a rigid sphere of `radius` [m] touching the rest surface at `point`
    along the outward `normal` and pressed `depth` [m]: the largest distance from the probe's axis of
    the surface it overlaps (sampled as in surface_patch; sqrt(2 R d - d^2) on a plane). A membrane on
    an elastic foundation touches the probe over about this disc; curvature under the probe sets it."""
    point, normal = np.asarray(point, dtype=np.float64), np.asarray(normal, dtype=np.float64)
    pts, _ = _patch_samples(mesh, point, 2.0 * np.sqrt(2.0 * radius * depth))
    inside = pts[np.linalg.norm(pts - (point + normal * (radius - depth)), axis=1) < radius] - point
    return float(np.linalg.norm(inside - np.outer(inside @ normal, normal), axis=1).max()) if len(inside) else 0.0


def hold_force(mesh, tissue, vertex, depth, *, rings="global", probe_radius=0.0, fixed_below=None, dt=1e-3,
               ramp=0.05, hold=0.1, device="cpu", timing_budget_s=None, law="springs"):
    """A press held until steady: (hold force [N], change over the hold's last 10% as a fraction,
    vertices simulated, seconds, median step [us] or None).

    timing_budget_s: time the step with the probe held at the press's depth for about that long.
    law: the tissue law (springs: these sections measure the spring model; a tet mesh's default law is
    another, depth_layers.py presses every law). Raises RuntimeError when the hold is not steady (STEADY)."""
    from ..protocol.palpation import Palpation

    start = time.perf_counter()
    pal = Palpation(mesh, tissue, rings=rings, integrator="implicit", dt=dt, device=device,
                    probe_radius=probe_radius, fixed_below=fixed_below, law=law)
    pal.touch(vertex)
    result = pal.press(depth, ramp=ramp, hold=hold, settle=dt)
    force = result.force[: result.release_step]
    change = steady_change(force, hold, dt)
    simulated = mesh.vertex_count if pal.region is None else pal.region_vertices
    seconds = time.perf_counter() - start
    step_us = held_step_us(pal, depth, timing_budget_s) if timing_budget_s else None
    return float(force[-1]), change, simulated, seconds, step_us


def held_step_us(pal, depth, budget_s) -> float:
    """The median step [us] of a palpation with its probe held `depth` [m] in along the inward normal (a
    sphere of pal.probe_radius, or the driven vertex), over about `budget_s` of stepping."""
    from ..protocol.timing import time_palpation
    from ..sim.model import PROBE_DISPLACEMENT, PROBE_SPHERE

    rest, inward = pal.rest_position(), pal.inward_normal()
    if pal.probe_radius > 0:
        pal.set_probe(PROBE_SPHERE, rest - inward * pal.probe_radius + inward * depth)
    else:
        pal.set_probe(PROBE_DISPLACEMENT, rest + inward * depth)
    return time_palpation(pal, 9, read_force=True, warmup=10, budget_s=budget_s, max_steps=5000).median * 1e6


def steady_change(force, hold, dt) -> float:
    """The change of a held force over the hold's last 10%, as a fraction of its last value.
    Raises RuntimeError when it is not under STEADY."""
    tail = force[-max(2, int(round(hold / dt)) // 10):]
    change = float((tail.max() - tail.min()) / force[-1])
    if change >= STEADY:
        raise RuntimeError(f"hold not steady: the force changed {change:.2%} over the last 10% of the hold")
    return change


def spread(forces) -> float:
    """max / min - 1 of a series of forces."""
    return float(max(forces) / min(forces) - 1.0)


def _ball_press(mesh, tissue, press, **kw):
    return hold_force(mesh, tissue, top_vertex(mesh), BALL["depth"], fixed_below=BALL["z_fix"], **press, **kw)


def count_tasks(settings) -> int:
    return 2 * (len(settings.continuum.subdivisions) + len(settings.continuum.edges_mm)) + 3 + len(settings.continuum.fem_rings)


def run_convergence(settings, device, tasks) -> dict:
    """Force against resolution: the material model and the paper's constants (R = 0) on the pole
    icosphere (4 rings around the contact, the global force to 1e-6: docs/calibration.md) and on the
    tet ball (global)."""
    ico = {"levels": list(settings.continuum.subdivisions), "vertices": [], "edge_mm": [], "series": {}}
    meshes = [pole_icosphere_mesh(ICOSPHERE["radius_mm"], s) for s in ico["levels"]]
    for mesh in meshes:
        ico["vertices"].append(mesh.vertex_count)
        ico["edge_mm"].append(float(mesh.edge_rest_length.mean() * 1e3))
    for label, tissue, radius in (("material, R 10 mm", SURFACE, ICOSPHERE["sphere"]), ("paper's constants, R 0", TissueParams(), 0.0)):
        forces = []
        for s, mesh in zip(ico["levels"], meshes):
            tasks.step(f"convergence: icosphere {s}, {label}")
            forces.append(hold_force(mesh, tissue, top_vertex(mesh), ICOSPHERE["depth"], rings=4, probe_radius=radius, device=device)[0])
        ico["series"][label] = forces
    ball = {"edges_mm": list(settings.continuum.edges_mm), "vertices": [], "contact_edge_mm": [], "series": {}}
    meshes = [ball_mesh(e) for e in ball["edges_mm"]]
    contact = hertz.hertz_contact_radius(BALL["sphere"], BALL["depth"], BALL["sphere"])
    for mesh in meshes:
        ball["vertices"].append(mesh.vertex_count)
        ball["contact_edge_mm"].append(contact_edge_mm(mesh, contact))
    for label, tissue, radius, press in (("material, R 50 mm", SOLID, BALL["sphere"], BALL_PRESS),
                                         ("paper's constants, R 0", TissueParams(), 0.0, PAPER_BALL_PRESS)):
        forces = []
        for e, mesh in zip(ball["edges_mm"], meshes):
            tasks.step(f"convergence: ball {e:g} mm, {label}")
            forces.append(_ball_press(mesh, tissue, press, probe_radius=radius, device=device)[0])
        ball["series"][label] = forces
    for part in (ico, ball):
        part["spread"] = {label: spread(f) for label, f in part["series"].items()}
    return {"icosphere": ico, "ball": ball, "contact_radius_mm": contact * 1e3}


def _fem_references(settings, vertices, tets, tasks) -> dict:
    """P2 on the ball, Hertz for the two spheres, and (settings.continuum.hertz_block) P2 against Hertz on a block."""
    tasks.step(f"against FEM: P2 on the {settings.continuum.fem_edge_mm:g} mm ball")
    t0 = time.perf_counter()
    p2 = fem.sphere_press(vertices, tets, young=BALL["young"], poisson=BALL["poisson"], order=2,
                          sphere_radius=BALL["sphere"], depth=BALL["depth"],
                          fixed=lambda x: fem.clamped_below(x, BALL["z_fix"]))
    out = {
        "p2_force_N": p2.force, "p2_contact_radius_mm": p2.contact_radius * 1e3, "p2_nodes": len(p2.nodes),
        "p2_s": round(time.perf_counter() - t0, 1),
        "hertz_force_N": hertz.hertz_force(BALL["young"], BALL["poisson"], BALL["sphere"], BALL["depth"], BALL["sphere"]),
        "hertz_contact_radius_mm": hertz.hertz_contact_radius(BALL["sphere"], BALL["depth"], BALL["sphere"]) * 1e3,
        "block": None,
    }
    tasks.step("against FEM: Hertz on a block")
    if settings.continuum.hertz_block:
        xs = np.array([0.0, 1.0, 2.0, 3.0, 5.0, 8.0, 13.0, 20.0, 30.0, 40.0])
        v, t = primitives.tet_grid_arrays(xs, xs, -xs[::-1])
        radius, depth = 0.02, 0.0002
        block = fem.sphere_press(v, t, young=BALL["young"], poisson=BALL["poisson"], order=2, copies=4,
                                 sphere_radius=radius, depth=depth,
                                 fixed=lambda x: fem.clamped_below(x, -0.04 + 1e-9) | fem.symmetry_planes(x, "xy"))
        out["block"] = {"sphere_mm": radius * 1e3, "depth_mm": depth * 1e3, "size_mm": [80, 80, 40],
                        "p2_force_N": block.force, "hertz_force_N": hertz.hertz_force(BALL["young"], BALL["poisson"], radius, depth),
                        "p2_contact_radius_mm": block.contact_radius * 1e3,
                        "hertz_contact_radius_mm": hertz.hertz_contact_radius(radius, depth) * 1e3}
    return out


def run_against_fem(settings, device, tasks) -> dict:
    """The issue's ball: the product's force (global, and local regions of settings.continuum.fem_rings around
    the sphere's patch) against P2 finite elements on the same mesh and Hertz's closed form; each
    configuration's error against the FEM and against the global model, and its step time."""
    vertices, tets = primitives.tet_ball_arrays(BALL["radius_mm"], settings.continuum.fem_edge_mm, refine_top=BALL["refine_top"])
    mesh = TissueMesh.from_arrays(vertices * 1e3, tetrahedra=tets, scale=1.0)
    out = {"edge_mm": settings.continuum.fem_edge_mm, "vertices": mesh.vertex_count, **_fem_references(settings, vertices, tets, tasks)}
    rows = []
    for rings in (*settings.continuum.fem_rings, "global"):
        tasks.step(f"against FEM: {rings} rings")
        force, change, simulated, _, step_us = _ball_press(mesh, SOLID, BALL_PRESS, rings=rings, probe_radius=BALL["sphere"],
                                                           device=device, timing_budget_s=settings.timing_budget_s)
        rows.append({"rings": rings, "region_vertices": simulated, "force_N": force, "hold_change": change, "step_us": step_us})
    glob = rows[-1]["force_N"]
    for row in rows:
        row["error_vs_fem_pct"] = 100.0 * (row["force_N"] / out["p2_force_N"] - 1.0)
        row["error_vs_global_pct"] = 100.0 * (row["force_N"] / glob - 1.0)
    out["rows"] = rows
    within = [r["rings"] for r in rows if r["rings"] != "global" and abs(r["error_vs_global_pct"]) <= 100 * WITHIN]
    out["rings_needed"] = min(within) if within else None
    out["within_pct"] = 100 * WITHIN
    return out


def _patch_samples(mesh, point, radius_m, per_mm2=50.0, seed=0):
    """Points [m] spread uniformly by area (about `per_mm2` a square millimetre) over the surface
    triangles within `radius_m` (plus the longest edge) of `point`, each with its triangle's id."""
    x, tri = mesh.vertices, mesh.triangles.astype(np.int64)
    centres = x[tri].mean(axis=1)
    reach = radius_m + float(mesh.edge_rest_length.max())
    near = np.flatnonzero(np.linalg.norm(centres - point, axis=1) <= reach)
    a, b, c = (x[tri[near, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    rng = np.random.default_rng(seed)
    count = max(1000, int(area.sum() * 1e6 * per_mm2))
    pick = rng.choice(len(near), size=count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    pts = a[pick] + u[:, None] * (b[pick] - a[pick]) + v[:, None] * (c[pick] - a[pick])
    return pts, near[pick]


def surface_patch(mesh, point, radius_m):
    """The surface under a probe at `point` [m]: (the closest point on the surface [m], to the
    sampling's spacing of about 0.15 mm; the unit outward normal averaged by area over the triangles
    within `radius_m` of it)."""
    point = np.asarray(point, dtype=np.float64)
    pts, _ = _patch_samples(mesh, point, 2.0 * float(mesh.edge_rest_length.max()))
    closest = pts[np.argmin(np.linalg.norm(pts - point, axis=1))]
    x, tri = mesh.vertices, mesh.triangles.astype(np.int64)
    near = np.flatnonzero(np.linalg.norm(x[tri].mean(axis=1) - closest, axis=1) <= radius_m)
    normal = 0.5 * np.cross(x[tri[near, 1]] - x[tri[near, 0]], x[tri[near, 2]] - x[tri[near, 0]]).sum(axis=0)
    return closest, normal / np.linalg.norm(normal)


def sphere_hold_at(mesh, tissue, point, normal, depth, radius, *, rings="global", dt=1e-3, ramp=0.05, hold=0.1, device="cpu"):
    """A rigid sphere of `radius` [m] that touches the surface at `point` [m] from outside along the
    outward `normal`, pressed `depth` [m] along -normal and held: (hold force [N], change over the
    hold's last 10% as a fraction). The contact is the sphere's (every vertex it would penetrate);
    the vertex nearest `point` only seeds the region. Raises RuntimeError when the hold is not steady."""
    import math

    from ..protocol.palpation import Palpation
    from ..protocol.schedule import PressSchedule
    from ..sim.model import PROBE_SPHERE

    point, normal = np.asarray(point, dtype=np.float64), np.asarray(normal, dtype=np.float64)
    surface = mesh.surface_vertices
    nearest = int(surface[np.argmin(np.linalg.norm(mesh.vertices[surface] - point, axis=1))])
    pal = Palpation(mesh, tissue, rings=rings, integrator="implicit", dt=dt, device=device, probe_radius=radius)
    pal.touch(nearest, depth)
    schedule = PressSchedule.from_times(dt, ramp, hold)
    force = np.zeros(schedule.release_step)
    for s in range(schedule.release_step):
        pal.set_probe(PROBE_SPHERE, point + normal * (radius - depth * schedule.fraction(s)))
        f = pal.step()
        force[s] = math.sqrt(float(f[0]) ** 2 + float(f[1]) ** 2 + float(f[2]) ** 2)
    pal.check_finite(schedule.release_step)
    change = steady_change(force, hold, dt)
    return float(force[-1]), change


def local_hausdorff(mesh_a, mesh_b, point, radius_m):
    """The largest distance [m] from either surface, within `radius_m` of `point`, to the other surface
    (both sampled at about 50 points a square millimetre: to about 0.15 mm)."""
    from scipy.spatial import cKDTree

    samples = [_patch_samples(m, point, radius_m)[0] for m in (mesh_a, mesh_b)]
    out = 0.0
    for here, there in ((samples[0], samples[1]), (samples[1], samples[0])):
        here = here[np.linalg.norm(here - point, axis=1) <= radius_m]
        out = max(out, float(cKDTree(there).query(here)[0].max()))
    return out
