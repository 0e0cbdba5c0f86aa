"""The pictures' decisions, not their pixels: what is coloured, what is marked and where, what is hidden,
the scale of what is drawn, the labels and units on every axis, no text over text."""

from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from almsdm_warp.export import sweep_png  # noqa: E402
from almsdm_warp.mesh.primitives import icosphere_arrays  # noqa: E402
from almsdm_warp.tissue.lesion import Lesion  # noqa: E402


def ellipsoid(half_height=0.5, subdivisions=2):
    """An icosphere of 50 mm flattened along z (so the maps look along z): (vertices [m], triangles)."""
    v, t = icosphere_arrays(50.0, subdivisions)
    return v * [1.0, 1.0, half_height], np.asarray(t, dtype=np.int64)


def table(vertices_m, vertex, stiffness):
    xyz = vertices_m[vertex] * 1e3
    return {"vertex": np.asarray(vertex), "x_mm": xyz[:, 0], "y_mm": xyz[:, 1], "z_mm": xyz[:, 2],
            "stiffness_N_per_mm": np.asarray(stiffness, dtype=np.float64)}


def test_unpressed_vertices_and_faces_stay_uncoloured():
    # the old map gave every vertex the value of the nearest pressed point; now only pressed ones have one
    v, t = ellipsoid()
    rng = np.random.default_rng(1)
    vertex = rng.choice(len(v), 60)  # with repeats: a vertex pressed twice has the mean
    stiff = rng.uniform(0.01, 0.05, len(vertex))
    stiff[3] = np.nan  # a press without a result gives its vertex nothing
    per_vertex = sweep_png.vertex_values(len(v), vertex, stiff)
    for k in range(len(v)):
        got = [s for i, s in zip(vertex, stiff) if i == k and np.isfinite(s)]
        if got:
            assert per_vertex[k] == pytest.approx(np.mean(got))
        else:
            assert np.isnan(per_vertex[k])
    assert np.isnan(per_vertex).sum() > len(v) // 2
    faces = sweep_png.face_values(t, per_vertex)
    for f, corners in zip(faces, t):
        if all(np.isfinite(per_vertex[c]) for c in corners):
            assert f == pytest.approx(np.mean(per_vertex[corners]))
        else:
            assert np.isnan(f)


def test_extremes_are_the_true_max_and_min_of_the_table():
    rng = np.random.default_rng(2)
    stiff = rng.uniform(0.0, 1.0, 500)
    stiff[rng.choice(500, 20)] = np.nan
    found = sweep_png.extremes({"stiffness_N_per_mm": stiff})
    finite = [(s, i) for i, s in enumerate(stiff) if np.isfinite(s)]
    assert found == {"stiffest": max(finite)[1], "softest": min(finite)[1]}
    assert sweep_png.extremes({"stiffness_N_per_mm": np.full(3, np.nan)}) == {}


def test_hidden_points_on_a_sphere_and_behind_another():
    # a sphere seen from +z hides its lower half; a second sphere above it hides the part of the first's
    # upper half under its disc (the closed form: a vertical ray from the point meets the upper sphere)
    v, t = icosphere_arrays(10.0, 3)
    v = v * 1e3
    both = np.vstack([v, v + [0.0, 0.0, 30.0]])
    tris = np.vstack([t, t + len(v)]).astype(np.int64)
    lower = np.arange(len(v))
    got = sweep_png.hidden(both[lower], lower, both, tris, [0.0, 0.0, 1.0])
    r = np.hypot(v[:, 0], v[:, 1])
    clear = (np.abs(v[:, 2]) > 1.0) & (np.abs(r - 10.0) > 1.0)  # away from the rims, where a polygon is not a sphere
    expected = (v[:, 2] < 0) | (r < 10.0)
    np.testing.assert_array_equal(got[clear], expected[clear])
    upper = lower + len(v)
    np.testing.assert_array_equal(sweep_png.hidden(both[upper], upper, both, tris, [0, 0, 1])[clear], (v[:, 2] < 0)[clear])


@pytest.fixture(scope="module")
def sweep_fig():
    """A map of the flattened sphere: 50 pressed vertices, the stiffest one on the underside."""
    v, t = ellipsoid()
    rng = np.random.default_rng(3)
    vertex = rng.choice(len(v), 50, replace=False)
    stiff = rng.uniform(0.01, 0.03, 50)
    low = int(np.argmin(v[vertex, 2]))  # the lowest pressed vertex: hidden from the top
    stiff[low] = 0.07
    columns = table(v, vertex, stiff)
    lesion = Lesion(center=(0.01, -0.02, 0.005), radius=0.012, stiffness_factor=3.0)
    fig = sweep_png.sweep_figure(SimpleNamespace(vertices=v, triangles=t), columns, title="test", lesion=lesion)
    fig.canvas.draw()
    return fig, v * 1e3, t, columns


def test_sweep_map_axes_in_mm_and_named_views(sweep_fig):
    fig, *_ = sweep_fig
    maps = [ax for ax in fig.axes if ax.get_title()]
    assert [ax.get_title() for ax in maps] == ["top: seen from +z", "bottom: seen from -z"]
    for ax in maps:
        assert ax.get_xlabel().startswith("x [mm]") and ax.get_ylabel() == "y [mm]"
        assert len(ax.get_xticklabels()) > 2 and len(ax.get_yticklabels()) > 2
    lo, hi = maps[1].get_xlim()
    assert lo > hi  # seen from below, x runs right to left
    assert "[N/mm]" in fig.axes[-1].get_ylabel()  # the colour bar


def test_sweep_map_marks_the_stiffest_point_in_every_view(sweep_fig):
    from matplotlib.text import Annotation

    fig, v, t, columns = sweep_fig
    row = int(np.nanargmax(columns["stiffness_N_per_mm"]))
    at = v[columns["vertex"][row]]
    for ax, behind in zip(fig.axes[:2], (True, False)):
        notes = [a for a in ax.texts if isinstance(a, Annotation) and a.get_text().startswith("stiffest")]
        assert len(notes) == 1
        assert notes[0].get_text() == f"stiffest {columns['stiffness_N_per_mm'][row]:.3g} N/mm" + (" (behind)" if behind else "")
        np.testing.assert_allclose(notes[0].xy, at[:2])


def test_sweep_map_outlines_the_lesion_at_its_size(sweep_fig):
    from matplotlib.patches import Circle

    fig, *_ = sweep_fig
    for ax in fig.axes[:2]:
        (circle,) = [p for p in ax.patches if isinstance(p, Circle)]
        assert circle.get_radius() == pytest.approx(12.0)
        np.testing.assert_allclose(circle.center, [10.0, -20.0])


def test_sweep_map_colours_only_faces_pressed_at_every_corner(sweep_fig):
    from matplotlib.collections import PolyCollection

    fig, v, t, columns = sweep_fig
    pressed = np.zeros(len(v), dtype=bool)
    pressed[columns["vertex"]] = True
    expected = sum(all(pressed[c]) for c in t)
    for ax in fig.axes[:2]:
        (surface,) = [c for c in ax.collections if isinstance(c, PolyCollection) and len(c.get_paths()) == len(t)]
        rgb = surface.get_facecolors()[:, :3]
        coloured = ~(np.isclose(rgb[:, 0], rgb[:, 1]) & np.isclose(rgb[:, 1], rgb[:, 2]))
        assert coloured.sum() == expected


def test_sweep_map_labels_stay_inside_their_axes_and_apart(sweep_fig):
    fig, *_ = sweep_fig
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes[:2]:
        frame = ax.get_window_extent(renderer)
        boxes = [a.get_bbox_patch().get_window_extent(renderer) for a in ax.texts]  # the texts, not their arrows
        for b in boxes:
            assert frame.x0 <= b.x0 and b.x1 <= frame.x1 and frame.y0 <= b.y0 and b.y1 <= frame.y1
        assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1:])


@pytest.fixture(scope="module")
def pressed_snapshot():
    """A 10 mm sphere 5 mm into a 50 mm icosphere, caught at the end of the hold (Snapshot.of)."""
    from almsdm_warp.export.preview import Snapshot
    from almsdm_warp.mesh.primitives import icosphere
    from almsdm_warp.protocol.palpation import Palpation

    mesh = icosphere(50.0, 3)
    pal = Palpation(mesh, rings=2, dt=1e-3, device="cpu", probe_radius=0.01)
    pal.touch(int(np.argmax(mesh.vertices[:, 2])))
    shots = {}
    pal.press(0.005, 0.05, 0.02, 0.02, record=lambda k, total: shots.setdefault(k, Snapshot.of(pal, k * pal.dt)), record_every=1)
    return mesh, shots[70]


def test_preview_sphere_touches_the_dent_it_made(pressed_snapshot):
    # the drawn sphere is where the simulation's sphere is: 5 mm below the rest contact, no vertex inside it
    mesh, snap = pressed_snapshot
    assert snap.in_contact and snap.probe_radius == 0.01
    top = mesh.vertices[snap.contact_vertex]
    np.testing.assert_allclose(snap.probe_centre, top + [0.0, 0.0, 0.01 - 0.005], atol=1e-6)
    gap = np.linalg.norm(snap.positions - snap.probe_centre, axis=1) - snap.probe_radius
    assert gap.min() > -2e-4 and gap.min() < 2e-4


def test_preview_draws_the_sphere_to_scale_and_labels_every_axis(pressed_snapshot):
    from almsdm_warp.export.preview import preview_figure

    mesh, snap = pressed_snapshot
    fig = preview_figure(mesh, snap, title="test")
    fig.canvas.draw()
    views = [ax for ax in fig.axes if ax.name == "3d"]
    assert len(views) == 2
    whole = fig.get_window_extent()
    for ax in views:
        (sphere,) = [c for c in ax.collections if c.get_gid() == "probe sphere"]
        corners = np.concatenate(sphere._faces)  # the 3D quads as given [mm] (matplotlib keeps them here)
        np.testing.assert_allclose(np.linalg.norm(corners - snap.probe_centre * 1e3, axis=1), 10.0, rtol=1e-9)
        for axis, name in zip((ax.xaxis, ax.yaxis, ax.zaxis), "xyz"):
            assert axis.get_label_text() == f"{name} [mm]"
            box = axis.label.get_window_extent(fig.canvas.get_renderer())
            assert whole.x0 <= box.x0 and box.x1 <= whole.x1 and whole.y0 <= box.y0 and box.y1 <= whole.y1, name
    assert "10 mm sphere, to scale" in views[1].get_title()


def test_trace_figure_labels_the_peak_and_every_region_move():
    from matplotlib.text import Annotation

    from almsdm_warp.export.trace_png import trace_figure

    rng = np.random.default_rng(4)
    n = 400
    t = np.arange(n) * 1e-3
    columns = {"t_s": t, "relocations": np.cumsum(rng.random(n) < 0.02)}
    for a in "xyz":
        columns[f"force_{a}_N"] = np.cumsum(rng.normal(0.0, 0.01, n))
        columns[f"probe_{a}_mm"] = np.cumsum(rng.normal(0.0, 0.1, n))
    fig = trace_figure(columns, title="test")
    force, probe = fig.axes
    mags = [np.sqrt(sum(columns[f"force_{a}_N"][i] ** 2 for a in "xyz")) for i in range(n)]
    peak = max(range(n), key=lambda i: mags[i])
    (note,) = [a for a in force.texts if isinstance(a, Annotation)]
    assert note.get_text() == f"peak {mags[peak]:.3f} N at t = {t[peak]:.3f} s"
    moves = [i for i in range(n) if columns["relocations"][i] > (columns["relocations"][i - 1] if i else 0)]
    assert moves
    for ax in (force, probe):
        dotted = [line for line in ax.lines if line.get_linestyle() == ":" and len(line.get_xdata()) == 2]
        assert sorted(line.get_xdata()[0] for line in dotted) == pytest.approx(t[moves])
        assert f"region moved ({len(moves)}x)" in [x.get_text() for x in ax.get_legend().get_texts()]
    assert force.get_ylabel().endswith("[N]") and probe.get_ylabel().endswith("[mm]") and probe.get_xlabel() == "t [s]"


def drawn_texts(fig) -> list:
    """(what, display box) of every text a drawing of `fig` shows: titles, axis labels, the tick labels in
    view, notes (their words, not their arrows), legends (one box each)."""
    from almsdm_warp.export.labels import extent, text_box

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    out = []

    def add(what, t):
        if t is not None and t.get_visible() and t.get_text().strip():
            out.append((f"{what} {t.get_text()[:40]!r}", text_box(t, renderer)))

    add("suptitle", fig._suptitle)
    for i, ax in enumerate(fig.axes):
        for t in (ax.title, ax._left_title, ax._right_title, ax.xaxis.label, ax.yaxis.label, *ax.texts):
            add(f"axes {i}", t)
        for axis in (ax.xaxis, ax.yaxis):
            for tick in axis._update_ticks():  # the ticks a drawing shows (in view)
                add(f"axes {i} tick", tick.label1)
                add(f"axes {i} tick", tick.label2)
        if ax.get_legend() is not None:
            out.append((f"axes {i} legend", extent(ax.get_legend().get_window_extent(renderer))))
    out += [("figure legend", extent(leg.get_window_extent(renderer))) for leg in fig.legends]
    return out


def overlapping_texts(fig, pad=0.5) -> list:
    """Pairs of drawn texts whose boxes overlap by more than `pad` pixels both ways."""
    boxes = drawn_texts(fig)
    return [(a, b) for i, (a, ba) in enumerate(boxes) for b, bb in boxes[i + 1:]
            if min(ba[2], bb[2]) - max(ba[0], bb[0]) > pad and min(ba[3], bb[3]) - max(ba[1], bb[1]) > pad]


def labelled_ticks(axis) -> int:
    return sum(bool(t.label1.get_visible() and t.label1.get_text().strip()) for t in axis._update_ticks())


EVALUATE_FIGURES = {
    "recovery": lambda p, r: p.plot_recovery(r["recovery"], "recovery.png"),
    "force_displacement": lambda p, r: p.plot_force_displacement(r["recovery"], r["table1"], "fd.png"),
    "speed_accuracy": lambda p, r: p.plot_speed_accuracy(r["accuracy"], r["accuracy"].get("extra", []), "sa.png", r["against_fem"],
                                                         r.get("depth_layers")),
    "stability": lambda p, r: p.plot_stability(r["stability"], "stability.png"),
    "anatomy_cost": lambda p, r: p.plot_anatomy_cost(r["anatomy"], "cost.png"),
    "anatomy_force": lambda p, r: p.plot_anatomy_force(r["anatomy"], "force.png"),
    "convergence": lambda p, r: p.plot_convergence(r["convergence"], "convergence.png"),
    "against_fem": lambda p, r: p.plot_against_fem(r["against_fem"], "fem.png"),
}


@pytest.mark.parametrize("name", sorted(EVALUATE_FIGURES))
def test_evaluate_figures_have_no_text_over_text_and_ticks_on_every_axis(name, monkeypatch):
    # the published results (docs/results.json) drawn again: the figure as finished, just before it is written
    import json

    import matplotlib.pyplot as plt

    from almsdm_warp.evaluation import plots
    from conftest import ROOT

    results = json.loads((ROOT / "docs" / "results.json").read_text())
    figures = []
    monkeypatch.setattr(plots, "_write", lambda fig, path: figures.append(fig) or path)
    EVALUATE_FIGURES[name](plots, results)
    (fig,) = figures
    try:
        assert overlapping_texts(fig) == []
        for i, ax in enumerate(fig.axes):
            for axis in (ax.xaxis, ax.yaxis):
                if axis.get_visible():
                    assert labelled_ticks(axis) >= 2, (i, axis.axis_name)
            assert ax.get_xlabel(), i
    finally:
        plt.close(fig)
