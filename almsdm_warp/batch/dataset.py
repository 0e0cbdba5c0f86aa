"""Datasets: sweeps over several organs and a grid of lesions in one run, gathered into one table.

A dataset spec (a TOML file, docs/datasets.md) lists scenes or meshes, the points pressed on each,
the press, and a lesion grid: lesion centres (farthest-point-spread surface vertices of each organ,
moved a depth inward along the surface normal, or listed), radii and stiffness factors, every
combination, plus a baseline without a lesion. Each (scene, lesion) pair is an *item*: a sweep of
the same points of its scene (a SweepPlan, resumable from its parts as a sweep is), written as its
own table; the items of a scene are pressed together, in shared launches on every device given
(batch/dataset_press.py), with the numbers of each pressed as a sweep of its own. The output folder holds::

    dataset.json              the spec's key and each finished item's key and checksum
    items/<scene>_L<id>.npz   each item's sweep table (batch.sweep_plan.SWEEP_TABLE)
    maps/<scene>.png          force maps (each scene's baseline, or every item)
    table.npz                 the dataset: one array per column and a "schema" entry (JSON)
    table.csv                 the same table as text (when the spec asks for it)
    table.parquet             the same table as Parquet (when the spec asks for it: the parquet extra),
                              its schema's metadata the "schema" entry and what made it (dataset_info)

A rerun with the same spec skips finished items and resumes the one in progress; a rerun with
another spec into the same folder is refused. Every file is written atomically.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..checks import AUTO, AUTO_TOL, check_limit, check_protocol, check_value, describe
from ..errors import InputError
from ..export.output import atomic_write, check_regular
from ..export.tables import TableLayout, millimetres
from ..solvers import integrators
from ..tissue.laws import law_entry, resolve_law
from .sampling import pressable_points, sample_points
from .records import UNITS, Records, lesion_columns
from .sweep import Writer, run_local
from .sweep_plan import COLUMNS, GPU_CHUNK, SweepPlan, check_sphere_travel, with_columns
from .sweep_store import Parts, file_sha256
from .sweep_times import SweepTimes

FORMAT = "almsdm dataset 1"
"""The manifest's format tag: a folder of another format is not resumed into."""
LESION_COLUMNS = ("scene", "lesion_id", "lesion_x_mm", "lesion_y_mm", "lesion_z_mm", "lesion_radius_mm", "lesion_factor", "point")
DATASET_COLUMNS = LESION_COLUMNS + COLUMNS
"""The dataset table's columns: the item's scene and lesion, the point's index in its scene, then a sweep's."""
SCHEMA = {
    "scene": ("str", "", "the scene's name (its file's stem; a repeated name gets _2, _3, ...)"),
    "lesion_id": ("int64", "", "0: the baseline (no lesion); 1.. the scene's lesions in grid order"),
    "lesion_x_mm": ("float64", "mm", "lesion centre x (NaN for the baseline)"),
    "lesion_y_mm": ("float64", "mm", "lesion centre y (NaN for the baseline)"),
    "lesion_z_mm": ("float64", "mm", "lesion centre z (NaN for the baseline)"),
    "lesion_radius_mm": ("float64", "mm", "lesion radius (0 for the baseline)"),
    "lesion_factor": ("float64", "", "stiffness factor inside the lesion (1 for the baseline)"),
    "point": ("int64", "", "index of the pressed point in its scene (the same points for every lesion)"),
    "x_mm": ("float64", "mm", "contact point x"),
    "y_mm": ("float64", "mm", "contact point y"),
    "z_mm": ("float64", "mm", "contact point z"),
    "vertex": ("int64", "", "contact vertex (the mesh vertex nearest the point)"),
    "peak_force_N": ("float64", "N", "peak feedback force of the press"),
    "hold_force_N": ("float64", "N", "feedback force at the end of the hold (full depth)"),
    "stiffness_N_per_mm": ("float64", "N/mm", "force at full depth / depth"),
    "recovery_error_mm": ("float64", "mm", "contact vertex's distance from rest at the end of the settle window"),
    "rings": ("int64", "", "rings of the local region"),
}
"""Column -> (dtype, unit, meaning): written into table.npz as its "schema" entry."""


def schema_entry(schema: dict) -> dict:
    """The layout's entries beside the columns: "schema", JSON of column -> {dtype, unit, meaning}."""
    return {"schema": json.dumps({"format": FORMAT, "columns": {c: {"dtype": d, "unit": u, "meaning": m} for c, (d, u, m) in schema.items()}})}


DATASET_TABLE = TableLayout("dataset table", {c: SCHEMA[c][0] for c in DATASET_COLUMNS}, optional=("hold_force_N",), meta=schema_entry(SCHEMA))
"""The dataset table (export/tables.py): .npz (one array per column, plus "schema": JSON text of column ->
{dtype, unit, meaning}; np.load reads it without pickle) or .csv (a header row); a table written before the
hold_force_N column has none."""


def dataset_layout(records: Records) -> TableLayout:
    """The dataset table with the rows for learning `records` asks for (their columns after the sweep's,
    the lesion labels last; each in the schema): DATASET_TABLE itself where none is asked for."""
    extra = records.dtypes(lesion=True)
    if not extra:
        return DATASET_TABLE
    return with_columns(DATASET_TABLE, extra, schema_entry(SCHEMA | {c: (d, *UNITS[c]) for c, d in extra.items()}))


MAPS = ("scene", "items", "none")
OWN = ("dataset.json", "items", "maps", "table.npz", "table.csv", "table.parquet")
"""What a dataset folder holds (and temporary files starting with a dot): a folder with anything else is not resumed into."""
SPEC_KEYS = {
    "dataset": ("scenes", "points", "rings", "integrator", "dt_ms", "scale_mm", "baseline", "maps", "csv", "parquet", "chunk",
                "curve_points", "tactile_size", "lesion_labels", "volume"),
    "press": ("depth_mm", "ramp_s", "hold_s", "settle_s"),
    "lesions": ("count", "depth_mm", "centers_mm", "radii_mm", "stiffness_factors"),
}


# -- the spec ----------------------------------------------------------------------------------
@dataclass
class DatasetSpec:
    """A dataset spec's values in SI units (load_spec reads one from TOML)."""

    scenes: list
    """The scenes (scene.loader.Scene), in the spec's order."""
    points: int
    """Points pressed on each scene (the same points for each of its lesions)."""
    radii: tuple = ()
    """Lesion radii [m]."""
    factors: tuple = (5.0,)
    """Lesion stiffness factors [-]."""
    count: int = 0
    """Lesion centres per scene, spread over its surface (with `depth`); 0 when `centers` are given."""
    depth: float = 10e-3
    """How far below the surface [m] a spread centre lies, along the inward normal."""
    centers: dict = field(default_factory=dict)
    """Scene name -> listed lesion centres [m], shape [n, 3] (instead of spread ones)."""
    rings: int | None = None
    """Rings of every region (None: each scene's)."""
    integrator: str = "explicit"
    dt: float = 1e-3
    """Frame [s]."""
    press: dict = field(default_factory=dict)
    """Overrides of every scene's press: depth [m], ramp, hold, settle [s]."""
    baseline: bool = True
    maps: str = "scene"
    csv: bool = False
    parquet: bool = False
    """Write table.parquet too (needs pyarrow: checked when the spec is read)."""
    records: Records = field(default_factory=Records)
    """The rows for learning each press keeps (batch/records.py): [dataset] curve_points, tactile_size, lesion_labels."""
    chunk: int | None = None
    """Points per resumable part (None: 64 on the CPU, an item's points on a GPU)."""
    volume: str | None = None
    """"auto" or "off" for every scene (scene/volume.py), or None: each scene's [mesh] volume."""
    source: dict = field(default_factory=dict)
    """The spec as read (interface units), kept in the manifest to say what changed on a refused resume."""


def load_spec(path) -> DatasetSpec:
    """Read and check a dataset spec (TOML); InputError naming the file and key for anything wrong."""
    from ..scene.loader import read_toml

    where = str(path)
    p = Path(path)
    data = read_toml(p, where, "dataset spec")
    for section, table in data.items():
        if section not in SPEC_KEYS or not isinstance(table, dict):
            raise InputError(f"{where}: unknown section {section!r}; allowed: {', '.join(f'[{s}]' for s in SPEC_KEYS)}")
        for key in table:
            if key not in SPEC_KEYS[section]:
                raise InputError(f"{where}: unknown key {key!r} in [{section}]; allowed: {', '.join(SPEC_KEYS[section])}")
    ds, lesions = data.get("dataset", {}), data.get("lesions", {})
    spec = DatasetSpec(scenes=_scenes(ds, p, where), points=_int(ds, "points", where, "[dataset]", None), source=data)
    spec.rings = _int(ds, "rings", where, "[dataset]", None, required=False)
    spec.integrator = ds.get("integrator", "explicit")
    if spec.integrator not in integrators(batch=True):
        raise InputError(f"{where}: [dataset] integrator {spec.integrator!r} is not one of {', '.join(integrators(batch=True))}")
    spec.dt = _number(ds, "dt_ms", where, "[dataset]", 1.0, "> 0") / 1000.0
    spec.maps = ds.get("maps", "scene")
    if spec.maps not in MAPS:
        raise InputError(f"{where}: [dataset] maps {spec.maps!r} is not one of {', '.join(map(repr, MAPS))}")
    for key in ("baseline", "csv", "parquet"):
        setattr(spec, key, _bool(ds, key, where, key == "baseline"))
    counts = {k: _int(ds, k, where, "[dataset]", 0, rule=">= 0") for k in ("curve_points", "tactile_size")}
    spec.records = Records(counts["curve_points"], counts["tactile_size"], _bool(ds, "lesion_labels", where, False))
    if spec.parquet:
        from ..export.parquet import require_pyarrow

        require_pyarrow(f"{where}: [dataset] parquet = true")
    spec.chunk = _int(ds, "chunk", where, "[dataset]", None, required=False)
    if "volume" in ds:
        from ..scene.loader import check_choice
        from ..mesh.volume import VOLUME_CHOICES

        spec.volume = check_choice(ds["volume"], VOLUME_CHOICES, f"{where}: [dataset] volume")
    press = data.get("press", {})
    spec.press = {k.rsplit("_", 1)[0]: _number(press, k, where, "[press]", None, "> 0" if k == "depth_mm" else ">= 0")
                  / (1000.0 if k == "depth_mm" else 1.0) for k in press}
    _lesion_grid(spec, lesions, where)
    return spec


def _scenes(ds: dict, p: Path, where: str) -> list:
    from ..scene.loader import resolve_scene_or_mesh

    names = ds.get("scenes")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n.strip() for n in names):
        raise InputError(f"{where}: [dataset] scenes must be a non-empty list of scene files, scene names or meshes, "
                         f"got {describe(names) if names is not None else 'nothing'}")
    scale = _number(ds, "scale_mm", where, "[dataset]", 1.0, "> 0")
    scenes = []
    for name in names:
        local = p.parent / name  # a path is relative to the spec; a bare name may be a shipped scene
        try:
            scenes.append(resolve_scene_or_mesh(str(local) if local.exists() else name, scale_mm=scale))
        except InputError as exc:
            raise InputError(f"{where}: [dataset] scenes: {exc}") from None
    return scenes


def _lesion_grid(spec: DatasetSpec, lesions: dict, where: str) -> None:
    radii = lesions.get("radii_mm", [])
    factors = lesions.get("stiffness_factors", [5.0])
    for key, values in (("radii_mm", radii), ("stiffness_factors", factors)):
        if not isinstance(values, list):
            raise InputError(f"{where}: [lesions] {key} must be a list of numbers, got {describe(values)}")
        for v in values:
            check_value(v, float, "> 0", f"{where}: [lesions] {key} value")
    for f in factors:
        check_limit(f, "lesion_factor", f"{where}: [lesions] stiffness_factors value")
    spec.radii = tuple(float(r) / 1000.0 for r in radii)  # mm -> m, correctly rounded
    spec.factors = tuple(float(f) for f in factors)
    spec.count = _int(lesions, "count", where, "[lesions]", 0, rule=">= 0")
    check_limit(spec.count, "points", f"{where}: [lesions] count")
    spec.depth = _number(lesions, "depth_mm", where, "[lesions]", 10.0, ">= 0") / 1000.0
    if "centers_mm" in lesions:
        spec.centers = _centers(lesions["centers_mm"], spec.scenes, where)
    has_centres = spec.count > 0 or bool(spec.centers)
    if spec.count and spec.centers:
        raise InputError(f"{where}: [lesions] give count (centres spread over each organ) or centers_mm, not both")
    if has_centres != bool(spec.radii):
        raise InputError(f"{where}: [lesions] needs both centres (count or centers_mm) and radii_mm, or neither")
    if not spec.baseline and not has_centres:
        raise InputError(f"{where}: the dataset has no items: no lesions and [dataset] baseline = false")


def _centers(value, scenes, where: str) -> dict:
    """centers_mm: a list of [x, y, z] for every scene, or a table of such lists by scene name."""
    names = [s.name for s in scenes]
    table = value if isinstance(value, dict) else {n: value for n in names}
    out = {}
    for name, rows in table.items():
        if name not in names:
            raise InputError(f"{where}: [lesions] centers_mm names scene {name!r}, not in [dataset] scenes ({', '.join(names)})")
        ok = isinstance(rows, list) and rows and all(
            isinstance(r, list) and len(r) == 3 and all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in r)
            for r in rows)
        if not ok:
            raise InputError(f"{where}: [lesions] centers_mm must be a list of [x, y, z] in mm, got {rows!r}")
        out[name] = np.asarray(rows, dtype=np.float64) / 1000.0
    return out


def _bool(table, key, where, default: bool) -> bool:
    value = table.get(key, default)
    if not isinstance(value, bool):
        raise InputError(f"{where}: [dataset] {key} must be true or false, got {describe(value)}")
    return value


def _number(table, key, where, section, default, rule):
    if key not in table:
        if default is None:
            raise InputError(f"{where}: {section} needs {key}")
        return float(default)
    return check_value(table[key], float, rule, f"{where}: {section} {key}")


def _int(table, key, where, section, default, required=True, rule=">= 1"):
    if key not in table:
        if required and default is None:
            raise InputError(f"{where}: {section} needs {key}")
        return default
    return check_value(table[key], int, rule, f"{where}: {section} {key}")


# -- the items ---------------------------------------------------------------------------------
@dataclass
class DatasetItem:
    """One sweep of the dataset: a scene with one lesion (or none), its plan and its table's name."""

    scene: str
    lesion_id: int
    lesion: object
    """tissue.lesion.Lesion, or None for the baseline."""
    plan: SweepPlan
    scene_obj: object = None

    @property
    def name(self) -> str:
        return f"{self.scene}_L{self.lesion_id:03d}"

    def key(self) -> str:
        """What decides this item's numbers (the plan but its chunking, which only cuts the work)."""
        h = hashlib.sha256(replace(self.plan, chunk=0).key().encode())
        h.update(json.dumps([self.scene, self.lesion_id, None if self.lesion is None else self.lesion.as_dict()]).encode())
        return h.hexdigest()[:16]

    def columns(self, sweep: dict) -> dict:
        """This item's rows of the dataset table from its sweep table."""
        n = len(sweep["vertex"])
        c = (np.nan, np.nan, np.nan) if self.lesion is None else millimetres(self.lesion.center)
        out = {"scene": np.full(n, self.scene), "lesion_id": np.full(n, self.lesion_id, dtype=np.int64),
               "lesion_x_mm": np.full(n, c[0]), "lesion_y_mm": np.full(n, c[1]), "lesion_z_mm": np.full(n, c[2]),
               "lesion_radius_mm": np.full(n, 0.0 if self.lesion is None else self.lesion.radius * 1e3),
               "lesion_factor": np.full(n, 1.0 if self.lesion is None else self.lesion.stiffness_factor),
               "point": np.arange(n, dtype=np.int64)}
        out.update({k: sweep[k] for k in self.plan.table.dtypes})
        records = self.plan.records
        if records is not None and records.lesion_labels:
            out.update(self.lesion_columns())
        return out

    def lesion_columns(self) -> dict:
        """lesion_in_footprint and lesion_distance_mm of each point (batch/records.py's lesion_columns)."""
        return lesion_columns(self.plan.mesh, self.plan.vertices, self.lesion, self.plan.probe_radius)


def lesion_centers(mesh, count: int, depth: float) -> np.ndarray:
    """`count` lesion centres [m]: surface vertices spread by farthest-point sampling (as a sweep's
    points are), each moved `depth` [m] inward along its outward rest normal."""
    from ..sim.model import vertex_normals

    points, vertices = sample_points(mesh, count)
    return points - depth * vertex_normals(mesh.vertices, mesh.triangles)[vertices]


def plan_items(spec: DatasetSpec, cuda: bool = False, on_item=None, gpus: int = 1) -> list[DatasetItem]:
    """Every item of the spec, in order: per scene its baseline, then each centre x radius x factor;
    on_item() after each item is planned (a progress bar: each lesion takes a pass over the whole mesh)."""
    from ..tissue.lesion import Lesion

    items, seen = [], {}
    for scene in spec.scenes:
        seen[scene.name] = seen.get(scene.name, 0) + 1
        name = scene.name if seen[scene.name] == 1 else f"{scene.name}_{seen[scene.name]}"
        name = name.replace(",", "_")  # a CSV cell
        mesh, base, scene = _scene_plan(spec, scene, name, cuda, gpus)
        if spec.centers:
            centers = spec.centers.get(scene.name, np.zeros((0, 3)))
        else:
            centers = lesion_centers(mesh, spec.count, spec.depth) if spec.count else np.zeros((0, 3))
        if spec.baseline:
            items.append(DatasetItem(name, 0, None, base, scene))
            if on_item is not None:
                on_item()
        grid = [(c, r, f) for c in centers for r in spec.radii for f in spec.factors]
        for k, (c, r, f) in enumerate(grid, start=1):
            lesion = Lesion(tuple(float(x) for x in c), r, f)
            scales = lesion.model_scales(mesh, scene.tissue, scene.law)
            if not any((s != 1.0).any() for s in scales.values()):
                raise InputError(f"lesion {k} of {name}: radius {r * 1e3:g} mm around {np.round(c * 1e3, 2).tolist()} mm "
                                 f"holds no vertex, spring or tet of the mesh (a lesion there changes nothing): "
                                 f"give a larger radius or a smaller [lesions] depth_mm")
            items.append(DatasetItem(name, k, lesion, replace(base, **scales), scene))
            if on_item is not None:
                on_item()
    return items


def item_chunk(points: int, cuda: bool, gpus: int = 1, volumetric: bool = False) -> int:
    """Points a chunk of an item when the spec gives none: 64 on the CPU (a resume loses little); on a GPU
    the item's points in one chunk (each item one launch with its scene's others); on several, where
    each would still hold split_points(volumetric), a chunk a GPU: the (item, chunk) pairs are then a
    multiple of the GPUs and split evenly over them (13 items of one chunk on two GPUs go 7 against 6).
    Smaller items stay whole: the parts a chunked item writes, and its table made from them at the end,
    would cost more."""
    if not cuda:
        return 64
    return -(-points // gpus) if gpus > 1 and points >= split_points(volumetric) * gpus else max(points, 1)


SPLIT_POINTS = GPU_CHUNK[0]
"""The fewest points a chunk of an item of springs is cut to on several GPUs (item_chunk): a sweep
chunk's least on a GPU (sweep_plan.GPU_CHUNK)."""

TET_SPLIT_POINTS = SPLIT_POINTS // 64
"""The same for a volumetric (tet) law's item: a tet press costs some 100-200 spring presses on a GPU
(the liver's neo-Hookean sweep 695 presses/s on an H200 against the stomach's 132,633), so 256 of
them are more work than a springs chunk's 16,384, and the liver's items of 3,100 points at 10,000 a
scene, left whole, went out as units of 4, 3, 3 and 3 items of some 20 s each: two GPUs a unit apart."""


def split_points(volumetric: bool) -> int:
    """The fewest points a chunk of an item is cut to on several GPUs (item_chunk)."""
    return TET_SPLIT_POINTS if volumetric else SPLIT_POINTS


def _scene_plan(spec: DatasetSpec, scene, name: str, cuda: bool, gpus: int = 1):
    """(The scene's mesh, its baseline plan (no lesion), the scene with its support made a plane for a
    press from above, as a sweep's), after the checks a sweep makes."""
    from ..checks import check_ring_count
    from ..protocol.palpation import check_probe_radius
    from ..region.contact import top_vertex

    rings = spec.rings if spec.rings is not None else scene.rings
    mesh = scene.load_mesh()
    from ..scene.volume import scene_tets  # a surface made tets where the scene or spec asks: finest at its points

    scene, mesh, pressed = scene_tets(scene, mesh, spec.points, spec.press.get("depth", scene.press.depth), spec.volume)
    scene = scene.with_support(mesh, float(mesh.vertices[top_vertex(mesh), 2]))
    scene = replace(scene, law=resolve_law(scene.law, mesh, scene.tissue))
    try:  # the scene's [tissue] law: a batch's kernels, before any work
        law_entry(scene.law).require(integrator=spec.integrator, path="batch")
    except ValueError as exc:
        raise InputError(f"scene {name!r}: {exc}") from None
    if rings != AUTO:
        check_ring_count(rings, mesh.vertex_count, f"rings of {name}")
    press = {k: spec.press.get(k, getattr(scene.press, k)) for k in ("depth", "ramp", "hold", "settle")}
    check_protocol(press["depth"], spec.dt, press["ramp"], press["hold"], press["settle"], 1, float(np.ptp(mesh.vertices, axis=0).max()))
    check_limit(spec.points, "points", "[dataset] points")
    check_probe_radius(scene.probe_radius, mesh)  # before any work, as the batch checks it again
    check_sphere_travel(scene.probe_radius, press["depth"], spec.dt, press["ramp"])
    points, vertices = pressed if pressed is not None else pressable_points(mesh, spec.points, scene.fixed_below)
    chunk = spec.chunk or item_chunk(len(vertices), cuda, gpus, law_entry(scene.law).volumetric)
    tol = (scene.tol or AUTO_TOL) if rings == AUTO else None
    plan = SweepPlan(mesh, scene.tissue, None, None, 1 if tol else int(rings), spec.dt, press["depth"], press["ramp"], press["hold"],
                     press["settle"], points, vertices, chunk, spec.integrator, tol, probe_radius=scene.probe_radius,
                     fixed_below=scene.fixed_below, law=scene.law, records=_records(spec, scene, name, press["ramp"]))
    if tol is not None:  # rings "auto" (a mesh file's preset): each point's sized once, on the baseline, as a sweep's
        from .sweep_auto import size_regions

        plan.rings = size_regions(mesh, scene.tissue, vertices, tol, depth=press["depth"], ramp=press["ramp"], hold=press["hold"],
                                  integrator=spec.integrator, dt=spec.dt, probe_radius=scene.probe_radius,
                                  fixed_below=scene.fixed_below, law=scene.law)
    return mesh, plan, scene


def _records(spec: DatasetSpec, scene, name: str, ramp: float) -> Records | None:
    """The spec's rows for learning for scene `name` (None: none asked for), or InputError: a map without a
    sphere or on the implicit integrator, more curve samples than the ramp's frames."""
    from ..protocol.schedule import PressSchedule

    records = spec.records
    if records == Records():
        return None
    try:
        records.check(scene.probe_radius, spec.integrator, f"scene {name!r}: [dataset] ")
    except ValueError as exc:
        raise InputError(str(exc)) from None
    frames = PressSchedule.from_times(spec.dt, ramp, 0.0, 0.0).ramp_n
    if records.curve_points > frames:
        raise InputError(f"scene {name!r}: [dataset] curve_points {records.curve_points}: the ramp has only {frames} frame(s); "
                         f"ask for at most {frames}, or a longer ramp_s")
    return records


def spec_cost(spec: DatasetSpec) -> tuple[int, float]:
    """(items, region-steps) of the spec from its counts alone, before any planning: every item's points x
    frames (one substep each: a lower bound of the cost the planned items then check exactly)."""
    items, cost = 0, 0.0
    for scene in spec.scenes:
        centres = spec.count or len(spec.centers.get(scene.name, ()))
        n = int(spec.baseline) + centres * len(spec.radii) * len(spec.factors)
        ramp, hold, settle = (spec.press.get(k, getattr(scene.press, k)) for k in ("ramp", "hold", "settle"))
        frames = max(ramp / spec.dt, 1.0) + hold / spec.dt + max(settle / spec.dt, 1.0)
        items += n
        cost += float(n) * spec.points * frames
    return items, cost


def check_spec_cost(spec: DatasetSpec, limit: float) -> None:
    """InputError, before any planning, for a spec whose items would take more than `limit` region-steps."""
    items, cost = spec_cost(spec)
    if not cost <= limit:
        raise InputError(f"the dataset would take at least {cost:.3g} region-steps ({items} items of {spec.points} points, "
                         f"each press's frames), more than the {limit:.3g} allowed; give --max-region-steps {cost:.2g} to run "
                         f"it anyway, or fewer lesions, points or shorter times")


def spec_key(items: list[DatasetItem]) -> str:
    """The dataset's key: every item's, in order (the maps and the CSV copy do not change a number)."""
    h = hashlib.sha256(FORMAT.encode())
    for item in items:
        h.update(item.key().encode())
    return h.hexdigest()[:16]


# -- the output folder -------------------------------------------------------------------------
class DatasetFolder:
    """A dataset's output folder: its manifest (dataset.json), the items' tables, maps and the table.

    The manifest holds the spec's key and, for each finished item, its key and its table's SHA-256
    (rewritten atomically after each item). An item counts as done only when its table's bytes
    match: one damaged on disk is pressed again.
    """

    def __init__(self, out, items: list[DatasetItem], spec: DatasetSpec):
        self.dir = Path(out)
        self.items = items
        self.spec = spec
        self.key = spec_key(items)
        self.layout = dataset_layout(spec.records)
        """The dataset table's layout: DATASET_TABLE, with the rows for learning the spec asks for."""
        self.done: dict[str, dict] = {}
        self.created = False
        """Whether open() made the folder (a run refused before its first item then leaves nothing)."""
        self.note: str | None = None
        """What open() found damaged and pressed again, or None."""

    @property
    def manifest(self) -> Path:
        return self.dir / "dataset.json"

    def item_path(self, item: DatasetItem) -> Path:
        return self.dir / "items" / f"{item.name}.npz"

    def open(self) -> list[DatasetItem]:
        """Create the folder or check that it holds this spec's dataset; returns the items still to press."""
        if self.dir.exists() and not self.dir.is_dir():
            raise InputError(f"{self.dir}: is a file, not a dataset folder")
        check_regular(self.manifest)
        if self.dir.exists() and any(self.dir.iterdir()):
            self._check_manifest()
        self.created = not self.dir.exists()
        try:
            (self.dir / "items").mkdir(parents=True, exist_ok=True)
            self._write_manifest()
        except (OSError, InputError) as exc:  # a full disk: a folder made here goes, and one line says why
            self.discard_if_new()
            raise exc if isinstance(exc, InputError) else InputError(f"{self.dir}: cannot write: {exc.strerror or exc}") from None
        return [item for item in self.items if not self._finished(item)]

    def _check_manifest(self) -> None:
        try:
            data = json.loads(self.manifest.read_text())
            found, fmt = data["key"], data["format"]
            self.done = {str(k): dict(v) for k, v in data.get("items", {}).items()}
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            foreign = sorted(p.name for p in self.dir.iterdir() if p.name not in OWN and not p.name.startswith("."))
            if foreign or not self.manifest.exists() and not (self.dir / "items").is_dir():
                raise InputError(f"{self.dir}: not empty and not a dataset folder (no readable dataset.json"
                                 f"{f'; it holds {foreign[0]}' if foreign else ''}): give another --out") from None
            self.done = {}  # a dataset's own folder whose manifest is damaged (truncated): every item pressed again
            self.note = f"{self.manifest} was unreadable (damaged): its items are pressed again"
            return
        if fmt != FORMAT or found != self.key:
            changed = [k for k in sorted(set(data.get("spec", {})) | set(self.spec.source))
                       if data.get("spec", {}).get(k) != self.spec.source.get(k)]
            what = f" (changed: {', '.join(f'[{k}]' for k in changed)})" if changed else " (other meshes or scene files)"
            raise InputError(f"{self.dir} holds a dataset of a different spec{what}: delete it, or give another --out")

    def discard_if_new(self) -> None:
        """Remove the folder where open() made it and no item is done (a run refused before any result)."""
        if self.created and not self.done:
            shutil.rmtree(self.dir, ignore_errors=True)

    def _finished(self, item: DatasetItem) -> bool:
        entry = self.done.get(item.name)
        path = self.item_path(item)
        if entry is None or entry.get("key") != item.key() or not path.is_file():
            return False
        return entry.get("sha256") == file_sha256(path)

    def _write_manifest(self) -> None:
        data = {"format": FORMAT, "key": self.key, "spec": self.spec.source, "items": self.done}
        atomic_write(self.manifest, lambda tmp: Path(tmp).write_text(json.dumps(data, indent=1, default=str) + "\n"))

    def open_parts(self, item: DatasetItem) -> tuple[Parts, set]:
        """The item's parts (sweep_store.Parts, opened: a note for any found damaged) and the chunks they hold."""
        parts = Parts(self.item_path(item), item.plan)
        done = set(parts.open())
        for why in ([parts.dropped] if parts.dropped else []) + ([f"({len(parts.damaged)}) did not match their checksum"] if parts.damaged else []):
            print(f"note: the chunks in {parts.dir} {why}: pressed again", file=sys.stderr)
        return parts, done

    def press(self, item: DatasetItem, devices: list[str], progress=None) -> None:
        """Sweep one item on its own (resuming its parts, as a sweep does), write its table, record it as done."""
        parts, done = self.open_parts(item)
        run_local(item.plan, parts, [i for i in range(len(item.plan.chunks)) if i not in done], devices, progress)
        self.finish_item(item, parts)

    def finish_item(self, item: DatasetItem, parts: Parts, columns: dict | None = None) -> None:
        """Write the item's table (`columns`, or its parts' when every chunk is written), remove the parts,
        record it as done."""
        path = self.item_path(item)
        item.plan.table.write(path, parts.gather() if columns is None else columns)
        parts.remove()
        self.done[item.name] = {"key": item.key(), "sha256": file_sha256(path), "scene": item.scene,
                                "lesion": None if item.lesion is None else item.lesion.as_dict()}
        self._write_manifest()

    def gather(self) -> dict:
        """The dataset table: every item's rows, in item order (InputError for a table damaged since)."""
        parts = []
        for item in self.items:
            path = self.item_path(item)
            if not self._finished(item):
                raise InputError(f"{path}: missing or damaged; run the same command again to press it again")
            parts.append(item.columns(item.plan.table.read(path)))
        return {c: np.concatenate([p[c] for p in parts]) for c in self.layout.dtypes}


def press_dataset(folder: DatasetFolder, todo: list[DatasetItem], devices: list[str], progress=None, on_item=None, *,
                  together: bool = True, times: SweepTimes | None = None) -> None:
    """Press the items `todo` on `devices`; on_item(item) after each is recorded done.

    together: the items of a scene share launches (batch/dataset_press.py), each item's table and line
    in dataset.json written as its last chunk is; False: one after another, each a sweep of its own (the
    reference the tests hold the first to: the same bits). times: where the wall time goes (SweepTimes; together)."""
    if not together:
        for item in todo:
            folder.press(item, devices, progress)
            if on_item is not None:
                on_item(item)
        return
    from .dataset_press import ItemWork, press_stacks, stacks_of

    works = []
    sink = ItemSink(folder, on_item)
    for item in todo:
        parts, done = folder.open_parts(item)
        works.append(ItemWork(item, parts, set(range(len(item.plan.chunks))) - done))
        if not works[-1].todo:  # every chunk was written before its table: the table now
            sink.finish(works.pop())
    times = times if times is not None else SweepTimes()
    try:
        press_stacks(stacks_of(works), devices, Writer(sink, times), progress, times)
    except BaseException:
        for work in works:  # the parts folders opened for nothing go
            if work.todo:
                work.parts.discard_if_new()
        raise


class ItemSink:
    """Where a dataset's pressed rows go (on sweep.Writer's thread, in order): each item's chunk into its
    parts, and an item whose last chunk that was into its table and dataset.json (an item of one chunk:
    its table at once, no parts written)."""

    def __init__(self, folder: DatasetFolder, on_item=None):
        self.folder, self.on_item = folder, on_item

    def write(self, key, columns: dict) -> None:
        work, chunk = key
        if work.todo == {chunk} and len(work.item.plan.chunks) == 1:
            work.todo.clear()
            self.finish(work, columns)
            return
        work.parts.write(chunk, columns)
        work.todo.discard(chunk)
        if not work.todo:
            self.finish(work)

    def finish(self, work, columns: dict | None = None) -> None:
        self.folder.finish_item(work.item, work.parts, columns)
        if self.on_item is not None:
            self.on_item(work.item)


def draw_maps(folder: DatasetFolder) -> list[Path]:
    """Force maps (export.sweep_png): each scene's baseline (or its first item), or every item."""
    from ..export.sweep_png import plot_sweep

    if folder.spec.maps == "none":
        return []
    (folder.dir / "maps").mkdir(exist_ok=True)
    drawn, written = set(), []
    for item in folder.items:
        if folder.spec.maps == "scene" and item.scene in drawn:
            continue
        drawn.add(item.scene)
        name = item.scene if folder.spec.maps == "scene" else item.name
        what = "no lesion" if item.lesion is None else f"lesion {item.lesion_id} ({item.lesion.radius * 1e3:g} mm, x{item.lesion.stiffness_factor:g})"
        title = f"{item.scene}, {what}: stiffness under a {item.plan.depth * 1e3:g} mm press"
        table = item.plan.table.read(folder.item_path(item))
        written.append(plot_sweep(item.plan.mesh, table, folder.dir / "maps" / f"{name}.png", title=title, lesion=item.lesion))
    return written


def dataset_info(folder: DatasetFolder) -> dict:
    """What made the dataset's table (a Parquet table's schema metadata): the package, each scene's mesh,
    material, law and press (sweep_plan.table_info of its baseline), and each item's lesion."""
    from .sweep_plan import table_info

    scenes, common = {}, {}
    for item in folder.items:
        if item.scene not in scenes:
            info = table_info(item.plan, item.scene_obj)
            common = {k: info.pop(k) for k in ("package", "version")}
            scenes[item.scene] = {k: v for k, v in info.items() if k != "lesion"}
    lesions = [{"scene": item.scene, "lesion_id": item.lesion_id, "lesion": None if item.lesion is None else item.lesion.as_dict()}
               for item in folder.items]
    return {**common, "format": FORMAT, "key": folder.key, "scenes": scenes, "lesions": lesions}


def finish_dataset(folder: DatasetFolder) -> dict:
    """Gather the items into table.npz (and table.csv, table.parquet when the spec asks), draw the maps;
    returns the table."""
    columns = folder.gather()
    folder.layout.write(folder.dir / "table.npz", columns)
    if folder.spec.csv:
        folder.layout.write(folder.dir / "table.csv", columns)
    if folder.spec.parquet:
        folder.layout.write(folder.dir / "table.parquet", columns, dataset_info(folder))
    draw_maps(folder)
    return columns
