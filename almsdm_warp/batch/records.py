"""Rows for learning, opt-in: what a press records beyond its peak and hold forces.

- the force curve: the feedback force sampled at `curve_points` depths along the ramp (sample k at the
  first step whose depth reaches (k + 1) / curve_points of the press's; the last at full depth), the
  same force the peak is taken from (kernels/probes/press.py's record_curve);
- with a sphere (explicit integrator), at the end of the hold (the force hold_force_N is): the contact
  patch's area (each vertex in contact, its share of the surface) and a tactile map, the contact
  pressure on a `tactile_size` x `tactile_size` grid over the sphere's footprint (the square of side
  2 x radius centred on the press axis, normal to it; axes footprint_frame's e1 and e2, rows along e2),
  each vertex's contact force along the press into the cell over which it lies, over the cell's area;
- per press, the lesion's label (lesion_labels): whether the lesion lies in the probe's footprint and
  the contact point's distance to the lesion's surface.

The records are made by the batch kernels only when asked for (a kernel variant of their own): a
press without them runs the same code as before, at the same speed, to the same bits. The force curve:
every batch kernel (exact and fast explicit, implicit); the patch and map: the exact explicit kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CURVE_MAX = 1024
"""The most samples of a force curve (and cells of a tactile map's side) a press takes."""

UNITS = {
    "force_curve_N": ("N", "feedback force at each sample of the ramp (sample k at (k + 1) / curve_points of the depth, "
                           "or the first step past it); the last at full depth"),
    "force_curve_depth_mm": ("mm", "the probe's depth at each sample of force_curve_N"),
    "patch_area_mm2": ("mm^2", "surface area of the vertices the sphere touches at the end of the hold"),
    "tactile_map_kPa": ("kPa", "contact pressure at the end of the hold on an n x n grid over the sphere's footprint "
                               "(side 2 x radius, row-major, rows along e2: docs/datasets.md)"),
    "lesion_in_footprint": ("", "1 where the lesion reaches into the cylinder of the probe's radius around the press axis, "
                                "from the contact point inward, else 0 (0 for the baseline)"),
    "lesion_distance_mm": ("mm", "distance from the contact point to the lesion's surface (negative inside; NaN for the baseline)"),
}
"""Each record column's unit and meaning (a dataset's schema)."""


@dataclass(frozen=True)
class Records:
    """Which learning records a press keeps (all off: the default table)."""

    curve_points: int = 0
    """Samples of the force curve along the ramp (0: none)."""
    tactile_size: int = 0
    """n of the n x n tactile map, with the contact patch's area (0: neither; needs a sphere)."""
    lesion_labels: bool = False
    """The lesion's label of each press (a dataset's items, whose lesion is known)."""

    @property
    def on(self) -> bool:
        """Whether the batch kernels record anything (the force curve or the patch and map)."""
        return self.curve_points > 0 or self.tactile_size > 0

    def check(self, probe_radius: float = 0.0, integrator: str = "explicit", where: str = "",
              names=("curve_points", "tactile_size")) -> "Records":
        """ValueError for records the press cannot make: a count out of range, a map without a sphere
        or on the implicit integrator. `where` starts each message; `names`: the two counts' names there."""
        for name, shown in zip(("curve_points", "tactile_size"), names):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= CURVE_MAX:
                raise ValueError(f"{where}{shown} must be an integer in 0..{CURVE_MAX}, got {value!r}")
        if self.tactile_size and not probe_radius > 0:
            raise ValueError(f"{where}{names[1]} {self.tactile_size}: the patch and tactile map need a spherical probe "
                             f"(a probe radius > 0), not the paper's point probe")
        if self.tactile_size and integrator != "explicit":
            raise ValueError(f"{where}{names[1]} {self.tactile_size}: the patch and tactile map are recorded by the "
                             f"explicit integrator only, not {integrator!r}")
        return self

    def dtypes(self, lesion: bool = False) -> dict:
        """The record columns' dtypes (export/tables.py), in table order; `lesion`: the lesion labels' too."""
        out = {}
        if self.curve_points:
            out |= {"force_curve_N": f"float64[{self.curve_points}]", "force_curve_depth_mm": f"float64[{self.curve_points}]"}
        if self.tactile_size:
            out |= {"patch_area_mm2": "float64", "tactile_map_kPa": f"float64[{self.tactile_size ** 2}]"}
        if lesion and self.lesion_labels:
            out |= {"lesion_in_footprint": "int64", "lesion_distance_mm": "float64"}
        return out


def curve_steps(ramp_steps: int, points: int) -> np.ndarray:
    """The step after which each sample of the force curve is taken (kernels/probes/press.py's curve_slot):
    the first of the ramp whose depth (step + 1) / ramp_steps reaches (k + 1) / points, int64 [points]."""
    k = np.arange(1, points + 1, dtype=np.int64)
    return -(-k * ramp_steps // points) - 1


def footprint_frame(direction) -> tuple[np.ndarray, np.ndarray]:
    """The tactile map's axes (e1, e2) for a press along the unit `direction` (the kernel's footprint_frame):
    e1 = direction x (x axis, or y where |direction_x| > 0.9), normalized; e2 = direction x e1."""
    d = np.asarray(direction, dtype=np.float64)
    axis = np.array([0.0, 1.0, 0.0]) if abs(d[0]) > 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(d, axis)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(d, e1)


def lesion_labels(points, directions, center, radius: float, probe_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(in footprint: int64 0/1, distance to the lesion's surface [m], negative inside) of presses at
    `points` [m] along the unit `directions` (inward), for a spherical lesion (`center` [m], `radius` [m])
    and a probe of `probe_radius` [m]. In the footprint: the lesion's ball meets the solid half-cylinder
    of the probe's radius around the press axis, from the contact point inward (for the paper's point
    probe, radius 0: the half-axis itself)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(center, dtype=np.float64) - p
    along = np.einsum("ij,ij->i", r, d)
    off_axis = np.maximum(np.linalg.norm(r - along[:, None] * d, axis=1) - probe_radius, 0.0)
    # the centre's distance to the half-cylinder: beside it where along >= 0, else to its end disc
    gap = np.where(along >= 0.0, off_axis, np.hypot(along, off_axis))
    return (gap < radius).astype(np.int64), np.linalg.norm(r, axis=1) - radius


def lesion_columns(mesh, vertices, lesion, probe_radius: float) -> dict:
    """lesion_in_footprint and lesion_distance_mm (people's units) of presses at `vertices` of `mesh` (each at its
    rest position, along its inward rest normal) for `lesion` (tissue.lesion.Lesion; None: the baseline's 0 and NaN)."""
    from ..export.tables import millimetres
    from ..sim.model import vertex_normals

    n = len(vertices)
    if lesion is None:
        return {"lesion_in_footprint": np.zeros(n, dtype=np.int64), "lesion_distance_mm": np.full(n, np.nan)}
    inward = -vertex_normals(mesh.vertices, mesh.triangles)[vertices]
    inside, distance = lesion_labels(mesh.vertices[vertices], inward, lesion.center, lesion.radius, probe_radius)
    return {"lesion_in_footprint": inside, "lesion_distance_mm": millimetres(distance)}


class BatchRecordArrays:
    """A BatchPalpation's learning records on its device (kernels/arrays.py's BatchRecords) and their read-back."""

    def __init__(self, records: Records | None, batch):
        import warp as wp

        self.spec = records or Records()
        self.on = self.spec.on
        self.batch = batch
        area = np.zeros(1, dtype=np.float32)
        if self.spec.tactile_size:
            from ..tissue.material import vertex_areas

            mesh = batch.model.mesh
            area = vertex_areas(mesh.vertices, mesh.triangles).astype(np.float32)
        self.vertex_area = batch.buffers.upload("records.vertex_area", area, wp.float32)
        self.allocate(1)

    def allocate(self, batch_size: int) -> None:
        """The record arrays for `batch_size` presses, zeroed (placeholders of one element where off)."""
        import warp as wp

        from ..kernels.arrays import BatchRecords

        a = self.batch.buffers.array
        n, m = self.spec.curve_points, self.spec.tactile_size
        out = BatchRecords()
        out.curve_points, out.map_size = n, m
        out.force_curve = a("records.force_curve", (batch_size if n else 1, max(n, 1)), wp.vec3)
        out.tactile = a("records.tactile", (batch_size if m else 1, max(m * m, 1)), wp.float64)
        out.patch_area = a("records.patch_area", batch_size if m else 1, wp.float64)
        out.vertex_area = self.vertex_area
        self.arrays = out

    def check_press(self, ramp_steps: int) -> None:
        """ValueError where the ramp has fewer steps than the curve has samples."""
        if self.spec.curve_points > ramp_steps:
            raise ValueError(f"curve_points {self.spec.curve_points}: the ramp has only {ramp_steps} step(s); "
                             f"ask for at most {ramp_steps} samples, or a longer ramp")

    def read(self, depth: float, ramp_steps: int, host_copy) -> dict:
        """The records of the press just done, host arrays a row a press (SI: N, m, m^2, Pa); host_copy(array):
        a device array's host copy (batch_palpation.host_copy: on the current stream, not the null stream)."""
        out = {}
        if self.spec.curve_points:
            f = host_copy(self.arrays.force_curve).astype(np.float64)
            out["force_curve"] = np.sqrt(f[..., 0] ** 2 + f[..., 1] ** 2 + f[..., 2] ** 2)  # result_from's magnitudes
            steps = curve_steps(ramp_steps, self.spec.curve_points)
            out["curve_depth"] = np.broadcast_to(depth * ((steps + 1) / ramp_steps), f.shape[:2]).copy()
        if self.spec.tactile_size:
            side = 2.0 * self.batch.probe_radius / self.spec.tactile_size
            out["patch_area"] = host_copy(self.arrays.patch_area)
            out["tactile"] = host_copy(self.arrays.tactile) / (side * side)
        return out


def record_columns(records: dict) -> dict:
    """Table columns (people's units, export/tables.py) of BatchRecordArrays.read's arrays."""
    from ..export.tables import millimetres

    names = {"force_curve": ("force_curve_N", 1.0), "patch_area": ("patch_area_mm2", 1e6), "tactile": ("tactile_map_kPa", 1e-3)}
    out = {names[k][0]: v * names[k][1] for k, v in records.items() if k in names}
    if "curve_depth" in records:
        out["force_curve_depth_mm"] = millimetres(records["curve_depth"])
    return out
