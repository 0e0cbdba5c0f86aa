"""Soak: a long run in one process, watching memory and the rest shape.

    python scripts/soak.py [SCENE] [--steps 1000000] [--relocations 10000] [--rings 4]
                           [--integrator explicit|implicit] [--device cpu] [--json soak.json]

Phase 1, one palpation: press cycles at one contact (10 mm ramp 0.1 s, hold 0.2 s, release and
settle 0.7 s at dt = 1 ms: 1000 steps a cycle) for --steps steps. Phase 2, relocations: touch a
random surface vertex (seeded), press 5 mm over 20 steps, release for 30; --relocations times
(each rebuilds the region and recaptures the step graphs).

Measured: resident memory (VmRSS from /proc/self/status) sampled through both phases, with its
growth after a warm-up and the slope of a least-squares line; the drift of the rest shape: the
largest distance of any vertex from its rest position once each cycle has settled and at the
end (the tissue must come back), and whether the device's rest positions and rest lengths are
still the same bits. Exit code 1 when memory grew or the shape drifted past the limits below.
A long check, not a test; tests/test_soak.py runs a short version.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

CYCLE = (0.1, 0.2, 0.7)
"""Ramp, hold, release-and-settle of one press cycle [s]."""
DEPTH = 10.0e-3
MAX_GROWTH_MB = 8.0
"""Resident memory may not grow more than this after the warm-up (allocator noise is ~1 MB)."""
MAX_DRIFT_M = 1.0e-6
"""No vertex may be further than this from rest once a cycle has settled."""


def rss_kb() -> int:
    """Resident set size of this process [kB] (Linux: VmRSS in /proc/self/status)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("no VmRSS in /proc/self/status")


class Recorder:
    """(phase, count, seconds, rss kB) samples, and the drift seen after each settled cycle."""

    def __init__(self):
        self.t0 = time.perf_counter()
        self.samples = []
        self.drift = []

    def sample(self, phase: str, count: int) -> None:
        self.samples.append((phase, int(count), time.perf_counter() - self.t0, rss_kb()))


def rest_bits(pal):
    return pal.model.particle_q_rest.numpy().tobytes() + pal.model.spring_rest_length.numpy().tobytes()


def largest_offset(pal) -> float:
    """Largest distance of any vertex from its rest position [m], in both states."""
    rest = pal.model.particle_q_rest.numpy()
    return max(float(np.linalg.norm(s.particle_q.numpy() - rest, axis=1).max()) for s in pal.states)


def press_cycles(pal, steps: int, rec: Recorder, sample_every: int = 10_000) -> int:
    """Press cycles at the touched vertex for `steps` steps; the steps taken."""
    from almsdm_warp.sim.model import PROBE_DISPLACEMENT, PROBE_OFF

    dt = pal.dt
    ramp, hold, settle = (max(int(round(x / dt)), 1) for x in CYCLE)
    cycle = ramp + hold + settle
    rest, n = pal.rest_position(), pal.inward_normal()
    target = np.zeros(3)
    done = 0
    while done < steps:
        s = done % cycle
        if s < ramp + hold:
            np.add(rest, n * (DEPTH * min((s + 1) / ramp, 1.0)), out=target)
            pal.set_probe(PROBE_DISPLACEMENT, target)
        elif s == ramp + hold:
            pal.set_probe(PROBE_OFF)
        pal.step()
        done += 1
        if done % cycle == 0:
            pal.check_finite(done)
            rec.drift.append(largest_offset(pal))
        if done % sample_every == 0:
            rec.sample("press", done)
    return done


def relocations(pal, count: int, rec: Recorder, seed: int = 0, sample_every: int = 100) -> None:
    """`count` relocations to random surface vertices, each with a short press and release."""
    from almsdm_warp.sim.model import PROBE_DISPLACEMENT, PROBE_OFF

    rng = np.random.default_rng(seed)
    surface = pal.mesh.surface_vertices
    for k in range(1, count + 1):
        pal.touch(int(rng.choice(surface)))
        rest, n = pal.rest_position(), pal.inward_normal()
        for s in range(20):
            pal.set_probe(PROBE_DISPLACEMENT, rest + n * (0.5 * DEPTH * (s + 1) / 20))
            pal.step()
        pal.set_probe(PROBE_OFF)
        for _ in range(30):
            pal.step()
        if k % sample_every == 0:
            pal.check_finite(k)
            rec.sample("relocate", k)


def growth(samples, skip: int):
    """(growth after the first `skip` samples [MB], slope [kB per 1000 units]) of RSS."""
    if len(samples) <= skip + 1:
        return 0.0, 0.0
    x = np.array([s[1] for s in samples[skip:]], dtype=np.float64)
    y = np.array([s[3] for s in samples[skip:]], dtype=np.float64)
    slope = float(np.polyfit(x, y, 1)[0]) * 1000.0 if np.ptp(x) > 0 else 0.0
    return float(y[-1] - y[0]) / 1024.0, slope


def soak(scene=None, *, steps=1_000_000, relocation_count=10_000, rings=4, integrator="explicit", device="cpu", dt=1e-3,
         press_sample_every=10_000, relocation_sample_every=100, warmup_samples=2, log=None):
    """Run both phases; returns a dict of what was measured (see the module docstring)."""
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.scene.loader import resolve_scene_or_mesh
    from almsdm_warp.warp_init import init_warp

    init_warp()
    sc = resolve_scene_or_mesh(scene)
    mesh = sc.load_mesh()
    pal = Palpation(mesh, sc.tissue, rings=rings, integrator=integrator, dt=dt, device=device)
    sv = mesh.surface_vertices
    pal.touch(int(sv[np.argmax(mesh.vertices[sv, 2])]))
    bits = rest_bits(pal)
    rec = Recorder()
    rec.sample("start", 0)
    t0 = time.perf_counter()
    done = press_cycles(pal, steps, rec, press_sample_every)
    press_s = time.perf_counter() - t0
    if log:
        log(f"press: {done:,} steps in {press_s:.1f} s ({press_s / max(done, 1) * 1e6:.2f} us a step, Python loop included)")
    t0 = time.perf_counter()
    relocations(pal, relocation_count, rec, sample_every=relocation_sample_every)
    relocate_s = time.perf_counter() - t0
    if log:
        log(f"relocate: {relocation_count:,} relocations in {relocate_s:.1f} s ({relocate_s / max(relocation_count, 1) * 1e3:.2f} ms each)")
    # let the last region settle, then everything must be back at rest
    from almsdm_warp.sim.model import PROBE_OFF

    pal.set_probe(PROBE_OFF)
    for _ in range(int(round(CYCLE[2] / dt))):
        pal.step()
    final_offset = largest_offset(pal)
    press_samples = [s for s in rec.samples if s[0] in ("start", "press")]
    reloc_samples = [s for s in rec.samples if s[0] == "relocate"]
    press_growth, press_slope = growth(press_samples, warmup_samples)
    reloc_growth, reloc_slope = growth(reloc_samples, warmup_samples)
    rss = [s[3] for s in rec.samples]
    result = {
        "scene": sc.name,
        "rings": rings,
        "integrator": integrator,
        "device": str(pal.device),
        "dt_s": dt,
        "steps": done,
        "relocations": relocation_count,
        "press_s": press_s,
        "relocate_s": relocate_s,
        "rss_start_MB": rss[0] / 1024.0,
        "rss_max_MB": max(rss) / 1024.0,
        "rss_end_MB": rss[-1] / 1024.0,
        "press_rss_growth_MB": press_growth,
        "press_rss_slope_kB_per_1000_steps": press_slope,
        "relocation_rss_growth_MB": reloc_growth,
        "relocation_rss_slope_kB_per_1000_relocations": reloc_slope,
        "settled_offset_max_mm": max(rec.drift, default=0.0) * 1e3,
        "settled_offset_last_mm": (rec.drift[-1] if rec.drift else 0.0) * 1e3,
        "final_offset_mm": final_offset * 1e3,
        "rest_shape_bits_unchanged": rest_bits(pal) == bits,
        "samples": [{"phase": p, "count": c, "t_s": round(t, 3), "rss_kB": r} for p, c, t, r in rec.samples],
    }
    result["ok"] = bool(
        result["rest_shape_bits_unchanged"]
        and max(press_growth, reloc_growth) <= MAX_GROWTH_MB
        and result["settled_offset_max_mm"] <= MAX_DRIFT_M * 1e3
        and result["final_offset_mm"] <= MAX_DRIFT_M * 1e3
    )
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", nargs="?", default=None, help="scene name, .toml or mesh (default: stomach)")
    parser.add_argument("--steps", type=float, default=1e6)
    parser.add_argument("--relocations", type=float, default=1e4)
    parser.add_argument("--rings", type=int, default=4)
    parser.add_argument("--integrator", choices=("explicit", "implicit"), default="explicit")
    parser.add_argument("--dt-ms", type=float, default=1.0)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    r = soak(args.scene, steps=int(args.steps), relocation_count=int(args.relocations), rings=args.rings,
             integrator=args.integrator, device=args.device, dt=args.dt_ms * 1e-3, log=print)
    print(f"memory: VmRSS {r['rss_start_MB']:.1f} MB at start, {r['rss_max_MB']:.1f} MB at most, {r['rss_end_MB']:.1f} MB at the end")
    print(f"  press phase: {r['press_rss_growth_MB']:+.2f} MB after warm-up, slope {r['press_rss_slope_kB_per_1000_steps']:+.3f} kB per 1000 steps")
    print(f"  relocations: {r['relocation_rss_growth_MB']:+.2f} MB after warm-up, slope "
          f"{r['relocation_rss_slope_kB_per_1000_relocations']:+.1f} kB per 1000 relocations")
    print(f"rest shape: largest offset after a settled cycle {r['settled_offset_max_mm']:.3g} mm (last {r['settled_offset_last_mm']:.3g}), "
          f"at the end {r['final_offset_mm']:.3g} mm; rest arrays unchanged: {r['rest_shape_bits_unchanged']}")
    if args.json:
        from almsdm_warp.export.output import write_json

        write_json(args.json, r)
        print(f"wrote {args.json}")
    print("ok" if r["ok"] else "FAILED: memory grew or the rest shape drifted (limits in scripts/soak.py)")
    return 0 if r["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
