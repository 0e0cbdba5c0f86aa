"""The figures of `almsdm evaluate` (matplotlib, Agg backend: no display needed). Each function
takes an experiment's result dict and a path, and writes one PNG through a temporary file."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .common import PAPER
from ..export.output import atomic_path

FLOOR = 1e-6
"""Errors of exactly zero (the reference against itself) are drawn at this floor on log axes."""

STATE_COLOURS = {"stable": "#2a9d4b", "oscillating": "#f0a500", "not recovered": "#7b5ea7", "diverged": "#d1343a"}


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path) -> Path:
    """Finish the figure (_finish) and write it (_write)."""
    _finish(fig)
    return _write(fig, path)


def _finish(fig) -> None:
    for ax in fig.axes:
        _readable_log_ticks(ax)


def _write(fig, path) -> Path:
    path = Path(path)
    try:
        with atomic_path(path, ".png") as tmp:
            fig.savefig(tmp, dpi=110, bbox_inches="tight")
    finally:
        _plt().close(fig)
    return path


def _readable_log_ticks(ax) -> None:
    """A logarithmic axis over less than 2.5 decades gets plain numbers at 1-2-5 (or finer) steps, at
    least three in view; a wider one its decades only (matplotlib's default labels one tick, or
    crowds the minor ones). Axes with ticks set by hand are left alone."""
    from matplotlib.ticker import FixedLocator, LogLocator, NullFormatter, StrMethodFormatter

    for axis, (lo, hi) in ((ax.xaxis, sorted(ax.get_xlim())), (ax.yaxis, sorted(ax.get_ylim()))):
        if axis.get_scale() != "log" or not isinstance(axis.get_major_locator(), LogLocator) or lo <= 0:
            continue
        axis.set_minor_formatter(NullFormatter())
        if math.log10(hi / lo) >= 2.5:
            continue
        decades = range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1)
        for subs in ((1, 2, 5), (1, 1.5, 2, 3, 5, 7), (1, 1.5, 2, 2.5, 3, 4, 5, 6, 7, 8, 9), np.arange(10, 100) / 10):
            ticks = [m * 10.0**d for d in decades for m in subs if lo <= m * 10.0**d <= hi]
            if len(ticks) >= 3:
                break
        axis.set_major_locator(FixedLocator(ticks[::-(-len(ticks) // 7)]))  # at most 7
        axis.set_major_formatter(StrMethodFormatter("{x:g}"))


def _annotate_apart(fig, notes, fontsize=6) -> None:
    """Write the notes [(axes, text, (x, y) data)] where each hides no other note, text, marker or
    legend of its axes (export.labels.place), once the limits are final."""
    from ..export.labels import extent, marker_boxes, place, text_box

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    taken = {}
    for ax in dict.fromkeys(n[0] for n in notes):
        boxes = [text_box(t, renderer) for t in ax.texts]
        boxes += [extent(ax.get_legend().get_window_extent(renderer))] if ax.get_legend() else []
        for line in ax.lines:
            if line.get_marker() not in (None, "None", "", " "):
                boxes += marker_boxes(ax, line.get_xydata())
        taken[ax] = boxes
    for ax, text, xy in notes:
        place(ax, text, xy, renderer, taken[ax], fontsize=fontsize, radii=(1.0, 6.0, 14.0, 26.0, 40.0))


def _label_axes(ax, xlabel, ylabel, title=None, *, log="", legend=7, loc="best", title_size=None):
    """An axis's scales ("x", "y" or "xy" logarithmic), labels, title and legend (font size). A
    logarithmic x axis labels its decades only: over less than a decade matplotlib labels the minor
    ticks too, and they overlap."""
    if "x" in log:
        from matplotlib.ticker import NullFormatter

        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
    if "y" in log:
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title, **({"fontsize": title_size} if title_size else {}))
    ax.legend(fontsize=legend, loc=loc)


def plot_recovery(rec, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    top = 10.0
    for k, row in enumerate(rec["rows"]):
        res = [x for x in row["residual_mm"] if x is not None and math.isfinite(x)]
        label = f"{row['rings']} ring{'s' if row['rings'] != 1 else ''}" if isinstance(row["rings"], int) else "global, no anchors"
        # each ring count's markers smaller than the last's: counts that coincide (all at 0) stay visible as rings
        size = {"ms": max(11 - 2.5 * k, 3), "lw": max(3.0 - 0.6 * k, 1.2)} if isinstance(row["rings"], int) else {}
        line = ax.plot(range(1, len(res) + 1), res, marker="o", label=label, **size)
        top = max([top] + [x * 10 for x in res])
        if row.get("ran_away_at_press"):
            k = row["ran_away_at_press"]
            y = max(res + [1.0]) * 3
            ax.plot([k], [y], marker="x", ms=9, color=line[0].get_color())
            ax.annotate(f"ran away at press {k}", (k, y), fontsize=7, xytext=(-105, 4), textcoords="offset points")
            top = max(top, y * 10)
    for value, text in ((0.11, "paper rings 1-2 < 0.11"), (0.48, "paper ring 3 ~0.48"), (1.15, "paper ring 4 ~1.15")):
        ax.axhline(value, color="grey", lw=0.8, ls=":")
        ax.text(1.02, value, text, fontsize=7, va="bottom", color="grey")
    ax.set_yscale("symlog", linthresh=1e-3)
    ax.set_ylim(-3e-4, top)  # room under 0 for the markers of the series that recover fully
    ax.set_xlim(0.7, len(rec["rows"][0]["residual_mm"]) + 0.3)
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.set_xlabel("press at the same spot")
    ax.set_ylabel(f"residual of the contact vertex after {rec['settle_s']:g} s [mm]")
    ax.set_title("Recovery after repeated 10 mm presses (stomach; paper Fig. 9)")
    ax.legend(fontsize=8, loc="center right")
    return _save(fig, path)


def plot_force_displacement(rec, table1, path):
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.0))
    ax = axes[0]
    for rings, (d, f) in rec["curves"].items():
        if rings not in ("4", "global-free"):
            ax.plot(d, f, label=f"{rings} ring(s)")
    for row in table1["rows"]:
        d, f = row["curve"]
        ax = axes[0] if row["scene"] == "stomach" else axes[1]
        ax.plot(d, f, label=row["label"].split(", ", 1)[1], ls="--" if "global" in row["label"] else "-")
    for ax, name, paper in ((axes[0], "stomach (surface)", 2.402), (axes[1], "liver (volume)", 2.312)):
        ax.axhline(paper, color="grey", lw=0.8, ls=":", label=f"paper, 4 rings at 10 mm: {paper} N")
        ax.set_title(name)
        ax.set_xlabel("displacement of the contact vertex [mm]")
        ax.set_ylabel("feedback force [N]")
        ax.legend(fontsize=7, loc="upper left")
    fig.suptitle("Force against displacement during the ramp and hold (paper Fig. 10)", y=1.02)
    return _save(fig, path)


def plot_speed_accuracy(acc, extra, path, against_fem=None, depth=None):
    plt = _plt()
    axes, title_y = _speed_accuracy_axes(plt, 2 + bool(against_fem) + bool(depth))
    fig = axes[0].figure
    rows = acc["rows"] + list(extra)
    notes = []  # (axes, text, point): written apart once the limits are final
    groups = {}
    for r in rows:
        groups.setdefault((r["scene"], r["integrator"], r["device"]), []).append(r)
    for (scene, integrator, device), rs in groups.items():
        local = [r for r in rs if r["rings"] != "global" and not str(r["rings"]).startswith("auto")]
        auto = [r for r in rs if str(r["rings"]).startswith("auto")]
        for ax, key in ((axes[0], "force_error_N"), (axes[1], "disp_error_mm")):
            line = ax.plot([r["step_us"] for r in local], [max(r[key], FLOOR) for r in local], marker="o", ms=4, label=f"{scene}, {integrator}, {device}")
            notes += [(ax, str(r["rings"]), (r["step_us"], max(r[key], FLOOR))) for r in local]
            for r in auto:  # the adaptive region: one point per tolerance, not on the fixed-ring line
                y = max(r[key], FLOOR)
                ax.plot([r["step_us"]], [y], marker="*", ms=8, ls="none", color=line[0].get_color(), mec="k", mew=0.4)
                notes.append((ax, f"tol {str(r['rings']).split(':', 1)[-1]}", (r["step_us"], y)))
            for r in rs:
                if r["rings"] == "global":
                    ax.plot([r["step_us"]], [FLOOR], marker="s", color=line[0].get_color(), mfc="none")
                    notes.append((ax, "global", (r["step_us"], FLOOR)))
    for ax, label in ((axes[0], "error of the peak force at the probe [N]"), (axes[1], "largest displacement error over the mesh [mm]")):
        ax.axvline(1000.0, color="k", lw=0.8, ls="--")
        ax.text(1000.0, 0.5, " 1 kHz haptic budget", fontsize=7, transform=ax.get_xaxis_transform())
        for fps, text in ((PAPER["fps_4_rings"], "paper 4 rings: 120 fps"), (PAPER["fps_global_surface"], "paper global: 34.5 fps")):
            ax.axvline(1e6 / fps, color="grey", lw=0.8, ls=":")
            ax.text(1e6 / fps, 0.05, " " + text, fontsize=7, rotation=90, color="grey", transform=ax.get_xaxis_transform())
        _label_axes(ax, "time per step [us] (paper: per rendered frame)", label, log="xy", loc="upper right")
    if against_fem:
        notes += _fem_reference_panel(axes[2], against_fem)
    if depth:
        notes += _law_panel(axes[-1], depth)
    fig.suptitle(
        "Speed against accuracy: rings 1..N against the global anchored reference\n"
        f"(numbers: rings; stars: auto rings at a tolerance in mm; errors below {FLOOR:g}, or {100 * FLOOR:g} %, drawn there: "
        f"a model against itself)", y=title_y
    )
    _annotate_apart(fig, notes)
    return _save(fig, path)


def _speed_accuracy_axes(plt, panels: int):
    """The speed-accuracy figure's axes, flat (one row of up to three panels, two rows of two for four),
    and the height of its two-line title in figure coordinates."""
    if panels == 4:
        fig, axes = plt.subplots(2, 2, figsize=(12, 9.0))
        fig.subplots_adjust(hspace=0.35, top=0.9)
        return list(axes.ravel()), 0.99
    fig, axes = plt.subplots(1, panels, figsize=(5.5 * panels, 4.4))
    return list(axes), 1.07


def _law_panel(ax, depth) -> list:
    """Every tissue law on the deep press (evaluation/depth_layers): each local region's and the global
    model's force error against the neo-Hookean FEM of the same tets (filled, solid) and against the
    law's own global model (open, dashed), over its step time. Returns the notes (rings at each point)
    for _annotate_apart."""
    deep = next(c for c in depth["cases"] if c["case"] == "deep")
    notes = []
    for i, law in enumerate(depth["laws"]):
        rows = [r for r in depth["regions"] if r["law"] == law and r.get("step_us") and r.get("force_N") is not None]
        if not rows:
            continue
        x = [r["step_us"] for r in rows]
        for key, style, fill, against in (("error_vs_fem_pct", "o-", None, "FEM"), ("error_vs_global_pct", "o--", "none", "its global model")):
            y = [max(abs(r[key]), 100 * FLOOR) if r[key] is not None else math.nan for r in rows]
            ax.plot(x, y, style, color=f"C{i}", mfc=fill, ms=4, label=f"{law} against {against}")
        notes += [(ax, str(r["rings"]), (r["step_us"], max(abs(r["error_vs_fem_pct"] or 0.0), 100 * FLOOR))) for r in rows]
    fem = f"FEM {deep['fem_N']:.3f} N" if deep.get("fem_N") is not None else "no FEM"
    _label_axes(ax, "time per step [us]", "force error [%] (|error|)",
                f"every tissue law, deep press ({deep['vertices']} vertices, sphere R {deep['sphere_mm']:g} mm "
                f"{deep['depth_mm']:g} mm in)\nagainst the neo-Hookean FEM ({fem}) and against its own global model",
                log="xy", legend=6, title_size=9)
    # the legend in two columns in room above the 100% errors: below them each law falls to its floor at its own step time
    ax.set_ylim(top=ax.get_ylim()[1] * 1e3)
    ax.legend(fontsize=6, loc="upper center", ncol=2)
    return notes


def plot_stability(stab, path):
    plt = _plt()
    from matplotlib.patches import Patch

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), gridspec_kw={"width_ratios": [1, 1, 0.8]})
    scales = sorted(stab["critical_dt_ms"], key=float)
    dts = [c["dt_ms"] for c in stab["cells"]] + [stab["critical_dt_ms"][s] for s in scales]
    ys = [float(s) for s in scales]
    for ax, integrator in ((axes[0], "explicit"), (axes[1], "implicit")):
        for c in stab["cells"]:
            if c["integrator"] == integrator:
                ax.scatter([c["dt_ms"]], [c["scale"]], marker="s", s=100, color=STATE_COLOURS[c["state"]], edgecolors="k", linewidths=0.3)
        ax.plot([stab["critical_dt_ms"][s] for s in scales], ys, "k-", lw=1.2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlim(min(dts) / 1.6, max(dts) * 1.6)
        ax.set_ylim(min(ys) / 1.6, max(ys) * 1.6)
        ax.set_xlabel("time step [ms]")
        ax.set_ylabel("stiffness scale (k_ij and k_i)")
        ax.set_title(f"{integrator}, 4 rings (stomach)")
    ax = axes[2]
    for c in stab["global_free_cells"]:
        y = 1 if c["integrator"] == "explicit" else 0
        ax.scatter([c["dt_ms"]], [y], marker="s", s=100, color=STATE_COLOURS[c["state"]], edgecolors="k", linewidths=0.3)
    if stab.get("global_free_critical_dt_ms"):
        ax.axvline(stab["global_free_critical_dt_ms"], color="k", lw=1.2)
    ax.set_xscale("log")
    free_dts = [c["dt_ms"] for c in stab["global_free_cells"]] + [stab.get("global_free_critical_dt_ms") or 1.0]
    ax.set_xlim(min(free_dts) / 1.6, max(free_dts) * 1.6)
    ax.set_yticks([0, 1], ["implicit", "explicit"])
    ax.set_ylim(-0.7, 1.7)
    ax.set_xlabel("time step [ms]")
    ax.set_title("paper's global surface model\n(no anchors, no fixed ring), stiffness 1")
    from matplotlib.lines import Line2D

    handles = [Patch(color=col, label=state) for state, col in STATE_COLOURS.items()]
    handles.append(Line2D([], [], color="k", label="critical dt of semi-implicit Euler (Model.critical_dt, linearized)"))
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8, bbox_to_anchor=(0.5, -0.08))
    fig.suptitle("Stability of a 10 mm press at the top of the stomach", y=1.06)
    return _save(fig, path)


def plot_anatomy_cost(anat, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    rows = sorted(anat["rows"], key=lambda r: r["vertices"])
    for subset, tag in (([r for r in rows if r["file"].startswith("mor_")], "MOR liver series"), ([r for r in rows if not r["file"].startswith("mor_")], "other meshes")):
        if not subset:
            continue
        x = [r["vertices"] for r in subset]
        ls, marker = ("-", "o") if tag.startswith("MOR") else ("none", "^")
        ax.plot(x, [r["local_step_us"] for r in subset], ls=ls, marker=marker, color="C0", label=f"4 rings, {tag}")
        ax.plot(x, [r["global_step_us"] for r in subset], ls=ls, marker=marker, color="C3", label=f"global, {tag}")
    _label_axes(ax, "mesh vertices", "time per step [us] (implicit, dt 1 ms, CPU)",
                "Cost of a step against mesh size (real meshes)", log="xy")
    return _save(fig, path)


def plot_anatomy_force(anat, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for i, r in enumerate(anat["rows"]):
        d, f = r["local_curve"]
        ax.plot(d, f, color=f"C{i % 10}", label=f"{r['file']} ({r['vertices']} v)")
        d, f = r["global_curve"]
        ax.plot(d, f, color=f"C{i % 10}", ls=":")
    _label_axes(ax, "displacement of the contact vertex [mm]", "feedback force [N]",
                "Force against displacement on real meshes (solid: 4 rings, dotted: global)", legend=6)
    return _save(fig, path)


def _fem_reference_panel(ax, fem) -> list:
    """The ball's configurations: each one's force error against the P2 reference (filled) and against
    the global model (open), over its step time; the P2 force itself is the reference line at 0.
    Returns the notes (rings at each point) for _annotate_apart."""
    rows = [r for r in fem["rows"] if r["step_us"]]
    x = [r["step_us"] for r in rows]
    ax.plot(x, [max(abs(r["error_vs_fem_pct"]), 100 * FLOOR) for r in rows], "o-", color="C3", label="against P2 FEM")
    ax.plot(x, [max(abs(r["error_vs_global_pct"]), 100 * FLOOR) for r in rows], "o--", color="C0", mfc="none", label="against the global model")
    notes = [(ax, str(r["rings"]), (r["step_us"], max(abs(r["error_vs_fem_pct"]), 100 * FLOOR))) for r in rows]
    glob = next(r for r in fem["rows"] if r["rings"] == "global")
    ax.axhline(abs(glob["error_vs_fem_pct"]), color="C3", lw=0.8, ls=":")
    ax.text(min(x), abs(glob["error_vs_fem_pct"]), " the global model against P2: the cost of springs", fontsize=7, va="bottom", color="C3")
    _label_axes(ax, "time per step [us]", "force error [%] (|error|)",
                f"tet ball {fem['edge_mm']:g} mm, sphere R 50 mm at 2 mm: P2 {fem['p2_force_N']:.4f} N",
                log="xy", loc="upper right", title_size=9)
    return notes


def plot_convergence(conv, path):
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    notes = []
    for ax, part, xkey, xlabel, title in (
        (axes[0], conv["icosphere"], "vertices", "mesh vertices", "icosphere R 50 mm, sphere R 10 mm pressed 5 mm (4 rings)"),
        (axes[1], conv["ball"], "vertices", "mesh vertices", "tet ball R 50 mm, pressed 2 mm (global)"),
    ):
        for i, (label, forces) in enumerate(part["series"].items()):
            ref = forces[-1]
            ax.plot(part[xkey], [f / ref for f in forces], marker="o", color=f"C{i}",
                    label=f"{label}: spread {100 * part['spread'][label]:.1f}%")
            notes += [(ax, f"{f:.3f} N", (xv, f / ref)) for xv, f in zip(part[xkey], forces)]
        ax.axhspan(0.95, 1.05, color="grey", alpha=0.12, lw=0)
        _label_axes(ax, xlabel, "hold force / the finest level's", title, log="x", title_size=9)
        ax.set_xticks(part[xkey], [str(v) for v in part[xkey]])  # the levels themselves: less than a decade apart
        ax.set_xlim(min(part[xkey]) / 1.15, max(part[xkey]) * 1.15)  # room for the labels at the ends
    _annotate_apart(fig, notes)
    fig.suptitle("Mesh convergence: the same press at three resolutions (grey: within 5% of the finest)", y=1.02)
    return _save(fig, path)


def plot_against_fem(fem, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.8, 4.2))
    rows = [r for r in fem["rows"] if r["rings"] != "global"]
    glob = next(r for r in fem["rows"] if r["rings"] == "global")
    ax.plot([r["region_vertices"] for r in rows], [r["force_N"] for r in rows], "o-", color="C0", label="local model (rings)")
    ax.plot([glob["region_vertices"]], [glob["force_N"]], "s", color="C0", mfc="none", label=f"global model {glob['force_N']:.4f} N")
    ax.axhline(fem["p2_force_N"], color="C3", lw=1.2, label=f"P2 FEM, same mesh: {fem['p2_force_N']:.4f} N")
    ax.axhline(fem["hertz_force_N"], color="grey", lw=1.0, ls="--", label=f"Hertz, two 50 mm spheres: {fem['hertz_force_N']:.4f} N")
    _label_axes(ax, "vertices simulated", "hold force [N]",
                f"The ball case against continuum mechanics (tet ball, edge {fem['edge_mm']:g} mm)",
                log="x", loc="upper center", title_size=9)
    ax.get_legend().set_bbox_to_anchor((0.5, -0.16))  # below the axes: off the points and their labels
    _annotate_apart(fig, [(ax, f"{r['rings']} rings", (r["region_vertices"], r["force_N"])) for r in rows], fontsize=7)
    return _save(fig, path)
