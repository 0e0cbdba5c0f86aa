"""Model (static, on the device), State (what each step changes) and Control (the probe).

As in Newton: a Model is made once from a mesh and tissue parameters; ``model.state()`` gives a
State at rest; a solver steps ``state_in`` to ``state_out`` under a ``Control``.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..kernels.arrays import ProbeArrays, ProbeSphereArrays, TissueArrays, struct_from
from ..kernels.laws.tets import TetRest
from ..mesh.device_mesh import as_device_mesh
from ..mesh.topology import corner_cross
from ..tissue.laws import law_entry, resolve_law, tet_entry_tets
from ..tissue.material import Material, damping, springs_for_mesh
from ..tissue.params import TissueParams

PROBE_OFF = 0
"""The probe does not touch: every free vertex moves under the tissue's forces alone."""
PROBE_DISPLACEMENT = 1
"""The probe drives its vertex to `probe_target`; the reaction is the sum of internal forces on it."""
PROBE_FORCE = 2
"""The probe pushes its vertex with `probe_force`, which then moves freely."""
PROBE_SPHERE = 3
"""The probe is a rigid sphere (centre `probe_target`, radius `probe_radius`): frictionless one-sided
contact on every free surface vertex it would contain; the reaction is the sum of the contact
reactions (kernels/probes/sphere.py)."""


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted outward vertex normals of a surface (unit length; zero where no face), host."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    face_n = np.stack(corner_cross(v, t)[0], axis=1) if len(t) else np.zeros((0, 3))  # |n| = 2 x area
    # each vertex's faces summed as np.add.at over corners 0, 1, 2 in turn sums them (bincount adds in input order)
    corners = t.T.reshape(-1)
    n = np.stack([np.bincount(corners, np.tile(face_n[:, k], 3), minlength=len(v)) for k in range(3)], axis=1)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def check_factors(values, count: int, name: str, each: str, rule: str = ">= 0") -> np.ndarray:
    """`values` as `count` float64 multipliers (a lesion's, an anchor's area), each finite, `rule` (">= 0" or
    "> 0") and 0 or of the magnitude every parameter is held to (checks.MAGNITUDE); else ValueError naming
    `name`, the first bad one and its value."""
    from ..checks import MAGNITUDE

    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(v) != count:
        raise ValueError(f"{name} must be {count} factors (one {each}), got {len(v)}")
    lo, hi = MAGNITUDE
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(v) & ((v > 0) if rule == "> 0" else (v >= 0)) & ((v == 0) | ((np.abs(v) >= lo) & (np.abs(v) <= hi)))
    bad = np.flatnonzero(~ok)
    if len(bad):
        raise ValueError(f"{name} must be finite factors {rule}, 0 or of magnitude {lo:g} to {hi:g}: "
                         f"{name}[{int(bad[0])}] = {float(v[bad[0]])!r}")
    return v


class Model:
    """The static tissue model on one device: rest shape, topology, masses, springs, anchors."""

    def __init__(self, mesh, tissue=None, device=None, *, edge_scale=None, anchor_scale=None, fixed_below=None,
                 support=None, anchors=None, law: str | None = None, element_scale=None):
        """mesh: TissueMesh or DeviceMesh. tissue: TissueParams (the paper's per-spring constants, SI;
        default: the stomach scene's) or Material (every spring, anchor, damper and mass derived per
        edge and vertex by tissue.material.springs_for_mesh).

        edge_scale [edge_count] and anchor_scale [vertex_count]: optional multipliers of stiffness
        per spring and per anchor (a stiffer lesion, `Lesion.scales`), on top of either tissue; the
        paper's dampers scale with them, a material's follow the scaled springs by its damping law.
        fixed_below [m]: every vertex with z below it is supported (fixed); support: vertex ids, also
        fixed. anchors: keep the anchor springs k_i (True), drop them (False), or None: dropped on a
        supported tet mesh (the support holds it), kept otherwise; the vertex dampers d_i stay (with
        a material they hold the mass-proportional Rayleigh damping). law: the tissue law, a key of
        almsdm_warp.tissue.laws.LAWS (its kernels' functions, critical step and stiffness bound);
        None: stable neo-Hookean tets for a material on a tet mesh, springs otherwise (default_law).
        element_scale [tet_count]: a volumetric law's multiplier of each tet's moduli (a lesion,
        `Lesion.model_scales`); edge_scale and anchor_scale are the springs law's.
        """
        self.dmesh = dm = as_device_mesh(mesh, device)
        self.mesh = dm.mesh
        self.device = dm.device
        self.tissue = t = tissue if tissue is not None else TissueParams()
        if not isinstance(t, (TissueParams, Material)):
            raise TypeError(f"tissue must be a TissueParams or a Material, got {type(t).__name__}")
        self.law_entry = law_entry(resolve_law(law, self.mesh, t))
        self.law = self.law_entry.name
        """The tissue law's name: the step kernels are made for it (kernels/laws)."""
        if self.law_entry.check is not None:
            self.law_entry.check(self.law, self.mesh, t)
        n, e = dm.vertex_count, dm.edge_count
        self.particle_count = n
        self.spring_count = e
        self._set_support(fixed_below, support)
        if anchors is None:
            anchors = not (self.support_count and self.mesh.tet_count)
        ke, kd, ka, da, mass = self._tissue_constants(t)
        if np.any(mass <= 0):
            bad = int(np.flatnonzero(mass <= 0)[0])
            raise ValueError(f"vertex {bad} has mass {mass[bad]:.3g} kg: it belongs to no element with area or volume")
        es = np.ones(e) if edge_scale is None else check_factors(edge_scale, e, "edge_scale", "an edge")
        an = np.ones(n) if anchor_scale is None else check_factors(anchor_scale, n, "anchor_scale", "a vertex")
        if isinstance(t, Material):  # the dampers follow the scaled springs by the material's law
            ke, ka = ke * es, ka * an
            kd, da = damping(t, self.mesh.edges, ke, ka, mass)
        else:
            ke, kd, ka, da = ke * es, kd * es, ka * an, da * an
        ka = ka * float(bool(anchors))
        d = self.device
        self.particle_mass_host = mass
        self.particle_mass = wp.array(mass, dtype=wp.float32, device=d)
        """Lumped vertex mass [kg], shape [particle_count], float32."""
        self.particle_q_rest = dm.rest_position
        """Rest positions [m], shape [particle_count], vec3."""
        self.anchor_ke = wp.array(ka, dtype=wp.float32, device=d)
        """Anchor stiffness k_i [N/m], shape [particle_count], float32, eq. (3)."""
        self.anchor_kd = wp.array(da, dtype=wp.float32, device=d)
        """Anchor damping d_i [N s/m], shape [particle_count], float32, eq. (3)."""
        self.spring_ke = wp.array(ke, dtype=wp.float32, device=d)
        """Spring stiffness k_ij [N/m], shape [spring_count], float32, eqs. (4)-(5)."""
        self.spring_kd = wp.array(kd, dtype=wp.float32, device=d)
        """Spring damping d_ij [N s/m], shape [spring_count], float32, eq. (6)."""
        self.spring_rest_length = dm.edge_rest_length
        """Spring rest length [m], shape [spring_count], float32."""
        _, _, adj_edge = self.mesh.adjacency
        per_entry = np.stack([ke, kd, self.mesh.edge_rest_length], axis=1)[adj_edge]
        self.adj_spring = wp.array(per_entry, dtype=wp.vec3, device=d)
        """(k_ij [N/m], d_ij [N s/m], rest length [m]) of the spring of each CSR adjacency entry, shape
        [2 * spring_count], vec3: the step reads one vector per neighbour, not three arrays by edge id."""
        self.vertex_normal_rest = vertex_normals(self.mesh.vertices, self.mesh.triangles)
        """Outward unit normal of each surface vertex at rest (host, float64): the press direction."""
        self.arrays = struct_from(
            TissueArrays, self, q_rest=dm.rest_position, adj_offsets=dm.adj_offsets, adj_vertex=dm.adj_vertex, adj_edge=dm.adj_edge
        )
        """The arrays above as one kernel argument (kernels/arrays.py)."""
        self.spring_ke_host, self.spring_kd_host, self.anchor_ke_host, self.anchor_kd_host = ke, kd, ka, da
        """The constants above in float64 (host), as derived: the law's critical step reads them."""
        self._set_entries(edge_scale is not None or anchor_scale is not None, element_scale)

    def _set_entries(self, scaled: bool, element_scale) -> None:
        volumetric = self.law_entry.volumetric
        if volumetric and scaled:
            raise ValueError(f"the {self.law} law takes a lesion as per-tet scales (element_scale), not per-spring or per-anchor ones")
        if element_scale is not None:
            if not volumetric:
                raise ValueError(f"element_scale scales a volumetric law's tets; the {self.law} law takes edge_scale and anchor_scale")
            element_scale = check_factors(element_scale, self.mesh.tet_count, "element_scale", "a tet", "> 0")
        self.element_scale = element_scale
        """Each tet's modulus factor (a volumetric law's lesion), or None."""
        self.entry_offsets, self.entry_topology, self.entry_params = self.law_entry.entries(self)
        """Each vertex's entries that its law's vertex_force gathers (kernels/laws): CSR offsets
        [particle_count + 1], and per entry its topology and parameters, typed by the law (the springs
        law: the CSR adjacency, each neighbour and its spring's constants; the neo-Hookean law: the
        incident tets)."""
        self.nodal_pressure = wp.zeros(self.particle_count if volumetric else 1, dtype=wp.float32, device=self.device)
        """Each vertex's nodal pressure [Pa] (a volumetric law's, kernels/laws/neo_hookean.py), as the last
        step's pressure pass left it over its region's vertices (0 elsewhere: at rest); one zero for springs."""
        self.entries = self.law_entry.kernels.Entries()
        """The four above as one kernel argument (the law's Entries struct)."""
        self.entries.offsets, self.entries.topology, self.entries.params = self.entry_offsets, self.entry_topology, self.entry_params
        self.entries.pressure = self.nodal_pressure

    def entry_tets(self):
        """A tet law's (entry_tet, tet_corners, tet_rest) on the device (tissue.laws.tet_entry_tets), made on first use."""
        if getattr(self, "_entry_tets", None) is None:
            entry_tet, tets, rest = tet_entry_tets(self)
            d = self.device
            self._entry_tets = (wp.array(entry_tet, dtype=wp.int32, device=d), wp.array(tets, dtype=wp.vec4i, device=d),
                                wp.array(rest, dtype=TetRest, device=d))
        return self._entry_tets

    def _tissue_constants(self, t):
        """(k_ij, d_ij per edge; k_i, d_i, m_i per vertex), float64 host arrays, from either tissue."""
        n, e = self.particle_count, self.spring_count
        if isinstance(t, Material):
            s = springs_for_mesh(self.mesh, t)
            return s.edge_stiffness, s.edge_damping, s.anchor_stiffness, s.anchor_damping, s.vertex_mass
        mass = self.mesh.vertex_masses(t.density, t.thickness)
        return (np.full(e, t.edge_stiffness), np.full(e, t.edge_damping), np.full(n, t.anchor_stiffness),
                np.full(n, t.anchor_damping), mass)

    def _set_support(self, fixed_below, support) -> None:
        n = self.particle_count
        mask = np.zeros(n, dtype=bool)
        if fixed_below is not None:
            z = float(fixed_below)
            if not np.isfinite(z):
                raise ValueError(f"fixed_below must be a finite height [m], got {fixed_below!r}")
            mask |= self.mesh.vertices[:, 2] < z
        if support is not None:
            ids = np.asarray(support).reshape(-1)
            if ids.size and (not np.issubdtype(ids.dtype, np.integer) or ids.min() < 0 or ids.max() >= n):
                raise ValueError(f"support must be vertex ids in 0..{n - 1}, got {ids[:5].tolist()}...")
            mask[ids.astype(np.int64)] = True
        if mask.all():
            raise ValueError(f"every vertex is supported (fixed_below = {fixed_below!r} m is above the whole mesh): nothing can move")
        self.fixed_below = None if fixed_below is None else float(fixed_below)
        """The support plane's height [m] (vertices with z below it are fixed), or None."""
        self.support_mask = mask
        """Host: True for each supported (fixed) vertex, shape [particle_count], bool; solvers never move them."""
        self.support_count = int(mask.sum())

    def state(self) -> "State":
        """A State at rest."""
        return State(self)

    def control(self) -> "Control":
        """A Control for this model's vertices (the sphere may touch the surface vertices)."""
        return Control(self.device, self.particle_count, self.mesh.surface_vertices)

    def critical_dt(self, vertices=None, anchors: bool = True) -> float:
        """Largest stable step [s] of semi-implicit Euler over the free `vertices` (default: all; the
        others held fixed), linearized at rest: the tissue law's (almsdm_warp.tissue.laws)."""
        return self.law_entry.critical_dt(self, vertices, anchors)

    def stiffness_bound(self) -> float:
        """The stiffest vertex's stiffness [N/m] (the tissue law's): what bounds a force that has not diverged."""
        return self.law_entry.stiffness_bound(self)


class State:
    """Positions and velocities of every mesh vertex; a step writes only the free region vertices."""

    def __init__(self, model: Model):
        d = model.device
        self.particle_q = wp.clone(model.particle_q_rest)
        """Positions [m], shape [particle_count], vec3."""
        self.particle_qd = wp.zeros(model.particle_count, dtype=wp.vec3, device=d)
        """Velocities [m/s], shape [particle_count], vec3."""


class Control:
    """The probe: which vertex it holds, how (off / displacement / force), where or how hard.

    The step writes the reaction into `probe_reaction`, so the feedback force can be read each
    step through a view kept across steps (``control.reaction_view()``), with no copy on the CPU.
    """

    def __init__(self, device, particle_count: int = 1, surface_vertices=None):
        """surface_vertices: the mesh ids a spherical probe may touch (default none)."""
        self.device = device
        self.probe_vertex = wp.full(1, -1, dtype=wp.int32, device=device)
        """Mesh id of the vertex the probe holds, shape [1], int32 (-1: none)."""
        self.probe_mode = wp.zeros(1, dtype=wp.int32, device=device)
        """PROBE_OFF, PROBE_DISPLACEMENT or PROBE_FORCE, shape [1], int32."""
        self.probe_target = wp.zeros(1, dtype=wp.vec3, device=device)
        """Target position of the held vertex [m] (displacement mode), shape [1], vec3."""
        self.probe_move = wp.zeros(2, dtype=wp.vec3d, device=device)
        """The frame's move [m] in float64: [0] where it starts (the last frame's target), [1] its
        target (probe_target before rounding to float32), shape [2], vec3d. A frame of n > 1 substeps
        sets probe_target to (s + 1) / n of this move before substep s (kernels/explicit/step.py)."""
        self.probe_reaction_peak = wp.zeros(1, dtype=wp.vec3, device=device)
        """Output: the largest probe_reaction over a frame's substeps [N], shape [1], vec3 (written by
        frames of more than one step)."""
        self.probe_force = wp.zeros(1, dtype=wp.vec3, device=device)
        """Force the probe applies [N] (force mode), shape [1], vec3."""
        self.probe_reaction = wp.zeros(1, dtype=wp.vec3, device=device)
        """Output: sum of the tissue's internal forces on the held vertex [N], shape [1], vec3; in
        sphere mode the sum of the contact reactions."""
        self.probe_radius = wp.zeros(1, dtype=wp.float32, device=device)
        """Radius of the spherical probe [m] (sphere mode), shape [1], float32."""
        surface = np.zeros(max(int(particle_count), 1), dtype=np.int32)
        if surface_vertices is not None:
            surface[np.asarray(surface_vertices, dtype=np.int64)] = 1
        self.probe_surface = wp.array(surface, dtype=wp.int32, device=device)
        """1 for a vertex the sphere may touch (a surface vertex), else 0, shape [particle_count], int32."""
        self.probe_contact = wp.zeros(len(surface), dtype=wp.vec3, device=device)
        """Output: each free vertex's contact reaction [N] in sphere mode (zero off contact), shape
        [particle_count], vec3."""
        self.sphere = False
        """Host: True once a sphere is set; the explicit step then sums the contact reactions."""
        self.arrays = struct_from(ProbeArrays, self)
        self.sphere_arrays = struct_from(ProbeSphereArrays, self)
        """The probe's arrays as one kernel argument (kernels/arrays.py); the sphere's in sphere_arrays."""

    def set_sphere(self, radius: float) -> None:
        """A spherical probe of `radius` [m] > 0 (its centre is `probe_target` in sphere mode)."""
        radius = float(radius)
        if not (math.isfinite(radius) and radius > 0):
            raise ValueError(f"the probe's radius must be > 0 m and finite, got {radius}")
        self.probe_radius.fill_(radius)
        self.sphere = True

    def set(self, vertex: int | None = None, mode: int | None = None, target=None, force=None) -> None:
        """Update the probe from the host (small copies; the hot loop writes views instead)."""
        if vertex is not None:
            self.probe_vertex.fill_(int(vertex))
        if mode is not None:
            self.probe_mode.fill_(int(mode))
        if target is not None:
            self.probe_target.fill_(wp.vec3(*np.asarray(target, dtype=np.float32)))
        if force is not None:
            self.probe_force.fill_(wp.vec3(*np.asarray(force, dtype=np.float32)))
