"""newton 1.8's neo-Hookean tets against the project's on the shipped liver, pressed the same way.

    PYTHONPATH=$PWD:/tmp/nwsite python scripts/newton_compare.py [--device cpu|cuda:0] [--depths-mm 2 5]
        [--blocks 9] [--block-steps 1000] [--core 0] [--poisson NU] [--no-fem] [--json FILE]

newton (NVIDIA's Newton physics engine, on Warp) is needed only here: put it on PYTHONPATH (its wheel
needs only warp-lang); the package and its tests never import it.

One press, the same in every engine: the liver scene's tet mesh (scenes/liver.toml: all 700 vertices
and 2340 tets, its material E, nu, density, Rayleigh alpha, and its support: every vertex below the
fixed plane held), its top vertex driven kinematically `depth` along the inward normal (a linear ramp
over --ramp-s, then held) and the force that holds it there read every step.

- **newton**: `ModelBuilder.add_soft_mesh` of the whole mesh (Smith et al.'s stable neo-Hookean tets
  with the rest-stability term, one volume term a tet), `SolverSemiImplicit` (symplectic Euler). Its
  Lame parameters are Smith et al.'s re-parameterisation of E and nu (k_mu = 4/3 mu, k_lambda = lambda
  + 5/6 mu), the one under which its energy is linear elasticity of (mu, lambda) at rest; k_damp 0.
  The supported vertices and the driven one have mass 0 (newton moves a massless particle only by its
  velocity, kept 0); before each step one kernel of this script writes the driven vertex's target,
  and sets `particle_f` to the scene's mass-proportional damping -alpha m v (newton's way of adding an
  external force; it has no mass-proportional damping of its own), so that both engines follow the
  same damped dynamics. Gravity 0, no contacts (particle grid off, triangle contact off). The force
  is `particle_f` of the driven vertex after the step: the tets' internal force on it (its mass 0
  takes no damping), whose negative holds it.
- **project**: `Palpation(rings="global", law="neo-hookean", probe_radius=0)` (stable neo-Hookean
  tets with average nodal pressure, every vertex free but the support), the explicit integrator in
  one substep a step, the probe in PROBE_DISPLACEMENT mode; the force is its feedback force.
- **FEM** (almsdm_warp/evaluation/fem_nonlinear.py): classic neo-Hookean P1 tets, Newton's method on
  the same displacement problem (the driven vertex's three dofs prescribed, the support fixed), its
  reaction at the driven vertex.

Per engine: the largest stable step (bisected to 2%: a press of the deepest depth run for --probe-s
must stay finite and its force under 10x the FEM's), the step used (0.9 x that for newton; the
project's own, 0.9 x its critical step estimate, which the bisection checks), the static force (the
end of a --hold-s press), the steps and simulated time until the force stays within --tol of it, and
microseconds a step: blocks of --block-steps steps at the held press, the engines alternated block by
block after warm-up, wp.synchronize around each block, medians and best blocks. A step is what a
press loop needs: one graph replay and the driven vertex's force on the host (the project's
Palpation.step(); newton's step captured the same way, its force copied to a pinned buffer in the
graph, waited for on CUDA). Beside it newton's step without the read (throughput), without its zero-
stiffness surface triangles, uncaptured, and with its default contacts (particle grid at its default
radius, triangle contact), which the body does not survive: that one timed from the rest state.
Time-to-answer = steps to --tol x the median step. On the CPU the process is pinned to one core
(--core). A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from dataclasses import dataclass, replace

import numpy as np
import warp as wp


@wp.kernel
def drive_and_damp(q: wp.array(dtype=wp.vec3), qd: wp.array(dtype=wp.vec3), f: wp.array(dtype=wp.vec3),
                   mass: wp.array(dtype=float), alpha: float, vertex: int, target: wp.array(dtype=wp.vec3)):
    # newton's particle_f before its step: the mass-proportional damping -alpha m v (replacing clear_forces);
    # the driven vertex put at its target, at rest
    i = wp.tid()
    if i == vertex:
        q[i] = target[0]
        qd[i] = wp.vec3(0.0)
    f[i] = (-alpha * mass[i]) * qd[i]


@dataclass
class Problem:
    """The liver scene's press: mesh [m], material, driven vertex, inward unit normal, support mask."""

    mesh: object
    tissue: object
    fixed_below: float
    vertex: int
    inward: np.ndarray
    supported: np.ndarray


def load_problem(poisson: float | None = None) -> Problem:
    from almsdm_warp.region.contact import top_vertex
    from almsdm_warp.scene.loader import default_scene_path, load_scene
    from almsdm_warp.sim.model import Model

    scene = load_scene(default_scene_path("liver"))
    if poisson is not None:
        scene = replace(scene, tissue=replace(scene.tissue, poisson_ratio=poisson))
    mesh = scene.load_mesh()
    vertex = top_vertex(mesh)
    scene = scene.with_support(mesh, float(mesh.vertices[vertex, 2]))
    model = Model(mesh, scene.tissue, "cpu", fixed_below=scene.fixed_below, law=scene.law)
    inward = -np.asarray(model.vertex_normal_rest[vertex], dtype=np.float64)
    return Problem(mesh, scene.tissue, scene.fixed_below, vertex, inward / np.linalg.norm(inward),
                   np.asarray(model.support_mask, dtype=bool))


class ProjectPress:
    """The project's global model (rings "global"), explicit, one substep a step of `dt`."""

    name = "project"

    def __init__(self, problem: Problem, dt: float, device: str):
        from almsdm_warp.protocol.palpation import Palpation

        self.p, self.dt = problem, dt
        self.pal = Palpation(problem.mesh, problem.tissue, rings="global", dt=dt, device=device, substeps=1,
                             law="neo-hookean", fixed_below=problem.fixed_below, probe_radius=0.0)
        self.pal.touch(problem.vertex)
        self.rest = self.pal.rest_position()

    def critical_dt(self) -> float:
        return self.pal.region_critical_dt()

    def set_depth(self, depth: float) -> None:
        from almsdm_warp.sim.model import PROBE_DISPLACEMENT

        self.pal.set_probe(PROBE_DISPLACEMENT, self.rest + self.p.inward * depth)

    def step(self) -> float:
        """One step; the force holding the vertex in, along the inward normal [N] (> 0 pressing)."""
        return -float(np.dot(self.pal.step(), self.p.inward))  # the feedback force: the body pushing the probe out

    def sync(self) -> None:
        wp.synchronize_device(self.pal.device)


class NewtonPress:
    """newton's soft mesh of the whole liver on SolverSemiImplicit, stepped at `dt` (module docstring).

    Each step copies the driven vertex's force into a host buffer (pinned on CUDA, inside the graph) and, on
    CUDA, waits for it, as the project's Palpation.step() does; read=False: neither (the GPU's throughput).
    capture: each step one graph replay (False: newton's kernels launched from Python). contacts: newton's
    default particle-particle and triangle contacts on (the body then blows apart at the default particle
    radius: every step is taken from the rest state, for its cost alone). triangles=False: add_soft_mesh's
    surface triangles (stiffness 0, there for collisions) left unevaluated (model.tri_count = 0)."""

    name = "newton"

    def __init__(self, problem: Problem, dt: float, device: str, capture: bool = True, contacts: bool = False,
                 triangles: bool = True, read: bool = True):
        import newton

        self.p, self.dt, self.device = problem, dt, wp.get_device(device)
        self.model = build_newton_model(problem, device)
        if not triangles:
            self.model.tri_count = 0
        if not contacts:  # newton's defaults: both on
            self.model.particle_grid = None
        self.solver = newton.solvers.SolverSemiImplicit(self.model, enable_tri_contact=contacts)
        self.states = [self.model.state(), self.model.state()]
        self.control = self.model.control()
        self.rest = problem.mesh.vertices[problem.vertex].astype(np.float32).astype(np.float64)
        pinned = self.device.is_cuda
        self.target = wp.array([self.rest], dtype=wp.vec3, device=self.device)
        self.target_host = wp.zeros(1, dtype=wp.vec3, device="cpu", pinned=pinned)
        self.force_host = wp.zeros(1, dtype=wp.vec3, device="cpu", pinned=pinned)
        self.force_view = self.force_host.numpy()
        self.alpha = float(problem.tissue.rayleigh_alpha)
        self.cur, self.graphs, self.capture, self.read = 0, None, capture, read
        self.frozen = contacts

    def _launch(self, a, b):
        m = self.model
        wp.copy(self.target, self.target_host)
        wp.launch(drive_and_damp, dim=m.particle_count, inputs=[a.particle_q, a.particle_qd, a.particle_f, m.particle_mass,
                                                                self.alpha, self.p.vertex, self.target], device=self.device)
        self.solver.step(a, b, self.control, None, self.dt)
        if self.read:  # the state stepped from holds the step's forces
            wp.copy(self.force_host, a.particle_f, src_offset=self.p.vertex, count=1)

    def set_depth(self, depth: float) -> None:
        self.target_host.numpy()[0] = self.rest + self.p.inward * depth

    def _capture(self):
        self._launch(self.states[self.cur], self.states[1 - self.cur])  # compiles and loads outside the capture
        self.cur ^= 1
        self.graphs = []
        for i in (0, 1):
            with wp.ScopedCapture(device=self.device, force_module_load=False) as cap:
                self._launch(self.states[i], self.states[1 - i])
            self.graphs.append(cap.graph)

    def step(self) -> float:
        """One step; the force holding the vertex in, along the inward normal [N] (nan with read=False)."""
        if self.capture and self.graphs is None:
            self._capture()
        elif self.graphs is not None:
            wp.capture_launch(self.graphs[self.cur])
        else:
            self._launch(self.states[self.cur], self.states[1 - self.cur])
        self.cur ^= 0 if self.frozen else 1
        if not self.read:
            return math.nan
        if self.device.is_cuda:
            wp.synchronize_device(self.device)
        return -float(np.dot(self.force_view[0], self.p.inward))

    def sync(self) -> None:
        wp.synchronize_device(self.device)


def newton_lame(tissue) -> tuple[float, float]:
    """(k_mu, k_lambda) [Pa] of newton's stable neo-Hookean for E, nu: Smith et al. 2018's mu' = 4/3 mu,
    lambda' = lambda + 5/6 mu, under which it is linear elasticity of the Lame parameters (mu, lambda) at rest."""
    from almsdm_warp.evaluation.fem import lame

    lam, mu = lame(tissue.youngs_modulus, tissue.poisson_ratio)
    return 4.0 / 3.0 * mu, lam + 5.0 / 6.0 * mu


def build_newton_model(problem: Problem, device: str):
    import newton

    builder = newton.ModelBuilder(gravity=(0.0, 0.0, 0.0))
    k_mu, k_lambda = newton_lame(problem.tissue)
    builder.add_soft_mesh(pos=(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0, vel=(0.0, 0.0, 0.0),
                          vertices=problem.mesh.vertices.astype(np.float32).tolist(),
                          indices=problem.mesh.tetrahedra.reshape(-1).tolist(), density=float(problem.tissue.density),
                          k_mu=k_mu, k_lambda=k_lambda, k_damp=0.0, add_surface_mesh_edges=False)
    for i in np.flatnonzero(problem.supported).tolist() + [problem.vertex]:
        builder.particle_mass[i] = 0.0  # held: newton integrates a massless particle by its velocity alone
    return builder.finalize(device=device)


def press_trace(engine, depth: float, ramp: float, duration: float, bound: float = math.inf) -> np.ndarray:
    """The force [N] every step of a press ramped to `depth` [m] over `ramp` [s] and held to `duration` [s];
    stops early (the trace cut short) where the force is not finite or beyond `bound`."""
    n = int(round(duration / engine.dt))
    ramp_n = max(1, int(round(ramp / engine.dt)))
    out = np.empty(n)
    for k in range(n):
        engine.set_depth(depth * min(1.0, (k + 1) / ramp_n))
        out[k] = engine.step()
        if not abs(out[k]) < bound:
            return out[: k + 1]
    return out


def settle(trace: np.ndarray, dt: float, tol: float) -> dict:
    """The static force (the trace's end), and the first step after which every force is within `tol` of it."""
    final = float(trace[-1])
    off = np.flatnonzero(np.abs(trace - final) > tol * abs(final))
    steps = int(off[-1]) + 2 if len(off) else 1
    tail = trace[int(0.9 * len(trace)) :]
    return {"force_N": final, "steps_to_tol": steps, "time_to_tol_s": steps * dt,
            "drift_last_10pct": float(np.ptp(tail) / abs(final))}


def stable(make, dt: float, depth: float, ramp: float, duration: float, bound: float) -> bool:
    try:
        trace = press_trace(make(dt), depth, ramp, duration, bound)
    except Exception as exc:  # the project raises SimulationDiverged
        if type(exc).__name__ != "SimulationDiverged":
            raise
        return False
    return len(trace) == int(round(duration / dt)) and bool(np.all(np.abs(trace) < bound))


def largest_stable_dt(make, lo: float, hi: float, depth: float, ramp: float, duration: float, bound: float,
                      rel: float = 0.02) -> float:
    """Bisect (geometric) the largest dt in [lo, hi] whose press stays bounded, to `rel`."""
    if not stable(make, lo, depth, ramp, duration, bound):
        raise RuntimeError(f"unstable even at dt {lo:g} s")
    while hi / lo > 1.0 + rel:
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if stable(make, mid, depth, ramp, duration, bound) else (lo, mid)
    return lo


def fem_force(problem: Problem, depth: float) -> float:
    """The P1 neo-Hookean FEM's force holding the driven vertex `depth` [m] in, along the inward normal [N]."""
    from almsdm_warp.evaluation import fem_nonlinear

    n = len(problem.mesh.vertices)
    fixed = np.zeros((n, 3), dtype=bool)
    fixed[problem.supported] = True
    fixed[problem.vertex] = True
    values = np.zeros((n, 3))
    values[problem.vertex] = problem.inward * depth
    t = problem.tissue
    res = fem_nonlinear.solve(problem.mesh.vertices, problem.mesh.tetrahedra, young=t.youngs_modulus,
                              poisson=t.poisson_ratio, fixed=fixed, values=values, steps=10)
    return float(np.dot(res.reactions[problem.vertex], problem.inward))


def time_blocks(engines: dict, blocks: int, steps: dict) -> dict:
    """Microseconds a step of each engine: blocks of steps[name] steps, the engines alternated block by block."""
    for name, e in engines.items():  # warm-up: compile, capture
        for _ in range(min(50, steps[name])):
            e.step()
        e.sync()
    us = {name: [] for name in engines}
    for _ in range(blocks):
        for name, e in engines.items():
            e.sync()
            t0 = time.perf_counter()
            for _ in range(steps[name]):
                e.step()
            e.sync()
            us[name].append((time.perf_counter() - t0) / steps[name] * 1e6)
    return {name: {"median_us": statistics.median(v), "best_us": min(v), "blocks_us": v} for name, v in us.items()}


def stable_steps(problem, device, args, bound) -> dict:
    """Each engine's largest stable dt (bisected) and the dt it runs at."""
    crit = ProjectPress(problem, 1e-4, device).critical_dt()
    depth = max(args.depths_mm) * 1e-3
    makers = {"project": lambda dt: ProjectPress(problem, dt, device), "newton": lambda dt: NewtonPress(problem, dt, device)}
    out = {}
    for name, make in makers.items():
        largest = largest_stable_dt(make, crit / 8.0, crit * 8.0, depth, args.ramp_s, args.probe_s, bound)
        out[name] = {"largest_stable_dt_s": largest}
        print(f"{name}: largest stable dt {largest * 1e6:.4g} us", flush=True)
    out["project"].update(dt_s=0.9 * crit, critical_dt_estimate_s=crit)
    out["newton"]["dt_s"] = 0.9 * out["newton"]["largest_stable_dt_s"]
    return out


def forces(problem, device, args, dts, fem) -> dict:
    """Each engine's press at each depth: static force, steps and time to within tol of it, against the FEM."""
    out = {}
    for name, cls in (("project", ProjectPress), ("newton", NewtonPress)):
        out[name] = {}
        for depth_mm in args.depths_mm:
            engine = cls(problem, dts[name]["dt_s"], device)
            row = settle(press_trace(engine, depth_mm * 1e-3, args.ramp_s, args.hold_s), engine.dt, args.tol)
            row["wall_to_tol_ms"] = None  # filled from the timing
            if fem:
                row["of_fem"] = row["force_N"] / fem[depth_mm]
            out[name][depth_mm] = row
            print(f"{name} {depth_mm:g} mm: {row}", flush=True)
    return out


def moving_mass(problem, device) -> dict:
    """The mass [kg] of the vertices that move (neither supported nor driven) in each engine: the same lumping."""
    moving = ~problem.supported
    moving[problem.vertex] = False
    project = ProjectPress(problem, 1e-4, device).pal.model.particle_mass.numpy()
    return {"project": float(project[moving].sum()), "newton": float(build_newton_model(problem, device).particle_mass.numpy().sum())}


def report(res: dict) -> None:
    print(f"\ndevice {res['device']}, liver {res['vertices']} vertices, {res['tets']} tets, vertex {res['vertex']}, "
          f"nu {res['poisson']:g}, moving mass [kg] {res['moving_mass_kg']}")
    print("| engine | dt used (largest stable) [us] | us a step (median, best) | depth [mm] | static force [N] | / FEM P1 "
          "| steps to 1% | sim time [ms] | wall to 1% [ms] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in ("project", "newton"):
        d, t = res["dt"][name], res["timing"][name]
        for depth, row in res["forces"][name].items():
            of = f"{row['of_fem']:.4f}" if "of_fem" in row else "-"
            print(f"| {name} | {d['dt_s'] * 1e6:.4g} ({d['largest_stable_dt_s'] * 1e6:.4g}) | {t['median_us']:.4g} "
                  f"({t['best_us']:.4g}) | {depth:g} | {row['force_N']:.5g} | {of} | {row['steps_to_tol']} | "
                  f"{row['time_to_tol_s'] * 1e3:.4g} | {row['wall_to_tol_ms']:.4g} |")
    for name, what in (("newton-tets-only", "captured, its surface triangles (stiffness 0) left out (model.tri_count = 0)"),
                       ("newton-no-read", "captured, its force neither copied out nor waited for (throughput)"),
                       ("newton-uncaptured", "uncaptured (solver.step called from Python)"),
                       ("newton-defaults", "uncaptured with newton's default contacts (particle grid, triangle contact)")):
        t = res["timing"][name]
        print(f"newton's step {what}: {t['median_us']:.4g} us median, {t['best_us']:.4g} best")
    if res.get("fem"):
        print("FEM P1 neo-Hookean force [N]: " + ", ".join(f"{k:g} mm {v:.5g}" for k, v in res["fem"].items()))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--depths-mm", type=float, nargs="+", default=[2.0, 5.0])
    ap.add_argument("--ramp-s", type=float, default=0.05, help="ramp time [s] to the depth")
    ap.add_argument("--hold-s", type=float, default=1.0, help="press duration [s], ramp included: its last force is the static one")
    ap.add_argument("--probe-s", type=float, default=0.15, help="press duration [s] of each stability trial")
    ap.add_argument("--tol", type=float, default=0.01, help="time-to-answer: the force within this fraction of the static one")
    ap.add_argument("--blocks", type=int, default=9)
    ap.add_argument("--block-steps", type=int, default=1000)
    ap.add_argument("--defaults-fraction", type=int, default=100,
                    help="newton with its default contacts is timed over block-steps / this many steps a block (it is slow)")
    ap.add_argument("--core", type=int, default=None, help="the CPU core to pin to on --device cpu (default: the lowest allowed)")
    ap.add_argument("--poisson", type=float, default=None, help="Poisson's ratio in place of the scene's (0.45)")
    ap.add_argument("--no-fem", action="store_true")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    if args.device == "cpu":
        core = min(os.sched_getaffinity(0)) if args.core is None else args.core
        os.sched_setaffinity(0, {core})
    from almsdm_warp.warp_init import init_warp

    init_warp()
    problem = load_problem(args.poisson)
    fem = {} if args.no_fem else {d: fem_force(problem, d * 1e-3) for d in args.depths_mm}
    if fem:
        print(f"FEM: {fem}", flush=True)
    bound = 10.0 * max(fem.values()) if fem else 100.0
    dts = stable_steps(problem, args.device, args, bound)
    res = {"device": str(wp.get_device(args.device)), "vertices": len(problem.mesh.vertices), "tets": len(problem.mesh.tetrahedra),
           "vertex": problem.vertex, "poisson": problem.tissue.poisson_ratio, "fem": fem, "dt": dts, "args": vars(args)}
    res["forces"] = forces(problem, args.device, args, dts, fem)
    res["moving_mass_kg"] = moving_mass(problem, args.device)
    engines = {"project": ProjectPress(problem, dts["project"]["dt_s"], args.device),
               "newton": NewtonPress(problem, dts["newton"]["dt_s"], args.device),
               "newton-tets-only": NewtonPress(problem, dts["newton"]["dt_s"], args.device, triangles=False),
               "newton-no-read": NewtonPress(problem, dts["newton"]["dt_s"], args.device, read=False),
               "newton-uncaptured": NewtonPress(problem, dts["newton"]["dt_s"], args.device, capture=False),
               "newton-defaults": NewtonPress(problem, dts["newton"]["dt_s"], args.device, capture=False, contacts=True)}
    for e in engines.values():
        e.set_depth(max(args.depths_mm) * 1e-3)
    steps = {name: args.block_steps for name in engines}
    steps["newton-defaults"] = max(1, args.block_steps // args.defaults_fraction)
    res["timing"] = time_blocks(engines, args.blocks, steps)
    for name in ("project", "newton"):
        for row in res["forces"][name].values():
            row["wall_to_tol_ms"] = row["steps_to_tol"] * res["timing"][name]["median_us"] * 1e-3
    report(res)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(res, fh, indent=1)


if __name__ == "__main__":
    main()
