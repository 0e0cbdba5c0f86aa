"""Recording a palpation to USD (usd-core, imported only here, only when a stage is written).

The stage, in millimetres (metersPerUnit 0.001), Z up, one time code per simulation step
(timeCodesPerSecond = 1 / dt; time code k is the state after k steps, 0 the rest shape):

    /Palpation                Xform, the default prim; customData: dt_s, record_every, mesh
      Organ                   Mesh: points, normals (vertex), extent, primvars:displacement_mm
                              (vertex, time-sampled), primvars:displayColor by ring (vertex),
                              almsdm:vertex_id (the mesh vertex of each point)
      RegionSprings           BasisCurves (linear, one 2-point curve per spring): points, widths
      Probe                   Sphere: xformOp:translate, almsdm:feedback_force_N (float3),
                              almsdm:feedback_force_magnitude_N (float); time-sampled

A volume mesh exports its surface (its surface vertices, in mesh order, as the points). Frames go
to the layer as they are recorded and nothing else keeps them; the layer is a crate (.usdc) file
saved whenever about `flush_mb` (64 MB) of samples have gathered, so the samples already written
live on disk, not in memory (a crate layer saves incrementally; each save also rewrites the
layer's tables, so saving often costs time and file size: 64 MB is a save every ~2000 frames of
the 1002-vertex stomach; docs/performance.md). A .usda target is exported from that crate at the
end. All of it is written under a temporary name beside the target and renamed when complete.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..protocol.stroke import ProbeStroke
from ..sim.model import PROBE_OFF, PROBE_SPHERE
from .output import atomic_path, discard, publish, temp_path

USD_SUFFIXES = (".usda", ".usdc", ".usd")

PLAIN_COLOR = (0.80, 0.62, 0.58)
"""Tissue outside the region."""
CONTACT_COLOR = (0.85, 0.10, 0.10)
FIXED_COLOR = (0.15, 0.35, 0.85)
"""The fixed outer ring."""
FREE_RAMP = ((0.95, 0.45, 0.10), (0.98, 0.85, 0.25))
"""Free rings 1.. from the first colour to the second."""
SPRING_COLOR = (0.10, 0.55, 0.20)


def check_usd_path(path) -> Path:
    """The target path, if its suffix is a USD one and its folder writable; else an InputError."""
    from .output import check_writable

    p = Path(path)
    if p.suffix.lower() not in USD_SUFFIXES:
        raise InputError(f"{p}: unknown USD suffix {p.suffix!r} (allowed: {', '.join(USD_SUFFIXES)})")
    return check_writable(p)


def usd_error_cause(exc) -> str:
    """The cause in a USD error stack (Tf.ErrorException: one line per error, each with its
    commentary quoted): the first error's commentary, from its last colon ("No space left on device")."""
    notes = re.findall(r" : '(.*)'\s*$", str(exc), flags=re.M)
    text = notes[0] if notes else " ".join(str(exc).split())
    return text.rsplit(": ", 1)[-1].strip() or text


def ring_colors(vertex_ring: np.ndarray, outer_ring: int) -> np.ndarray:
    """displayColor per vertex from its ring index (-1 outside): contact red, free rings orange to
    yellow, the fixed outer ring blue, the rest plain tissue. [n, 3] float32."""
    ring = np.asarray(vertex_ring)
    colors = np.tile(np.asarray(PLAIN_COLOR, dtype=np.float32), (len(ring), 1))
    free = (ring > 0) & (ring < outer_ring)
    if outer_ring > 1:
        t = ((ring[free] - 1) / max(outer_ring - 2, 1)).astype(np.float32)[:, None]
        a, b = (np.asarray(c, dtype=np.float32) for c in FREE_RAMP)
        colors[free] = (1 - t) * a + t * b
    colors[ring == 0] = CONTACT_COLOR
    if outer_ring > 0:
        colors[ring == outer_ring] = FIXED_COLOR
    return colors


class UsdRecorder:
    """Records a Palpation to a USD stage, one frame every `every` steps.

    Use it as a context manager (an exception discards the temporary file), record the rest
    shape with ``frame(0)``, then pass :meth:`on_press_step` to ``Palpation.press(record=...,
    record_every=every)``, or call ``frame(step)`` yourself after stepping.

        with UsdRecorder("press.usdc", pal, every=10) as rec:
            rec.frame(0)
            pal.press(0.01, record=rec.on_press_step, record_every=rec.every)
    """

    def __init__(self, path, palpation, *, every: int = 1, normals: str = "precomputed", probe_radius: float | None = None, flush_every: int | None = None, flush_mb: float = 64.0):
        try:
            from pxr import Sdf, Usd, UsdGeom, Vt  # usd-core (the `usd` extra): only here
        except ImportError as exc:
            raise ImportError("UsdRecorder needs usd-core: pip install 'almsdm_warp[usd]'") from exc

        from ..sim.normals import SurfaceNormals

        if not (isinstance(every, (int, np.integer)) and every >= 1):
            raise ValueError(f"every must be an int >= 1, got {every!r}")
        self._Usd, self._Vt, self._Sdf, self._UsdGeom = Usd, Vt, Sdf, UsdGeom
        self.path = check_usd_path(path)
        self.pal = pal = palpation
        self.every = int(every)
        self._flush_every = flush_every
        self._flush_bytes = flush_mb * 1e6
        # the drawn probe: the palpation's sphere, or a 2.5 mm marker on the paper's one-vertex probe
        sphere = float(getattr(pal, "probe_radius", 0.0) or 0.0)
        self.probe_radius = float(probe_radius) if probe_radius is not None else (sphere if sphere > 0 else 2.5e-3)
        mesh = pal.mesh
        self.normals = SurfaceNormals(pal.model.dmesh, pal.device, normals)
        # the exported points: the surface vertices (all of them on a surface mesh), in mesh order
        self.point_vertex = mesh.surface_vertices if mesh.is_volume else np.arange(mesh.vertex_count, dtype=np.int32)
        remap = np.full(mesh.vertex_count, -1, dtype=np.int64)
        remap[self.point_vertex] = np.arange(len(self.point_vertex))
        self._rest_mm = (mesh.vertices[self.point_vertex] * 1e3).astype(np.float32)
        self._base = 0  # steps taken by the presses before this one
        self._codes = set()  # the time codes written (a press pressed again writes its codes again)
        self._unsaved = 0
        self._last_code = None
        self._colors = None
        self._region_key = None
        self._spring_ends = None
        self._tmp = temp_path(self.path, ".tmp.usdc")
        from pxr import Tf

        try:
            self._layer = Sdf.Layer.CreateNew(str(self._tmp))
            if self._layer is None:
                raise InputError(f"{self.path}: USD could not create a layer at {self._tmp}")
            self._build_stage(remap[mesh.triangles])
        except Tf.ErrorException as exc:  # a full disk, a quota: one line, not USD's error stack
            self._discard()
            raise InputError(f"{self.path}: cannot write the USD stage: {usd_error_cause(exc)}") from None
        except BaseException:
            self._discard()
            raise

    # -- the stage's static part ---------------------------------------------------------------
    def _build_stage(self, faces):
        Usd, UsdGeom, Vt, Sdf = self._Usd, self._UsdGeom, self._Vt, self._Sdf
        pal = self.pal
        self.stage = stage = Usd.Stage.Open(self._layer)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, 0.001)
        stage.SetTimeCodesPerSecond(1.0 / pal.dt)
        stage.SetFramesPerSecond(1.0 / (pal.dt * self.every))
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(0)
        root = UsdGeom.Xform.Define(stage, "/Palpation")
        stage.SetDefaultPrim(root.GetPrim())
        data = {
            "dt_s": float(pal.dt),
            "record_every": self.every,
            "mesh": pal.mesh.name,
            "rings": str(pal.rings),
            "contact_vertex": int(pal.vertex),
            "integrator": pal.solver.integrator,
            "normals": self.normals.strategy,
        }
        if isinstance(pal, ProbeStroke):
            # a stroke touches many vertices on its way: the probe's path is the Probe prim's, no one vertex
            del data["contact_vertex"]
            data["probe"] = "stroke"
        root.GetPrim().SetCustomData(data)
        organ = self.organ = UsdGeom.Mesh.Define(stage, "/Palpation/Organ")
        organ.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # a triangle mesh: use the normals
        organ.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)  # triangles wound outward
        organ.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, dtype=np.int32)))
        organ.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces.reshape(-1), dtype=np.int32)))
        self._points = organ.CreatePointsAttr()
        self._normals = organ.CreateNormalsAttr()
        organ.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        self._extent = organ.CreateExtentAttr()
        pv = UsdGeom.PrimvarsAPI(organ)
        self._color = pv.CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.vertex)
        self._disp = pv.CreatePrimvar("displacement_mm", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)
        ids = organ.GetPrim().CreateAttribute("almsdm:vertex_id", Sdf.ValueTypeNames.IntArray, custom=True)
        ids.Set(Vt.IntArray.FromNumpy(np.ascontiguousarray(self.point_vertex, dtype=np.int32)))

        curves = self.curves = UsdGeom.BasisCurves.Define(stage, "/Palpation/RegionSprings")
        curves.CreateTypeAttr(UsdGeom.Tokens.linear)
        curves.CreateWrapAttr(UsdGeom.Tokens.nonperiodic)
        self._curve_counts = curves.CreateCurveVertexCountsAttr()
        self._curve_points = curves.CreatePointsAttr()
        self._curve_extent = curves.CreateExtentAttr()
        self._curve_width = 0.3  # mm
        curves.CreateWidthsAttr(Vt.FloatArray([self._curve_width]))
        curves.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        curves.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([SPRING_COLOR]))

        probe = self.probe = UsdGeom.Sphere.Define(stage, "/Palpation/Probe")
        r_mm = self.probe_radius * 1e3
        probe.CreateRadiusAttr(r_mm)
        probe.CreateExtentAttr(Vt.Vec3fArray([(-r_mm, -r_mm, -r_mm), (r_mm, r_mm, r_mm)]))
        probe.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([(0.6, 0.6, 0.65)]))
        self._translate = probe.AddTranslateOp()
        prim = probe.GetPrim()
        self._force = prim.CreateAttribute("almsdm:feedback_force_N", Sdf.ValueTypeNames.Float3, custom=True)
        self._force_mag = prim.CreateAttribute("almsdm:feedback_force_magnitude_N", Sdf.ValueTypeNames.Float, custom=True)

    @property
    def flush_every(self) -> int:
        """Frames between saves: as given, or those that fill `flush_mb` (points, normals and
        displacement per surface vertex, two points per spring, at the current region's size)."""
        if self._flush_every is not None:
            return int(self._flush_every)
        springs = len(self._spring_ends) // 2 if self._spring_ends is not None else 0
        frame_bytes = 28 * len(self.point_vertex) + 24 * springs + 64
        return max(1, int(self._flush_bytes // frame_bytes))

    @property
    def frames(self) -> int:
        """Frames recorded so far (distinct time codes)."""
        return len(self._codes)

    # -- frames --------------------------------------------------------------------------------
    def on_press_step(self, k: int, total: int) -> None:
        """The hook for ``Palpation.press(record=...)``: record after step k of `total`."""
        self.frame(self._base + k)
        if k == total:
            self._base += total

    def frame(self, step: int, probe_center=None, force=None) -> None:
        """Record the palpation's current state at time code `step` (steps taken so far). A probe
        that moves on its own path (almsdm trace) gives its sphere's centre [m] and force [N] here."""
        pal = self.pal
        code = self._Usd.TimeCode(float(step))
        q_dev = pal.state.particle_q
        region = pal.region
        self.normals.update_region(q_dev, region)
        q = q_dev.numpy()
        n = self.normals.vertex_normal.numpy()
        with np.errstate(all="ignore"):  # a diverging run is recorded as it is, then discarded
            self._write_frame(code, q, n, probe_center, force)
        self._codes.add(step)
        self._unsaved += 1
        self._last_code = max(step, self._last_code or 0)
        if self._unsaved >= self.flush_every:
            self._unsaved = 0
            self.stage.SetEndTimeCode(self._last_code)
            self._save()  # crate layers save incrementally: the written samples leave memory

    def _write_frame(self, code, q, n, probe_center=None, force=None):
        Vt = self._Vt
        pal = self.pal
        pts = (q[self.point_vertex] * 1e3).astype(np.float32)
        self._points.Set(Vt.Vec3fArray.FromNumpy(pts), code)
        self._normals.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(n[self.point_vertex], dtype=np.float32)), code)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        self._extent.Set(Vt.Vec3fArray.FromNumpy(np.stack([lo, hi]).astype(np.float32)), code)
        self._disp.Set(Vt.FloatArray.FromNumpy(np.linalg.norm(pts - self._rest_mm, axis=1).astype(np.float32)), code)
        self._write_region(code)
        ends = (q[self._spring_ends] * 1e3).astype(np.float32).reshape(-1, 3)
        self._curve_points.Set(Vt.Vec3fArray.FromNumpy(ends), code)
        if len(ends):
            w = self._curve_width / 2
            self._curve_extent.Set(Vt.Vec3fArray.FromNumpy(np.stack([ends.min(axis=0) - w, ends.max(axis=0) + w])), code)
        in_contact = pal.probe_mode != PROBE_OFF
        if probe_center is not None:  # a probe on a path: where the path put it
            center = np.asarray(probe_center, dtype=np.float64) * 1e3
        elif in_contact and pal.probe_mode == PROBE_SPHERE:  # a sphere pressing: its centre, as the step sees it
            center = pal.probe_target * 1e3
        else:  # a press: its tip on the contact vertex while it presses, at the rest surface once lifted
            tip = q[pal.vertex].astype(np.float64) if in_contact else pal.rest_position()
            outward = -np.asarray(pal.inward_normal(), dtype=np.float64)  # per frame: the probe may have moved
            center = (tip + outward * self.probe_radius) * 1e3
        self._translate.Set(tuple(float(c) for c in center), code)
        if force is not None:
            f = np.asarray(force, dtype=np.float64)
        else:
            f = np.asarray(pal.feedback_force, dtype=np.float64) if in_contact else np.zeros(3)
        self._force.Set(tuple(float(c) for c in f), code)
        self._force_mag.Set(float(np.linalg.norm(f)), code)

    def _write_region(self, code):
        # ring colours and springs: written when the region changes (a new contact, more rings)
        pal = self.pal
        region = pal.region
        key = (region.seed, region.vertex_count) if region is not None else ("global",)
        if key == self._region_key:
            return
        self._region_key = key
        Vt = self._Vt
        mesh = pal.mesh
        if region is not None:
            ring = region.vertex_ring.numpy()
            colors = ring_colors(ring, region.outer_ring)
            spring_edges = region.springs()
        else:
            colors = ring_colors(np.ones(mesh.vertex_count, dtype=np.int32), 2)  # all free
            spring_edges = np.arange(mesh.edge_count)
        colors = Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(colors[self.point_vertex]))
        if self._colors is not None and self._last_code is not None:
            # USD interpolates between samples: hold the old colours up to the last frame before
            self._color.Set(self._colors, self._Usd.TimeCode(float(self._last_code)))
        self._colors = colors
        self._color.Set(colors, code)
        self._spring_ends = mesh.edges[spring_edges].reshape(-1)
        self._curve_counts.Set(Vt.IntArray.FromNumpy(np.full(len(spring_edges), 2, dtype=np.int32)), code)

    # -- finishing -----------------------------------------------------------------------------
    def close(self) -> Path:
        """Write the stage's end time code, save, and rename it to the target; returns the path."""
        if self._tmp is None:
            return self.path
        try:
            self.stage.SetEndTimeCode(self._last_code or 0)
            self._save()
            if self.path.suffix.lower() == ".usda":
                with atomic_path(self.path, ".tmp.usda") as text_tmp:
                    self._save(text_tmp)
                self._discard()
            else:
                self._release()
                publish(self._tmp, self.path)
                self._tmp = None
        except BaseException:
            self._discard()
            raise
        return self.path

    def _save(self, export_to=None):
        """Save the layer (or export it as text to `export_to`); a write USD refuses (a full disk, a
        quota) is one InputError naming the target and the cause, not USD's error stack."""
        from pxr import Tf

        try:
            ok = self._layer.Export(export_to) if export_to is not None else self._layer.Save()
        except Tf.ErrorException as exc:
            raise InputError(f"{self.path}: cannot write the USD stage: {usd_error_cause(exc)}") from None
        if not ok:
            raise InputError(f"{self.path}: cannot write the USD stage (USD refused to save {export_to or self._tmp})")

    def _release(self):
        self.stage = self._layer = self.organ = self.curves = self.probe = None
        self._points = self._normals = self._extent = self._color = self._disp = None
        self._curve_counts = self._curve_points = self._curve_extent = None
        self._translate = self._force = self._force_mag = None

    def _discard(self):
        self._release()
        if self._tmp is not None:
            discard(self._tmp)
            self._tmp = None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self._discard()
        return False
