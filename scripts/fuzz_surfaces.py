"""A hostile-input campaign on the surfaces of issue 24: trace paths, dataset specs, material and
probe magnitudes, the Python facade's arguments, interrupted and damaged datasets, full disks.

    python scripts/fuzz_surfaces.py [--tree PATH] [--only WORD] [--json out.json]
    python scripts/fuzz_surfaces.py --table before.json after.json    # docs/reliability.md's table

Every case runs in a fresh process (the tree's package on PYTHONPATH, a 60 s limit, 4 GiB of address
space) in a folder of its own, and is counted as one of:

  clean      exit 2 and exactly one stderr line "almsdm: ...", nothing left behind (the facade: a
             ValueError / TypeError naming the argument)
  sane       exit 0 and a result that passes the case's check (a force where the probe presses, ...)
  traceback  any other exit, or an exception of another kind
  hang       past the time or memory limit
  silent     exit 0 with a result that fails the check, or a refused run that left files behind
  noisy      a refusal whose stderr is more than one line (Warp's banner, warnings)
  stuck      a resume that does not reach the uninterrupted table

--tree runs the cases against another checkout (the "before" counts: --tree /work/main). The flags are
spelt as they were before issue 23's renaming (the old spellings are still taken), so both trees read them.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
LIMIT_S = 60
LAST = []  # the last command's return code, last stderr line and last stdout line (printed with --why)
MEMORY = 4 * 1024**3


def _limits():
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY, MEMORY))
    os.setsid()


def run(argv, cwd, tree, timeout=LIMIT_S, env=None, python=None):
    """(returncode or 'hang', stdout, stderr) of `almsdm argv` (or python -c `python`) in `cwd`."""
    e = dict(os.environ, PYTHONPATH=str(tree), WARP_CACHE_PATH=str(ROOT / ".warp_cache"), **(env or {}))
    e.pop("ALMSDM_VERBOSE", None)
    cmd = [sys.executable, "-c", python] if python else [sys.executable, "-m", "almsdm_warp.cli.main", *argv]
    p = subprocess.Popen(cmd, cwd=cwd, env=e, stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=_limits)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        return "hang", "", ""
    LAST[:] = [p.returncode, (err.decode(errors="replace").strip().splitlines() or [""])[-1][:300],
               (out.decode(errors="replace").strip().splitlines() or [""])[-1][:300]]
    return p.returncode, out.decode(errors="replace"), err.decode(errors="replace")


def listing(folder: Path) -> set:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def classify(code, out, err, left=(), sane=None) -> str:
    """One of the outcomes above for a command's end."""
    if code == "hang":
        return "hang"
    lines = [l for l in err.splitlines() if l.strip()]
    if "MemoryError" in err or "std::bad_alloc" in err:
        return "hang"
    if code == 2:
        if "Traceback" in err:
            return "traceback"
        if len(lines) != 1 or not lines[0].startswith("almsdm: "):
            return "noisy"
        return "silent" if left else "clean"
    if code == 0:
        return "sane" if sane is None or sane(out) else "silent"
    return "traceback"


# -- the meshes and paths -------------------------------------------------------------------------
def stomach_top(tree):
    """(x, y, z) [mm] of the stomach's highest vertex, and its lowest z."""
    sys.path.insert(0, str(tree))
    import trimesh

    m = trimesh.load(ROOT / "scenes" / "stomach.obj", process=False)
    v = np.asarray(m.vertices)
    return v[np.argmax(v[:, 2])], float(v[:, 2].min()), v.mean(axis=0)


def write_path(folder: Path, rows, name="path.csv") -> str:
    text = "t_s,x_mm,y_mm,z_mm\n" + "".join(f"{t!r},{x!r},{y!r},{z!r}\n" for t, x, y, z in ((float(a), float(b), float(c), float(d)) for a, b, c, d in rows))
    (folder / name).write_text(text)
    return name


def press_rows(top, radius=10.0, depth=5.0, seconds=0.2, n=5, start=2.0):
    x, y, z = top
    zs = np.linspace(z + radius + start, z + radius - depth, n)
    return [(seconds * i / (n - 1), x, y, zz) for i, zz in enumerate(zs)]


def table_check(path, column, ok):
    """A check: the CSV table at `path` is there, and ok(values) of column(table), all finite."""
    def check(out):
        try:
            data = np.genfromtxt(path, delimiter=",", names=True)
        except OSError:
            return False
        values = column(data)
        return bool(np.all(np.isfinite(values)) and ok(values))
    return check


def trace_force(folder):
    """The trace's force is finite, its peak above 1 mN (the path presses 5 mm)."""
    return table_check(folder / "t.csv", lambda d: np.sqrt(d["force_x_N"] ** 2 + d["force_y_N"] ** 2 + d["force_z_N"] ** 2),
                       lambda f: f.max() > 1e-3)


def finite_json(folder, name="o.json"):
    def check(out):
        try:
            text = (folder / name).read_text()
        except OSError:
            return False
        return "Infinity" not in text and "NaN" not in text
    return check


# -- the cases ------------------------------------------------------------------------------------
def trace_cases(tree):
    top, zmin, centre = stomach_top(tree)
    cases = []
    for flag in ("--youngs-modulus-kpa", "--thickness-mm", "--rayleigh-alpha-per-s", "--damping-ratio",
                 "--density-kg-m3", "--foundation-kpa-per-mm", "--rayleigh-beta-s"):
        for value in ("1e300", "1e-300", "1e13"):
            cases.append((f"trace {flag} {value}", "press", [flag, value]))
    for k in ("1e300", "1e13"):
        cases.append((f"trace coupling k {k}", "press", ["--coupling-stiffness-N-per-mm", k, "--device-damping-Ns-per-m", "1e300"]))
    for flag, value in (("--youngs-modulus-kpa", "1e9"), ("--youngs-modulus-kpa", "1e-9"), ("--thickness-mm", "1e-3"),
                        ("--rayleigh-alpha-per-s", "1e6"), ("--density-kg-m3", "1e-9"), ("--damping-ratio", "10")):
        cases.append((f"trace {flag} {value} (legal)", "press", [flag, value]))  # a result, or a clean "diverged"
    cases.append(("trace --probe-radius-mm 1e12", "press", ["--probe-radius-mm", "1e12"]))
    cases.append(("trace --probe-radius-mm 1e-300", "press", ["--probe-radius-mm", "1e-300"]))
    out = []
    for name, path, flags in cases:
        def case(folder, flags=flags):
            p = write_path(folder, press_rows(top))
            code, o, e = run(["trace", "stomach", "--path", p, "--out", "t.csv", *flags], folder, tree)
            return classify(code, o, e, sane=trace_force(folder))
        out.append((name, case))

    def jump(folder):  # one step from above the organ to below it
        x, y, z = top
        p = write_path(folder, [(0.0, x, y, z + 12.0), (0.001, x, y, zmin - 12.0), (0.002, x, y, zmin - 12.0)])
        code, o, e = run(["trace", "stomach", "--path", p, "--out", "t.csv"], folder, tree)
        return classify(code, o, e, sane=lambda _o: False)  # through the organ in 1 ms: no answer is right
    out.append(("trace: a path through the organ in one step", jump))

    def inside(folder):  # starts with the sphere's centre inside the organ
        x, y, z = centre
        p = write_path(folder, [(0.0, x, y, z), (0.1, x, y, z + 1.0)])
        code, o, e = run(["trace", "stomach", "--path", p, "--out", "t.csv"], folder, tree)
        return classify(code, o, e, sane=trace_force(folder))
    out.append(("trace: a path starting inside the organ", inside))

    def below(folder):  # pressed from below into supported vertices
        x, y, _ = top
        rows = [(0.1 * i, x, y, zmin - 10.0 - 2.0 + 3.0 * i) for i in range(5)]
        p = write_path(folder, rows)
        code, o, e = run(["trace", "stomach", "--path", p, "--out", "t.csv", "--fixed-below-mm", str(zmin + 5.0)], folder, tree)
        return classify(code, o, e)
    out.append(("trace: pressed from below into supported vertices", below))

    def down_through(folder):  # down through the liver onto its support
        p = write_path(folder, [(0.0, 0.0, 0.0, 200.0), (2.0, 0.0, 0.0, -200.0)])
        code, o, e = run(["trace", "liver", "--path", p, "--out", "t.csv", "--fixed-below-mm", "-20"], folder, tree)
        return classify(code, o, e)
    out.append(("trace liver: down through the organ onto its support", down_through))

    for name, make in (("/dev/zero", lambda f: os.symlink("/dev/zero", f / "p.csv")),
                       ("a FIFO", lambda f: os.mkfifo(f / "p.csv")),
                       ("/dev/urandom", lambda f: os.symlink("/dev/urandom", f / "p.csv")),
                       ("2e6 rows", lambda f: (f / "p.csv").write_text("t_s,x_mm,y_mm,z_mm\n" + "".join(f"{i * 1e-3},0,0,{200 + i * 1e-6}\n" for i in range(2_000_000)))),
                       ("a folder", lambda f: (f / "p.csv").mkdir()),
                       ("binary bytes", lambda f: (f / "p.csv").write_bytes(os.urandom(4096)))):
        def case(folder, make=make):
            make(folder)
            code, o, e = run(["trace", "stomach", "--path", "p.csv", "--out", "t.csv"], folder, tree, timeout=40)
            return classify(code, o, e, sane=lambda _o: False)
        out.append((f"trace --path {name}", case))
    return out


def magnitude_cases(tree):
    out = []
    for cmd, extra in (("palpate", ["--json", "o.json"]), ("sweep", ["--out", "s.csv", "--points", "4", "--settle-s", "0.05"])):
        for flag, value in (("--youngs-modulus-kpa", "1e300"), ("--youngs-modulus-kpa", "1e-300"), ("--thickness-mm", "1e300"),
                            ("--depth-mm", "1e-308"), ("--probe-radius-mm", "1e12"), ("--rayleigh-alpha-per-s", "1e300"),
                            ("--density-kg-m3", "1e-300"), ("--foundation-kpa-per-mm", "1e300")):
            def case(folder, cmd=cmd, extra=extra, flag=flag, value=value):
                code, o, e = run([cmd, "stomach", flag, value, *extra], folder, tree)
                before = {"o.json", "s.csv"}
                left = listing(folder) - before if code == 2 else ()
                check = finite_json(folder) if cmd == "palpate" else _sweep_sane(folder)
                return classify(code, o, e, left=left, sane=check)
            out.append((f"{cmd} {flag} {value}", case))
    for flag, value in (("--youngs-modulus-kpa", "1e9"), ("--thickness-mm", "1e-3"), ("--depth-mm", "1e-3"), ("--probe-radius-mm", "1000")):
        def case(folder, flag=flag, value=value):
            code, o, e = run(["palpate", "stomach", flag, value, "--json", "o.json"], folder, tree)
            return classify(code, o, e, left=listing(folder) if code == 2 else (), sane=finite_json(folder))
        out.append((f"palpate {flag} {value} (legal)", case))
    for key, value in (("radius_mm", "1e12"), ("radius_mm", "1e9")):
        def case(folder, key=key, value=value):
            text = (ROOT / "scenes" / "stomach.toml").read_text().replace("radius_mm = 10.0", f"{key} = {value}")
            text = text.replace('path = "stomach.obj"', f'path = "{ROOT / "scenes" / "stomach.obj"}"')
            (folder / "s.toml").write_text(text)
            code, o, e = run(["palpate", "s.toml", "--json", "o.json"], folder, tree)
            return classify(code, o, e, sane=lambda _o: _palpate_force(folder) > 1e-3)
        out.append((f"scene [probe] {key} = {value}", case))

    def thickness0(folder):
        text = (ROOT / "scenes" / "stomach.toml").read_text().replace("thickness_mm = 3.0", "thickness_mm = 0")
        text = text.replace('path = "stomach.obj"', f'path = "{ROOT / "scenes" / "stomach.obj"}"')
        (folder / "s.toml").write_text(text)
        code, o, e = run(["sweep", "s.toml", "--out", "s.csv", "--points", "4"], folder, tree)
        return classify(code, o, e, left=listing(folder) - {"s.toml"} if code == 2 else (), sane=_sweep_sane(folder))
    out.append(("sweep on a material scene with thickness_mm = 0", thickness0))
    return out


def _palpate_force(folder) -> float:
    try:
        data = json.loads((folder / "o.json").read_text())
    except (OSError, ValueError):
        return 0.0
    found = [v for k, v in _walk(data) if k == "peak_force_N" and isinstance(v, (int, float))]
    return float(found[0]) if found else 0.0


def _walk(d):
    if isinstance(d, dict):
        for k, v in d.items():
            yield k, v
            yield from _walk(v)
    elif isinstance(d, list):
        for v in d:
            yield from _walk(v)


def _sweep_sane(folder):
    """The sweep's stiffness is finite, > 0 and under 1 kN/mm at every point."""
    return table_check(folder / "s.csv", lambda d: d["stiffness_N_per_mm"], lambda k: bool(np.all(k > 0) and np.all(k < 1e3)))


SPEC = (ROOT / "scenes" / "datasets" / "tiny.toml").read_text()
"""The smallest dataset: the stomach's baseline and one lesion, 3 points each."""


def dataset_cases(tree):
    out = []
    specs = {
        "nested 3000 deep": "[dataset]\nscenes = " + "[" * 3000 + "]" * 3000 + "\n",
        "lesion count 2**63-1": SPEC.replace("count = 1", "count = 9223372036854775807"),
        "lesion count 1e9": SPEC.replace("count = 1", "count = 1000000000"),
        "10,000 items": SPEC.replace("count = 1", "count = 100").replace("radii_mm = [15.0]", "radii_mm = [" + ",".join(str(10 + i) for i in range(10)) + "]")
                             .replace("stiffness_factors = [3.0]", "stiffness_factors = [" + ",".join(str(2 + i) for i in range(10)) + "]"),
        "points 2**63-1": SPEC.replace("points = 3", "points = 9223372036854775807"),
        "depth 1e-308": SPEC.replace("depth_mm = 5.0\nramp", "depth_mm = 1e-308\nramp"),
        "radius 1e300": SPEC.replace("radii_mm = [15.0]", "radii_mm = [1e300]"),
        "dt 1e-300": SPEC.replace("dt_ms = 0.5", "dt_ms = 1e-300"),
    }
    for name, text in specs.items():
        if name == "10,000 items":
            text = text + "\n"  # with a cost limit under its cost: refused before any planning
            name = "10,000 items over --max-region-steps 1e5"

        def case(folder, text=text, name=name):
            (folder / "spec.toml").write_text(text)
            extra = ["--max-region-steps", "1e5"] if "max-region-steps" in name else []
            code, o, e = run(["sweep", "--dataset", "spec.toml", "--out", "ds", *extra], folder, tree, timeout=40)
            return classify(code, o, e, left=listing(folder) - {"spec.toml"} if code == 2 else ())
        out.append((f"dataset spec: {name}", case))
    def many_items(folder):  # 10,000 items: a long run, which must say at once what it plans (it was silent for minutes)
        (folder / "spec.toml").write_text(specs["10,000 items"])
        env = dict(os.environ, PYTHONPATH=str(tree), WARP_CACHE_PATH=str(ROOT / ".warp_cache"))
        proc = subprocess.Popen([sys.executable, "-m", "almsdm_warp.cli.main", "sweep", "--dataset", "spec.toml", "--out", "ds"],
                                cwd=folder, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, preexec_fn=_limits)
        try:
            out, _ = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            out, _ = proc.communicate()
        return "sane" if b"10001 item(s)" in out else "hang"
    out.append(("dataset spec: 10,000 items, said within 20 s", many_items))
    for flags in (["--points", "9"], ["--probe-radius-mm", "3"], ["--fixed-below-mm", "0"], ["--integrator", "implicit"],
                  ["--youngs-modulus-kpa", "5"], ["--depth-mm", "5"]):
        def case(folder, flags=flags):
            (folder / "spec.toml").write_text(SPEC)
            code, o, e = run(["sweep", "--dataset", "spec.toml", "--out", "ds", *flags], folder, tree)
            return classify(code, o, e, left=listing(folder) - {"spec.toml"} if code == 2 else (), sane=lambda _o: False)
        out.append((f"sweep --dataset {' '.join(flags)}", case))

    def ray(folder):
        code, o, e = run(["sweep", "stomach", "--out", "s.csv", "--points", "4", "--ray"], folder, tree)
        return classify(code, o, e, left=listing(folder) if code == 2 else (), sane=_sweep_sane(folder))
    out.append(("sweep --ray without Ray", ray))

    def cost(folder):  # refused by the cost check, then the corrected spec into the same folder
        (folder / "spec.toml").write_text(SPEC.replace("points = 3", "points = 4000").replace("settle_s = 0.02", "settle_s = 1000"))
        code, o, e = run(["sweep", "--dataset", "spec.toml", "--out", "ds"], folder, tree)
        first = classify(code, o, e, left=listing(folder) - {"spec.toml"} if code == 2 else ())
        if first != "clean":
            return first
        (folder / "spec.toml").write_text(SPEC)
        code, o, e = run(["sweep", "--dataset", "spec.toml", "--out", "ds"], folder, tree)
        return "clean" if code == 0 else "stuck"
    out.append(("dataset: refused by the cost check, then corrected", cost))
    return out


def _dataset(folder, tree, extra=(), timeout=LIMIT_S):
    return run(["sweep", "--dataset", "spec.toml", "--out", "ds", *extra], folder, tree, timeout=timeout)


def resume_cases(tree):
    """Damaged or interrupted datasets: 'sane' when a rerun (or following the one line's advice) ends in the
    uninterrupted table, 'stuck' otherwise."""
    ref = {}

    def reference(folder):
        if "table" not in ref:
            sub = folder.parent / "reference"
            sub.mkdir(exist_ok=True)
            (sub / "spec.toml").write_text(SPEC)
            code, o, e = _dataset(sub, tree)
            assert code == 0, e
            ref["table"] = dict(np.load(sub / "ds" / "table.npz"))
            ref["folder"] = sub / "ds"
        return ref

    def converge(folder, extra=()):
        for _ in range(3):  # a rerun, or the one line's advice followed
            code, o, e = _dataset(folder, tree, extra)
            if code == 0:
                table = dict(np.load(folder / "ds" / "table.npz"))
                same = all(np.array_equal(table[c], reference(folder)["table"][c]) for c in ("vertex", "peak_force_N", "hold_force_N"))
                return "sane" if same else "silent"
            if code == "hang":
                return "hang"
            if "Traceback" in e:
                return "traceback"
            if "delete" not in e:
                return "stuck"
            target = next((w.rstrip(":,;") for w in e.split() if (folder / w.rstrip(":,;")).exists() and w.rstrip(":,;") not in ("ds",)), None)
            if target is None:
                return "stuck"
            import shutil
            shutil.rmtree(folder / target, ignore_errors=True)
            (folder / target).unlink(missing_ok=True)
        return "stuck"

    def copy_ref(folder):
        import shutil
        reference(folder)
        (folder / "spec.toml").write_text(SPEC)
        shutil.copytree(ref["folder"], folder / "ds")
        return folder / "ds"

    def parts_half_removed(folder):  # killed while an item's parts folder was removed: chunks, no plan.json
        ds = copy_ref(folder)
        m = json.loads((ds / "dataset.json").read_text())
        name = sorted(m["items"])[-1]
        del m["items"][name]
        (ds / "dataset.json").write_text(json.dumps(m))
        (ds / "table.npz").unlink()
        parts = ds / "items" / f"{name}.npz.parts"
        parts.mkdir()
        table = dict(np.load(ds / "items" / f"{name}.npz"))
        np.savez(parts / "chunk_000000.npz", **{k: v[:2] for k, v in table.items()})
        (ds / "items" / f"{name}.npz").unlink()
        return converge(folder)

    def truncated(name):
        def case(folder):
            ds = copy_ref(folder)
            target = ds / name
            if name == "plan.json":
                m = json.loads((ds / "dataset.json").read_text())
                item = sorted(m["items"])[-1]
                del m["items"][item]
                (ds / "dataset.json").write_text(json.dumps(m))
                parts = ds / "items" / f"{item}.npz.parts"
                parts.mkdir()
                table = dict(np.load(ds / "items" / f"{item}.npz"))
                np.savez(parts / "chunk_000000.npz", **{k: v[:2] for k, v in table.items()})
                (parts / "plan.json").write_text('{"key": "abc')
                (ds / "items" / f"{item}.npz").unlink()
            else:
                target.write_text(target.read_text()[:40])
            (ds / "table.npz").unlink()
            return converge(folder)
        return case

    def chunk_changed(folder):
        (folder / "spec.toml").write_text(SPEC)
        p = subprocess.Popen([sys.executable, "-m", "almsdm_warp.cli.main", "sweep", "--dataset", "spec.toml", "--out", "ds"],
                             cwd=folder, env=dict(os.environ, PYTHONPATH=str(tree), WARP_CACHE_PATH=str(ROOT / ".warp_cache")),
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.time() + 60
        while time.time() < deadline and not list((folder / "ds" / "items").glob("*.parts/chunk_*.npz")) if (folder / "ds" / "items").exists() else time.time() < deadline:
            time.sleep(0.02)
        p.kill()
        p.wait()
        return converge(folder, ["--chunk", "3"])

    def killed(delay):
        def case(folder):
            (folder / "spec.toml").write_text(SPEC)
            p = subprocess.Popen([sys.executable, "-m", "almsdm_warp.cli.main", "sweep", "--dataset", "spec.toml", "--out", "ds"],
                                 cwd=folder, env=dict(os.environ, PYTHONPATH=str(tree), WARP_CACHE_PATH=str(ROOT / ".warp_cache")),
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            time.sleep(delay)
            p.kill()
            p.wait()
            return converge(folder)
        return case

    out = [("resume: killed while an item's parts were removed", parts_half_removed),
           ("resume: truncated plan.json", truncated("plan.json")),
           ("resume: truncated dataset.json", truncated("dataset.json")),
           ("resume: chunk changed mid-resume", chunk_changed)]
    out += [(f"resume: SIGKILL at {d:.1f} s", killed(d)) for d in (2.0, 3.0, 4.0, 5.0, 6.0, 8.0)]
    return out


def usd_cases(tree):
    def leftover(folder):  # trace --usd killed (SIGKILL) while it records; a later run removes its temporary
        top, _zmin, _c = stomach_top(tree)
        rows = press_rows(top, seconds=20.0, n=50)
        p = write_path(folder, rows)
        env = dict(os.environ, PYTHONPATH=str(tree), WARP_CACHE_PATH=str(ROOT / ".warp_cache"))
        proc = subprocess.Popen([sys.executable, "-m", "almsdm_warp.cli.main", "trace", "stomach", "--path", p, "--usd", "t.usdc"],
                                cwd=folder, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.time() + LIMIT_S
        while time.time() < deadline and proc.poll() is None and not list(folder.glob(".t.usdc.*")):
            time.sleep(0.05)
        time.sleep(0.5)
        proc.kill()
        proc.wait()
        if not list(folder.glob(".t.usdc.*")):
            return "harness: no temporary seen"
        write_path(folder, press_rows(top))
        code, o, e = run(["trace", "stomach", "--path", p, "--usd", "t.usdc"], folder, tree)
        if code != 0:
            return classify(code, o, e)
        return "sane" if not list(folder.glob(".t.usdc.*")) else "silent"
    return [("trace --usd: a killed run's temporary", leftover)]


def disk_cases(tree):
    """Every output kind on a full 256 KiB tmpfs (root only): one line, exit 2, nothing left."""
    if os.geteuid() != 0:
        return []
    top, _zmin, _c = stomach_top(tree)
    out = []
    for name, argv in (("trace --usd", ["trace", "stomach", "--path", "{p}", "--usd", "{d}/t.usdc"]),
                       ("trace --out", ["trace", "stomach", "--path", "{p}", "--out", "{d}/t.csv"]),
                       ("palpate --usd", ["palpate", "stomach", "--usd", "{d}/p.usdc", "--usd-every", "1"]),
                       ("sweep --out", ["sweep", "stomach", "--points", "3000", "--settle-s", "0.01", "--hold-s", "0.01", "--ramp-s", "0.02", "--out", "{d}/s.csv"]),
                       ("sweep --dataset", ["sweep", "--dataset", "{s}", "--out", "{d}/ds"])):
        def case(folder, argv=argv):
            disk = folder / "disk"
            disk.mkdir()
            if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(disk)]).returncode:
                return "skipped"
            try:
                fd = os.open(disk / "fill", os.O_WRONLY | os.O_CREAT)
                try:  # every block taken
                    while os.write(fd, b"\0" * 4096):
                        pass
                except OSError:
                    pass
                os.close(fd)
                p = write_path(folder, press_rows(top))
                (folder / "spec.toml").write_text(SPEC)
                args = [a.format(p=p, d=str(disk), s="spec.toml") for a in argv]
                code, o, e = run(args, folder, tree)
                left = listing(disk) - {"fill"} if code == 2 else ()
                return classify(code, o, e, left=left, sane=lambda _o: False)
            finally:
                subprocess.run(["umount", str(disk)])
        out.append((f"full disk: {name}", case))
    return out


FACADE = """
import math, numpy as np, warnings
warnings.simplefilter("error")
import almsdm_warp as a
from almsdm_warp.scene.loader import resolve_scene_or_mesh
scene = resolve_scene_or_mesh("stomach"); mesh = scene.load_mesh()
try:
{body}
except (ValueError, TypeError) as exc:
    print("ERROR", type(exc).__name__, exc)
"""

FACADE_CASES = {
    "Palpation(probe_radius=1e9)": ("probe_radius", "p = a.Palpation(mesh, scene.tissue, rings=2, probe_radius=1e9); p.touch(0); r = p.press(0.005, 0.05, 0.05, 0.05); print('VALUE', r.peak_force_N)"),
    "BatchPalpation(probe_radius=1e9)": ("probe_radius", "b = a.BatchPalpation(mesh, scene.tissue, rings=2, probe_radius=1e9); b.touch([0, 5]); r = b.press(0.005, 0.05, 0.05, 0.05); print('VALUE', float(np.min(r.peak_force)))"),
    "BatchPalpation.press(depth=0)": ("depth", "b = a.BatchPalpation(mesh, scene.tissue, rings=2); b.touch([0, 5]); r = b.press(0.0, 0.05, 0.05, 0.05); print('VALUE', float(np.max(r.stiffness_N_per_mm)))"),
    "BatchPalpation.press(depth=nan)": ("depth", "b = a.BatchPalpation(mesh, scene.tissue, rings=2); b.touch([0, 5]); r = b.press(float('nan'), 0.05, 0.05, 0.05); print('VALUE', float(np.max(r.peak_force)))"),
    "Palpation.press(depth=0)": ("depth", "p = a.Palpation(mesh, scene.tissue, rings=2); p.touch(0); r = p.press(0.0, 0.05, 0.05, 0.05); print('VALUE', r.peak_force_N)"),
    "Palpation.press(depth=1e-308)": ("depth", "p = a.Palpation(mesh, scene.tissue, rings=2); p.touch(0); r = p.press(1e-308, 0.05, 0.05, 0.05); print('VALUE', r.peak_force_N / 1e-305)"),
    "Palpation.set_probe(99, ...)": ("mode", "p = a.Palpation(mesh, scene.tissue, rings=2); p.touch(0); p.set_probe(99, [0.0, 0.0, 0.0]); f = p.step(); print('VALUE', 'accepted')"),
    "Palpation.set_probe(displacement, NaN)": ("target", "p = a.Palpation(mesh, scene.tissue, rings=2); p.touch(0); p.set_probe(a.PROBE_DISPLACEMENT, [float('nan'), 0.0, 0.0]); f = p.step(); print('VALUE', 'accepted')"),
    "Palpation.set_probe_force(inf)": ("force", "p = a.Palpation(mesh, scene.tissue, rings=2); p.touch(0); p.set_probe_force([0.0, 0.0, float('inf')]); f = p.step(); print('VALUE', 'accepted')"),
    "Palpation.touch(10**9)": ("vertex", "p = a.Palpation(mesh, scene.tissue, rings=2); p.touch(10**9); print('VALUE', 'accepted')"),
    "Palpation.touch(-1)": ("vertex", "p = a.Palpation(mesh, scene.tissue, rings=2); p.touch(-1); print('VALUE', 'accepted')"),
    "Palpation(dt=nan)": ("dt", "p = a.Palpation(mesh, scene.tissue, rings=2, dt=float('nan')); print('VALUE', 'accepted')"),
    "Palpation(dt=1e300)": ("dt", "p = a.Palpation(mesh, scene.tissue, rings=2, dt=1e300); p.touch(0); r = p.press(0.005, 0.05, 0.05, 0.05); print('VALUE', r.peak_force_N)"),
    "Palpation(fixed_below=nan)": ("fixed_below", "p = a.Palpation(mesh, scene.tissue, rings=2, fixed_below=float('nan')); print('VALUE', 'accepted')"),
    "Palpation(integrator='bogus')": ("integrator", "p = a.Palpation(mesh, scene.tissue, rings=2, integrator='bogus'); print('VALUE', 'accepted')"),
    "Palpation(rings=True)": ("rings", "p = a.Palpation(mesh, scene.tissue, rings=True); print('VALUE', 'accepted')"),
    "BatchPalpation.touch([10**9])": ("vert", "b = a.BatchPalpation(mesh, scene.tissue, rings=2); b.touch([10**9]); print('VALUE', 'accepted')"),
    "BatchPalpation.press(ramp=-1)": ("ramp", "b = a.BatchPalpation(mesh, scene.tissue, rings=2); b.touch([0]); r = b.press(0.005, -1.0, 0.05, 0.05); print('VALUE', 'accepted')"),
    "Material(youngs_modulus=1e300)": ("youngs_modulus", "m = a.Material(youngs_modulus=1e300); print('VALUE', 'accepted')"),
    "Material(thickness=1e300)": ("thickness", "m = a.Material(youngs_modulus=1e3, thickness=1e300); print('VALUE', 'accepted')"),
    "TissueParams(edge_stiffness=1e300)": ("edge_stiffness", "m = a.TissueParams(edge_stiffness=1e300); print('VALUE', 'accepted')"),
    "load_mesh(scale=nan)": ("scale", "m = a.load_mesh('{root}/scenes/stomach.obj', scale=float('nan')); print('VALUE', 'accepted')"),
}


def facade_cases(tree):
    out = []
    for name, (arg, body) in FACADE_CASES.items():
        def case(folder, arg=arg, body=body):
            code, o, e = run([], folder, tree, python=FACADE.format(body=textwrap.indent(body.format(root=ROOT), "    ")))
            if code == "hang":
                return "hang"
            if code != 0:
                return "traceback"
            lines = [l for l in o.splitlines() if l.startswith(("ERROR", "VALUE"))]
            if not lines:
                return "traceback"
            if lines[-1].startswith("ERROR"):
                return "clean" if arg in lines[-1] else "noisy"
            value = lines[-1].split(None, 1)[1]
            try:
                v = float(value)
            except ValueError:
                return "silent"  # nonsense accepted
            return "sane" if np.isfinite(v) and 1e-3 < v < 1e3 else "silent"
        out.append((f"facade: {name}", case))

    def banner(folder):  # the facade prints nothing of Warp's unless asked (ALMSDM_VERBOSE=1)
        code, o, e = run([], folder, tree, python="import almsdm_warp as a\nfrom almsdm_warp.scene.loader import resolve_scene_or_mesh\n"
                         "m = resolve_scene_or_mesh('stomach').load_mesh(); p = a.Palpation(m, rings=2); p.touch(0); p.press(0.005, 0.02, 0.02, 0.02)")
        if code != 0:
            return "traceback"
        return "sane" if not (o.strip() or e.strip()) else "noisy"
    out.append(("facade: a press prints nothing", banner))
    return out


GROUPS = {"trace": trace_cases, "magnitude": magnitude_cases, "dataset": dataset_cases, "resume": resume_cases,
          "usd": usd_cases, "disk": disk_cases, "facade": facade_cases}
OUTCOMES = ("clean", "sane", "traceback", "hang", "silent", "noisy", "stuck")


def table(before: str, after: str) -> str:
    """A Markdown table: per group of cases, the runs and each outcome's count before -> after."""
    runs = [json.loads(Path(p).read_text())["cases"] for p in (before, after)]
    rows = ["| cases | runs | " + " | ".join(OUTCOMES) + " |", "|---" * (len(OUTCOMES) + 2) + "|"]
    groups = {name: group for group, make in GROUPS.items() for name, _case in make(ROOT)}
    for group in [*GROUPS, "all"]:
        names = [n for n in runs[1] if group == "all" or groups.get(n) == group]
        if not names:
            continue
        counts = [collections.Counter(r.get(n, "not run") for n in names) for r in runs]
        cells = [f"{c0[o]} -> {c1[o]}" if c0[o] or c1[o] else "0" for o in OUTCOMES for c0, c1 in [counts]]
        rows.append(f"| {group} | {len(names)} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", default=str(ROOT), help="the checkout whose package runs the cases (default: this one)")
    ap.add_argument("--only", default=None, help="only the cases whose name holds this text")
    ap.add_argument("--json", default=None, help="write every case's outcome here")
    ap.add_argument("--why", action="store_true", help="print each case's last command's code and last lines")
    ap.add_argument("--table", nargs=2, metavar=("BEFORE", "AFTER"), help="print the counts of two campaigns' --json by group")
    args = ap.parse_args(argv)
    if args.table:
        print(table(*args.table))
        return 0
    tree = Path(args.tree).resolve()
    results, counts = {}, collections.Counter()
    with tempfile.TemporaryDirectory(prefix="fuzz_surfaces_") as tmp:
        for group, make in GROUPS.items():
            for name, case in make(tree):
                if args.only and args.only not in name:
                    continue
                folder = Path(tmp) / f"case{len(results):03d}"
                folder.mkdir()
                t0 = time.time()
                try:
                    outcome = case(folder)
                except Exception as exc:  # noqa: BLE001 (the harness's own failure: counted, said)
                    outcome = f"harness: {type(exc).__name__}: {exc}"
                results[name] = outcome
                counts[outcome if outcome in OUTCOMES else "harness"] += 1
                print(f"{outcome:10s} {time.time() - t0:5.1f} s  {name}", flush=True)
                if args.why and LAST:
                    print(f"    {LAST}", flush=True)
                LAST.clear()
    print(f"runs {len(results)}: " + ", ".join(f"{o} {counts[o]}" for o in (*OUTCOMES, "harness") if counts[o] or o in OUTCOMES))
    if args.json:
        Path(args.json).write_text(json.dumps({"tree": str(tree), "counts": counts, "cases": results}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
