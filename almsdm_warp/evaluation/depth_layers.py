"""Every tissue law against a neo-Hookean finite-element solve of the same tets where palpation happens:
deep, over bone and over a lesion. `almsdm evaluate`'s "depth, layers and lesions" section, and
scripts/law_vs_fem.py, which prints the same presses at other sizes.

    run_depth_layers(settings, device, tasks)  # the section's dict (results.json "depth_layers")
    press_laws(case, device)                   # one case: the reference and every law

The cases (E 10 kPa, nu 0.45; a rigid frictionless sphere pressed along -z at the top vertex):
- **layers** (slab_case): tissue over bone, a slab 10 mm thick on a rigid base (its bottom fixed),
  30 x 30 mm, tets of the given edge under the probe graded to 3x that at its sides, a sphere R 5 mm
  pressed 2 mm at the top face's centre; also against the locking-free linear P2/P0 solve (p2p0_force);
- **depth** (ball_case): a sphere R 10 mm pressed 10 mm into a tet ball R 25 mm (graded x 2 toward
  the top) resting on a support (vertices below -15 mm fixed): about 20% strain under the probe;
- **lesion** (with_lesion): the ball pressed 5 mm over a lesion 5x as stiff, R 10 mm, its centre
  15 mm below the top: the force with it over the force without, each law's against the reference's.

Every law of tissue.laws.LAWS is pressed (the list is read, never written here: a new law appears
without an edit), its global model, implicit where it has that integrator, 2 ms frames, the force at
the end of a 0.6 s hold (a static answer); on the deep press also its local regions of a few rings,
and each one's step timed with the sphere held at the depth (the speed-accuracy figure). The
reference is fem_nonlinear.solve (P1 tets, the classic compressible neo-Hookean energy,
augmented-Lagrangian contact, static, one modulus a tet for the lesion), which shares no code with
the product: the lesion's tets are chosen here by their centroids, not by tissue.lesion.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from ..mesh.primitives import tet_ball, tet_grid_arrays
from ..mesh.tissue_mesh import TissueMesh
from ..tissue.laws import LAWS, law_entry
from ..tissue.lesion import Lesion
from ..tissue.material import Material

E = 10e3
"""Young's modulus [Pa] of every case."""
POISSON = 0.45
"""Poisson's ratio of every case (the script may ask for another)."""
PRESS = dict(dt=2e-3, ramp=0.2, hold=0.6)
"""Each law's press [s]: 2 ms frames, ramp, hold (damped: the hold ends at the static force)."""
BALL = dict(radius_mm=25.0, refine_top=2.0, support=0.6, sphere_mm=10.0, depth_mm=10.0)
"""The deep press: a tet ball of radius_mm, fixed below -support x R, a sphere of sphere_mm pressed depth_mm."""
SLAB = dict(side_mm=30.0, thickness_mm=10.0, sphere_mm=5.0, depth_mm=2.0)
"""Tissue over bone: a slab side x side x thickness, its bottom fixed, a sphere of sphere_mm pressed depth_mm."""
LESION = dict(below_mm=15.0, radius_mm=10.0, factor=5.0, depth_mm=5.0)
"""The lesion: its centre below_mm under the top vertex, radius_mm, E x factor; the ball pressed depth_mm."""
TARGETS = {"slab": 0.08, "deep": 0.10, "lesion": 0.05}
"""Issue 22's bounds on |force / FEM - 1| (the lesion: on its force ratio over the FEM's ratio),
here against the FEM of the same tets."""
FEM_TIGHT = dict(steps_per_mm=2.0, rtol=1e-9, gap_rtol=1e-6)
"""The reference's load steps a millimetre of depth and tolerances (fem_nonlinear.solve's defaults)."""


@dataclass(frozen=True)
class Case:
    """One press: a tet mesh, where and how deep a sphere goes, the support and the lesion, if any."""

    name: str
    """"slab", "deep" or "lesion" (a key of TARGETS)."""
    label: str
    """The case in words, for tables."""
    mesh: TissueMesh
    vertex: int
    """The vertex under the sphere (the top of the body)."""
    fixed_below: float
    """Vertices with z below this [m] are fixed (the support, the rigid base)."""
    sphere: float
    """Sphere radius [m]."""
    depth: float
    """Press depth [m]."""
    poisson: float = POISSON
    lesion: Lesion | None = None

    def material(self) -> Material:
        """The tissue of every law: E, nu, water's density, mass-proportional damping (100 /s)."""
        return Material(youngs_modulus=E, poisson_ratio=self.poisson, density=1000.0, rayleigh_alpha=100.0)


def ball_case(edge_mm: float, depth_mm: float = BALL["depth_mm"], *, radius_mm: float = BALL["radius_mm"],
              refine_top: float = BALL["refine_top"], sphere_mm: float = BALL["sphere_mm"], poisson: float = POISSON) -> Case:
    """The deep press on a tet ball of `edge_mm` at its top (mesh.primitives.tet_ball)."""
    mesh = tet_ball(radius_mm, edge_mm, refine_top=refine_top)
    top = int(np.argmax(mesh.vertices[:, 2]))
    label = f"ball R {radius_mm:g} mm, {edge_mm:g} mm edges, sphere R {sphere_mm:g} mm {depth_mm:g} mm in"
    return Case("deep", label, mesh, top, -BALL["support"] * radius_mm * 1e-3, sphere_mm * 1e-3, depth_mm * 1e-3, poisson)


def graded(h: float, half: float) -> np.ndarray:
    """Coordinates [mm] from -half to half: steps of h within 3 h of 0, growing by 1.25 a step to at most 3 h."""
    side, x, step = [0.0], 0.0, h
    while x < half - 1e-9:
        if x >= 3 * h:
            step = min(step * 1.25, 3 * h)
        x = min(x + step, half)
        side.append(x)
    side = np.array(side)
    return np.concatenate([-side[:0:-1], side])


def slab_case(edge_mm: float, depth_mm: float = SLAB["depth_mm"], *, sphere_mm: float = SLAB["sphere_mm"], poisson: float = POISSON) -> Case:
    """Tissue over bone: the slab (SLAB) with tets of `edge_mm` under the probe, its bottom (z = 0) fixed."""
    t = SLAB["thickness_mm"]
    zs = np.linspace(0.0, t, max(int(round(t / edge_mm)), 2) + 1)
    vertices, tets = tet_grid_arrays(graded(edge_mm, SLAB["side_mm"] / 2), graded(edge_mm, SLAB["side_mm"] / 2), zs)
    mesh = TissueMesh.from_arrays(vertices * 1e3, tetrahedra=tets)
    top = int(np.argmin(np.linalg.norm(mesh.vertices - np.array([0.0, 0.0, t * 1e-3]), axis=1)))
    label = f"slab {t:g} mm on a rigid base, {edge_mm:g} mm edges, sphere R {sphere_mm:g} mm {depth_mm:g} mm in"
    return Case("slab", label, mesh, top, 1e-5, sphere_mm * 1e-3, depth_mm * 1e-3, poisson)


def with_lesion(case: Case, below_mm: float = LESION["below_mm"], radius_mm: float = LESION["radius_mm"],
                factor: float = LESION["factor"]) -> Case:
    """The case with a lesion `factor` times as stiff, `radius_mm`, its centre `below_mm` under the pressed vertex."""
    centre = case.mesh.vertices[case.vertex] - np.array([0.0, 0.0, below_mm * 1e-3])
    label = f"{case.label}, lesion E x {factor:g}, R {radius_mm:g} mm, {below_mm:g} mm below"
    return replace(case, name="lesion", label=label, lesion=Lesion(tuple(float(c) for c in centre), radius_mm * 1e-3, factor))


def fem_young(case: Case) -> np.ndarray | float:
    """The reference's Young's modulus [Pa]: one, or one a tet (the lesion's where the tet's centroid is inside it)."""
    if case.lesion is None:
        return E
    tets = case.mesh.tetrahedra.astype(np.int64)
    centroid = case.mesh.vertices[tets].mean(axis=1)
    inside = np.linalg.norm(centroid - np.asarray(case.lesion.center), axis=1) <= case.lesion.radius
    return E * np.where(inside, case.lesion.stiffness_factor, 1.0)


def fem_force(case: Case, steps_per_mm: float = FEM_TIGHT["steps_per_mm"], rtol: float = FEM_TIGHT["rtol"],
              gap_rtol: float = FEM_TIGHT["gap_rtol"]) -> dict:
    """The reference's static force on the sphere: {fem_N, fem_s, fem_steps}; where Newton does not converge in
    the load steps asked (at least 4), once more in twice as many; {fem_N: None, fem_error} if that fails too."""
    from . import fem_nonlinear as fnl

    x, tets = case.mesh.vertices, case.mesh.tetrahedra.astype(np.int64)
    fixed = np.zeros((len(x), 3), dtype=bool)
    fixed[x[:, 2] < case.fixed_below] = True
    sphere = fnl.Sphere(case.sphere, case.depth, tuple(x[case.vertex, :2]))
    steps = max(4, math.ceil(case.depth * 1e3 * steps_per_mm - 1e-9))
    t0 = time.perf_counter()
    for attempt in (steps, 2 * steps):
        try:
            ref = fnl.solve(x, tets, young=fem_young(case), poisson=case.poisson, fixed=fixed, sphere=sphere, steps=attempt,
                            rtol=rtol, gap_rtol=gap_rtol)
            return {"fem_N": ref.force, "fem_s": time.perf_counter() - t0, "fem_steps": attempt}
        except RuntimeError as exc:
            error = f"{exc} ({attempt} load steps)"
    return {"fem_N": None, "fem_s": time.perf_counter() - t0, "fem_error": error}


def p2p0_force(case: Case) -> dict:
    """The locking-free linear reference (fem.sphere_press: quadratic tets with a constant pressure, P2/P0,
    exact frictionless contact along z; small strain, no lesion): {p2p0_N, p2p0_s}. Beside the neo-Hookean
    P1 reference, which locks as nu -> 1/2 on coarse tets, it tells locking from a law's own error."""
    from . import fem

    x, tets = case.mesh.vertices, case.mesh.tetrahedra.astype(np.int64)
    t0 = time.perf_counter()
    ref = fem.sphere_press(x, tets, young=E, poisson=case.poisson, sphere_radius=case.sphere, depth=case.depth,
                           centre_xy=tuple(x[case.vertex, :2]), fixed=lambda n: fem.clamped_below(n, case.fixed_below), mixed=True)
    return {"p2p0_N": ref.force, "p2p0_s": time.perf_counter() - t0}


def law_integrator(law: str) -> str:
    """The integrator a law is pressed with: implicit where it has one, else its first."""
    entry = law_entry(law)
    return "implicit" if entry.has(integrator="implicit") else entry.integrators[0]


def law_press(case: Case, law: str, device="cpu", rings="global", timing_budget_s: float | None = None) -> dict:
    """One press of `case` under tissue `law` (PRESS): {integrator, force_N (end of the hold), inverted_tets
    (then), region_vertices, seconds (model, press), step_us (the median step with the sphere held at the
    depth, where a budget is given; else None)}; {integrator, error} where the law cannot model the case
    or the press diverges."""
    from ..protocol.palpation import Palpation
    from .continuum import held_step_us

    integrator = law_integrator(law)
    t0 = time.perf_counter()
    material = case.material()
    try:
        scales = {} if case.lesion is None else case.lesion.model_scales(case.mesh, material, law)
        pal = Palpation(case.mesh, material, rings=rings, law=law, integrator=integrator, dt=PRESS["dt"], device=device,
                        fixed_below=case.fixed_below, probe_radius=case.sphere, **scales)
        pal.touch(case.vertex, case.depth)
        result = pal.press(case.depth, ramp=PRESS["ramp"], hold=PRESS["hold"], settle=PRESS["dt"])
        seconds = time.perf_counter() - t0
        step_us = held_step_us(pal, case.depth, timing_budget_s) if timing_budget_s else None
    except (ValueError, RuntimeError) as exc:  # a law without kernels for this, or a press that ran away: reported
        return {"integrator": integrator, "error": f"{type(exc).__name__}: {exc}"}
    simulated = case.mesh.vertex_count if pal.region is None else pal.region_vertices
    return {"integrator": integrator, "force_N": result.hold_force_N, "inverted_tets": result.inverted_tets,
            "region_vertices": simulated, "seconds": seconds, "step_us": step_us}


def press_laws(case: Case, device="cpu", fem: dict | None = None, timing_budget_s: float | None = None, tasks=None,
               linear: bool = False) -> dict:
    """`case` under the reference (fem_force with `fem`'s keywords; with `linear`, p2p0_force too) and every
    law's global model: {case, label, vertices, tets, fem_N, fem_s, [p2p0_N, p2p0_s,] laws: {law: law_press's
    dict + of_fem (force / FEM) [+ of_p2p0]}}."""
    _step(tasks, f"depth, layers and lesions: FEM, {case.label}", 3)
    row = {"case": case.name, "label": case.label, "vertices": case.mesh.vertex_count, "tets": case.mesh.tet_count,
           "sphere_mm": case.sphere * 1e3, "depth_mm": case.depth * 1e3, **fem_force(case, **(fem or {})), "laws": {}}
    if linear:
        row.update(p2p0_force(case))
    for law in LAWS:
        _step(tasks, f"depth, layers and lesions: {law}, {case.label}")
        press = law_press(case, law, device, timing_budget_s=timing_budget_s)
        press["of_fem"] = _ratio(press.get("force_N"), row["fem_N"])
        if linear:
            press["of_p2p0"] = _ratio(press.get("force_N"), row["p2p0_N"])
        row["laws"][law] = press
    return row


def lesion_row(free: dict, stiff: dict) -> dict:
    """The lesion's row: `stiff` (press_laws with the lesion) with each force ratio over `free`'s (without it):
    fem_ratio, and per law ratio and ratio_of_fem (its ratio over the FEM's)."""
    row = {**stiff, "fem_N_without": free["fem_N"], "fem_ratio": _ratio(stiff["fem_N"], free["fem_N"]), "laws": {}}
    for law, press in stiff["laws"].items():
        ratio = _ratio(press.get("force_N"), free["laws"][law].get("force_N"))
        row["laws"][law] = {**press, "force_N_without": free["laws"][law].get("force_N"), "ratio": ratio,
                            "ratio_of_fem": _ratio(ratio, row["fem_ratio"])}
    return row


def region_rows(case: Case, deep: dict, rings, device, timing_budget_s, tasks=None) -> list[dict]:
    """Each law's local regions of `rings` on the deep press and its global model (from `deep`, press_laws's row):
    {law, rings, region_vertices, force_N, step_us, inverted_tets, error_vs_fem_pct, error_vs_global_pct}."""
    rows = []
    for law in LAWS:
        glob = deep["laws"][law]
        for r in rings:
            _step(tasks, f"depth, layers and lesions: {law}, {r} rings")
            rows.append({"law": law, "rings": r, **law_press(case, law, device, rings=r, timing_budget_s=timing_budget_s)})
        rows.append({"law": law, "rings": "global", **glob})
        for row in rows[-len(rings) - 1:]:
            row["error_vs_fem_pct"] = _pct(row.get("force_N"), deep["fem_N"])
            row["error_vs_global_pct"] = _pct(row.get("force_N"), glob.get("force_N"))
    return rows


def summarise(cases: list[dict]) -> dict:
    """Per law: its force / FEM on each case (slabs in order; over P2/P0 too), the lesion's ratio over the FEM's,
    the slabs' spread (max / min - 1 of its force across resolutions; the references' beside it), the most
    tets it leaves inverted, the cases it misses TARGETS on against the neo-Hookean FEM (a case it could not
    run counts as missed), and whether every slab is within the slab's bound of the locking-free P2/P0."""
    slabs = [c for c in cases if c["case"] == "slab"]
    out = {"fem_slab_spread": _spread([c["fem_N"] for c in slabs]), "p2p0_slab_spread": _spread([c.get("p2p0_N") for c in slabs])}
    for law in LAWS:
        pick = {name: [c["laws"][law] for c in cases if c["case"] == name] for name in TARGETS}
        missed = {c["case"] for c in cases if not _within(c, law)}
        misses = [name for name in TARGETS if name in missed]
        out[law] = {
            "slab_of_fem": [p.get("of_fem") for p in pick["slab"]],
            "slab_of_p2p0": _of_p2p0(pick["slab"]),
            "slab_spread": _spread([p.get("force_N") for p in pick["slab"]]),
            "deep_of_fem": next((p.get("of_fem") for p in pick["deep"]), None),
            "lesion_ratio_of_fem": next((p.get("ratio_of_fem") for p in pick["lesion"]), None),
            "inverted_tets": max((c["laws"][law].get("inverted_tets") or 0 for c in cases), default=0),
            "misses": misses,
            "slab_within_p2p0": all(x is not None and abs(x - 1.0) <= TARGETS["slab"] for x in _of_p2p0(pick["slab"])),
        }
    return out


def _of_p2p0(slabs: list[dict]) -> list:
    """A law's force over the P2/P0 solve's on each slab (None where either is missing)."""
    return [p.get("of_p2p0") for p in slabs]


def _within(case_row: dict, law: str) -> bool:
    # whether `law` is within its case's target (TARGETS) of the reference
    press = case_row["laws"][law]
    value = press.get("ratio_of_fem") if case_row["case"] == "lesion" else press.get("of_fem")
    return value is not None and abs(value - 1.0) <= TARGETS[case_row["case"]]


def count_tasks(settings) -> int:
    d, n = settings.depth, len(LAWS)
    cases = len(d.slab_edges_mm) + 3  # the slabs, the deep press, the lesion's ball with and without it
    return cases * (3 + n) + n * len(d.rings)


def run_depth_layers(settings, device, tasks) -> dict:
    """The section: every law on the slabs of settings.depth.slab_edges_mm, the deep press and the lesion on
    the ball of settings.depth.ball_edge_mm (its deep press timed, and its local regions of settings.depth.rings),
    against the reference of settings.depth's load steps and tolerances."""
    d = settings.depth
    fem = dict(steps_per_mm=d.fem_steps_per_mm, rtol=d.fem_rtol, gap_rtol=d.fem_gap_rtol)
    cases = [press_laws(slab_case(h), device, fem, tasks=tasks, linear=True) for h in d.slab_edges_mm]
    deep_case = ball_case(d.ball_edge_mm)
    deep = press_laws(deep_case, device, fem, settings.timing_budget_s, tasks)
    regions = region_rows(deep_case, deep, d.rings, device, settings.timing_budget_s, tasks)
    free_case = ball_case(d.ball_edge_mm, LESION["depth_mm"])
    free = press_laws(free_case, device, fem, tasks=tasks)
    cases += [deep, lesion_row(free, press_laws(with_lesion(free_case), device, fem, tasks=tasks))]
    return {"laws": list(LAWS), "cases": cases, "regions": regions, "summary": summarise(cases), "targets": TARGETS,
            "fem": fem, "press": PRESS, "young_Pa": E, "poisson": POISSON}


def _step(tasks, label: str, weight: int = 1) -> None:
    if tasks is not None:
        tasks.step(label, weight)


def _ratio(a, b):
    """a / b, None where either is missing."""
    return None if a is None or b is None else float(a) / float(b)


def _pct(a, b):
    """100 (a / b - 1), None where either is missing."""
    r = _ratio(a, b)
    return None if r is None else 100.0 * (r - 1.0)


def _spread(forces):
    """max / min - 1 of two or more forces; None for fewer or a missing one."""
    if len(forces) < 2 or any(f is None for f in forces):
        return None
    return float(max(forces) / min(forces) - 1.0)
