"""USD recording (almsdm_warp/export/usd.py): stages reopened and checked against what the
palpation did, sample by sample (points, normals by a float64 loop, displacement, ring colours
by a NumPy BFS, springs, probe, force), metadata, USD's own validators, the temporary file."""

import numpy as np
import pytest
from test_normals import area_weighted_f64
from test_simulation_press import palpation, scene_and_mesh

from almsdm_warp.errors import InputError
from almsdm_warp.export.usd import CONTACT_COLOR, FIXED_COLOR, PLAIN_COLOR, UsdRecorder

pxr = pytest.importorskip("pxr")
from pxr import Sdf, Usd, UsdGeom  # noqa: E402

RAMP, HOLD, SETTLE = 0.03, 0.01, 0.02  # [s]: 60 steps of 1 ms
EVERY = 7  # not a divisor of the press: the last step is recorded as well


def record(tmp_path, scene=None, *, suffix=".usda", device="cpu", presses=1, every=EVERY, **kw):
    """Record presses to a stage; returns (path, palpation, {step: what the palpation had})."""
    pal = palpation(scene, device=device)
    path = tmp_path / f"press{suffix}"
    seen = {}
    base = [0]

    def snapshot(step):
        seen[step] = {
            "q": pal.positions(),
            "force": np.array(pal.feedback_force, dtype=np.float64),
            "mode": pal.probe_mode,
        }

    with UsdRecorder(path, pal, every=every, **kw) as rec:
        rec.frame(0)
        snapshot(0)

        def hook(k, total):
            rec.on_press_step(k, total)
            snapshot(base[0] + k)
            if k == total:
                base[0] += total

        for _ in range(presses):
            pal.press(8e-3, RAMP, HOLD, SETTLE, record=hook, record_every=every)
        assert not path.exists()  # nothing at the target until the stage is complete
    return path, pal, seen


def validation_errors(stage):
    """Errors from USD's validators: UsdUtils.ComplianceChecker where it exists (usd-core < 25.x),
    else its successor, the UsdValidation framework with every registered validator."""
    from pxr import UsdUtils

    if hasattr(UsdUtils, "ComplianceChecker"):
        checker = UsdUtils.ComplianceChecker()
        checker.CheckCompliance(stage.GetRootLayer().realPath)
        return list(checker.GetErrors()) + list(checker.GetFailedChecks())
    from pxr import UsdValidation

    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    errors = UsdValidation.ValidationContext(validators).Validate(stage)
    return [e.GetErrorAsString() for e in errors if e.GetType() == UsdValidation.ValidationErrorType.Error]


def test_validators_catch_a_stage_without_metadata(tmp_path):
    # the check below can fail: a stage without upAxis / metersPerUnit / defaultPrim has errors
    stage = Usd.Stage.CreateNew(str(tmp_path / "bare.usda"))
    UsdGeom.Mesh.Define(stage, "/Organ")
    stage.Save()
    assert len(validation_errors(stage)) >= 1


@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usd"])
def test_stage_reopens_with_samples_metadata_and_no_validation_errors(tmp_path, suffix, device):
    path, pal, seen = record(tmp_path, suffix=suffix, device=device)
    _, mesh = scene_and_mesh(None)
    stage = Usd.Stage.Open(str(path))
    assert validation_errors(stage) == []
    layer = stage.GetRootLayer()
    magic = path.read_bytes()[:8]
    assert magic == (b"#usda 1." if suffix == ".usda" else b"PXR-USDC")  # the suffix chose the format
    assert layer.GetFileFormat() == Sdf.FileFormat.FindByExtension(suffix)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(1e-3)
    total = round((RAMP + HOLD + SETTLE) / pal.dt)
    steps = sorted(seen)
    assert steps == [0, *range(EVERY, total, EVERY), total]
    assert stage.GetStartTimeCode() == 0 and stage.GetEndTimeCode() == total
    assert stage.GetTimeCodesPerSecond() == pytest.approx(1.0 / pal.dt)
    assert stage.GetFramesPerSecond() == pytest.approx(1.0 / (pal.dt * EVERY))
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/Palpation")
    assert stage.GetDefaultPrim().GetCustomDataByKey("record_every") == EVERY

    organ = UsdGeom.Mesh(stage.GetPrimAtPath("/Palpation/Organ"))
    points = organ.GetPointsAttr()
    assert points.GetTimeSamples() == [float(s) for s in steps]
    assert organ.GetNormalsAttr().GetTimeSamples() == [float(s) for s in steps]
    assert organ.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    assert organ.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    np.testing.assert_array_equal(np.asarray(organ.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), mesh.triangles)
    disp = UsdGeom.PrimvarsAPI(organ).GetPrimvar("displacement_mm")
    assert disp.GetInterpolation() == UsdGeom.Tokens.vertex
    rest_mm = mesh.vertices.astype(np.float32).astype(np.float64) * 1e3
    deepest = max(steps, key=lambda s: np.abs(seen[s]["q"] - mesh.vertices).max())
    for s in (0, deepest, total):
        q_mm = seen[s]["q"] * 1e3
        p = np.asarray(points.Get(s), dtype=np.float64)
        np.testing.assert_allclose(p, q_mm, atol=1e-4)
        np.testing.assert_allclose(organ.GetNormalsAttr().Get(s), area_weighted_f64(q_mm, mesh.triangles), atol=2e-5)
        np.testing.assert_allclose(disp.Get(s), np.linalg.norm(q_mm - rest_mm, axis=1), atol=1e-3)
        extent = np.asarray(organ.GetExtentAttr().Get(s))
        np.testing.assert_allclose(extent, [p.min(axis=0), p.max(axis=0)], atol=1e-4)
    assert np.max(disp.Get(deepest)) == pytest.approx(8.0, abs=0.05)  # the press depth, mm

    # the probe: tip on the contact vertex while pressing, lifted to the rest surface after; its force
    probe = UsdGeom.Sphere(stage.GetPrimAtPath("/Palpation/Probe"))
    r = probe.GetRadiusAttr().Get()
    outward = -pal.inward_normal()
    (translate,) = probe.GetOrderedXformOps()
    force = probe.GetPrim().GetAttribute("almsdm:feedback_force_N")
    magnitude = probe.GetPrim().GetAttribute("almsdm:feedback_force_magnitude_N")
    assert translate.GetAttr().GetTimeSamples() == force.GetTimeSamples() == [float(s) for s in steps]
    for s in steps[1:]:
        pressing = seen[s]["mode"] != 0
        tip_mm = seen[s]["q"][pal.vertex] * 1e3 if pressing else pal.rest_position() * 1e3
        np.testing.assert_allclose(translate.Get(s), tip_mm + outward * r, atol=1e-3)
        expected_force = seen[s]["force"] if pressing else np.zeros(3)
        np.testing.assert_allclose(force.Get(s), expected_force, rtol=1e-6, atol=1e-9)
        assert magnitude.Get(s) == pytest.approx(np.linalg.norm(expected_force), rel=1e-6, abs=1e-9)
    assert magnitude.Get(deepest) > 1.0  # a real press: about 2 N at 8 mm


def ring_hops(mesh, seed, rings):
    """Hops from `seed` along mesh edges up to `rings` (-1 beyond), by NumPy frontier expansion."""
    hops = np.full(mesh.vertex_count, -1)
    hops[seed] = 0
    e = mesh.edges
    for r in range(1, rings + 1):
        front = hops == r - 1
        reached = np.concatenate([e[front[e[:, 0]], 1], e[front[e[:, 1]], 0]])
        new = reached[hops[reached] < 0]
        hops[new] = r
    return hops


def test_ring_colours_and_region_springs(tmp_path):
    path, pal, seen = record(tmp_path, every=30)
    _, mesh = scene_and_mesh(None)
    stage = Usd.Stage.Open(str(path))
    hops = ring_hops(mesh, pal.vertex, pal.rings)
    organ = UsdGeom.Mesh(stage.GetPrimAtPath("/Palpation/Organ"))
    color = UsdGeom.PrimvarsAPI(organ).GetPrimvar("displayColor")
    assert color.GetInterpolation() == UsdGeom.Tokens.vertex
    c = np.asarray(color.Get(0))
    np.testing.assert_allclose(c[hops == 0], [CONTACT_COLOR], atol=1e-6)
    np.testing.assert_allclose(c[hops == pal.rings], np.tile(FIXED_COLOR, ((hops == pal.rings).sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(c[hops < 0], np.tile(PLAIN_COLOR, ((hops < 0).sum(), 1)), atol=1e-6)
    free = (hops > 0) & (hops < pal.rings)
    assert not np.isclose(c[free], PLAIN_COLOR, atol=1e-3).all(axis=1).any()
    # springs: every mesh edge with both ends in the region, once, as 2-point linear curves
    curves = UsdGeom.BasisCurves(stage.GetPrimAtPath("/Palpation/RegionSprings"))
    assert curves.GetTypeAttr().Get() == UsdGeom.Tokens.linear
    inside = hops >= 0
    e = mesh.edges
    expected = e[inside[e[:, 0]] & inside[e[:, 1]]]
    counts = np.asarray(curves.GetCurveVertexCountsAttr().Get(0))
    assert len(counts) == len(expected) and set(counts.tolist()) == {2}
    for s in (30, max(seen)):
        ends = np.asarray(curves.GetPointsAttr().Get(s), dtype=np.float64).reshape(-1, 2, 3)
        q_mm = seen[s]["q"] * 1e3
        # each curve's two points are the current positions of one region edge's ends
        got = {tuple(sorted((int(np.argmin(np.linalg.norm(q_mm - a, axis=1))), int(np.argmin(np.linalg.norm(q_mm - b, axis=1)))))) for a, b in ends}
        assert got == {tuple(x) for x in expected.tolist()}


def test_volume_mesh_exports_its_surface(tmp_path):
    path, pal, seen = record(tmp_path, "liver", suffix=".usdc", every=20)
    _, mesh = scene_and_mesh("liver")
    assert mesh.is_volume
    stage = Usd.Stage.Open(str(path))
    assert validation_errors(stage) == []
    organ = UsdGeom.Mesh(stage.GetPrimAtPath("/Palpation/Organ"))
    ids = np.asarray(organ.GetPrim().GetAttribute("almsdm:vertex_id").Get())
    np.testing.assert_array_equal(ids, mesh.surface_vertices)
    faces = np.asarray(organ.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    np.testing.assert_array_equal(ids[faces], mesh.triangles)  # the same triangles, re-indexed
    last = max(seen)
    q_mm = seen[last]["q"] * 1e3
    np.testing.assert_allclose(organ.GetPointsAttr().Get(last), q_mm[ids], atol=1e-4)
    normals = np.asarray(organ.GetNormalsAttr().Get(last))
    np.testing.assert_allclose(normals, area_weighted_f64(q_mm, mesh.triangles)[ids], atol=2e-5)


def test_two_presses_continue_the_time_codes(tmp_path):
    path, pal, seen = record(tmp_path, suffix=".usdc", presses=2, every=25)
    total = round((RAMP + HOLD + SETTLE) / pal.dt)
    stage = Usd.Stage.Open(str(path))
    samples = UsdGeom.Mesh(stage.GetPrimAtPath("/Palpation/Organ")).GetPointsAttr().GetTimeSamples()
    assert samples == [0.0, 25.0, 50.0, 60.0, 85.0, 110.0, 120.0] == [float(s) for s in sorted(seen)]
    assert stage.GetEndTimeCode() == 2 * total


def test_a_new_contact_between_presses_is_recorded(tmp_path):
    _, mesh = scene_and_mesh(None)
    pal = palpation(None)
    path = tmp_path / "two.usdc"
    sv = mesh.surface_vertices
    low = int(sv[np.argmin(mesh.vertices[sv, 2])])
    with UsdRecorder(path, pal, every=20) as rec:
        rec.frame(0)
        first = pal.vertex
        pal.press(8e-3, RAMP, HOLD, SETTLE, record=rec.on_press_step, record_every=20)
        pal.touch(low)  # the region moves to the bottom
        pal.press(8e-3, RAMP, HOLD, SETTLE, record=rec.on_press_step, record_every=20)
    stage = Usd.Stage.Open(str(path))
    organ = UsdGeom.Mesh(stage.GetPrimAtPath("/Palpation/Organ"))
    color = UsdGeom.PrimvarsAPI(organ).GetPrimvar("displayColor")
    # written when the region changed, and the old colours once more at the frame before (USD
    # interpolates between samples: the colours blend only between those two frames)
    assert color.GetTimeSamples() == [0.0, 60.0, 80.0]
    for code, seed in ((0, first), (30, first), (60, first), (80, low), (120, low)):
        c = np.asarray(color.Get(code))
        np.testing.assert_allclose(c[seed], CONTACT_COLOR, atol=1e-6)
        hops = ring_hops(mesh, seed, pal.rings)
        np.testing.assert_allclose(c[hops < 0], np.tile(PLAIN_COLOR, ((hops < 0).sum(), 1)), atol=1e-6)
    curves = UsdGeom.BasisCurves(stage.GetPrimAtPath("/Palpation/RegionSprings"))
    assert len(curves.GetCurveVertexCountsAttr().Get(120)) == pal.region.spring_count
    # during the second press the probe sits over the new contact, along its outward normal
    probe = UsdGeom.Sphere(stage.GetPrimAtPath("/Palpation/Probe"))
    (translate,) = probe.GetOrderedXformOps()
    lifted = (pal.rest_position() - pal.inward_normal() * probe.GetRadiusAttr().Get() * 1e-3) * 1e3
    np.testing.assert_allclose(translate.Get(120), lifted, atol=1e-3)


def test_frames_reach_the_disk_while_recording_and_an_error_leaves_nothing(tmp_path):
    pal = palpation(None)
    path = tmp_path / "long.usdc"
    with pytest.raises(RuntimeError, match="stop"):
        with UsdRecorder(path, pal, every=1, flush_every=8) as rec:
            rec.frame(0)
            (tmp,) = tmp_path.iterdir()  # the temporary crate beside the target
            sizes = []

            def hook(k, total):
                rec.on_press_step(k, total)
                if k % 8 == 7:  # the layer was saved at frame 8, 16, ...: the file grows
                    sizes.append(tmp.stat().st_size)
                if k == 40:
                    raise RuntimeError("stop")

            pal.press(8e-3, RAMP, HOLD, SETTLE, record=hook)
    assert sizes[0] > 0 and all(b > a for a, b in zip(sizes, sizes[1:]))
    assert list(tmp_path.iterdir()) == []  # the temporary file is gone, no target


def test_bad_paths_and_arguments(tmp_path):
    pal = palpation(None)
    with pytest.raises(InputError, match=r"unknown USD suffix '\.abc' \(allowed: \.usda, \.usdc, \.usd\)"):
        UsdRecorder(tmp_path / "x.abc", pal)
    with pytest.raises(InputError, match="does not exist"):
        UsdRecorder(tmp_path / "missing" / "x.usda", pal)
    with pytest.raises(ValueError, match="every must be an int >= 1"):
        UsdRecorder(tmp_path / "x.usda", pal, every=0)
    with pytest.raises(ValueError, match="unknown normals strategy"):
        UsdRecorder(tmp_path / "x.usda", pal, normals="fast")
    assert list(tmp_path.iterdir()) == []


def test_a_sphere_probe_is_drawn_at_its_size_and_centre(tmp_path):
    """A palpation with a rigid sphere: the Probe prim has the sphere's radius, and while it presses
    its centre is the one the step holds the tissue against (every contact vertex at that distance)."""
    from almsdm_warp.mesh.primitives import icosphere
    from almsdm_warp.protocol import Palpation
    from almsdm_warp.tissue.material import Material

    mesh = icosphere(50.0, 3)
    pal = Palpation(mesh, Material(10e3, 0.45, 1000.0, thickness=2e-3, foundation=1e6, rayleigh_alpha=60.0),
                    rings=2, device="cpu", probe_radius=10e-3, integrator="implicit")
    top = int(np.argmax(mesh.vertices[:, 2]))
    pal.touch(top, 5e-3)
    path = tmp_path / "sphere.usda"
    codes = {}

    def hook(k, total):
        rec.on_press_step(k, total)
        if k == 100:  # the end of the ramp: pressed 5 mm
            codes["q"] = pal.positions()
            codes["centre"] = pal.probe_target

    with UsdRecorder(path, pal, every=100) as rec:
        rec.frame(0)
        pal.press(5e-3, 0.1, 0.05, 0.05, record=hook, record_every=100)
    stage = Usd.Stage.Open(str(path))
    probe = UsdGeom.Sphere(stage.GetPrimAtPath("/Palpation/Probe"))
    assert probe.GetRadiusAttr().Get() == pytest.approx(10.0)
    (translate,) = probe.GetOrderedXformOps()
    centre_mm = np.asarray(translate.Get(100))
    np.testing.assert_allclose(centre_mm, codes["centre"] * 1e3, atol=1e-4)
    # the vertices the sphere holds lie on its surface: none inside, the nearest at its radius
    d = np.linalg.norm(codes["q"] * 1e3 - centre_mm, axis=1)
    assert d.min() == pytest.approx(10.0, abs=0.05)
