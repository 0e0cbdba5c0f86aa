"""Where a sweep's wall time goes: host phases, the press kernels' time on the device, the way to the first press."""

from __future__ import annotations

import math
import threading
import time
from contextlib import contextmanager

import numpy as np

PHASES = ("loading", "sampling", "set-up", "waiting for the points", "region build", "critical steps", "planning", "launch",
          "waiting for the device", "read-back", "checks", "writing", "waiting for the writer", "gather", "output")
"""The host phases of a sweep's wall time (SweepTimes; "loading": the mesh read, checked and its topology); the
device's press time is counted apart."""


class SweepTimes:
    """Where a sweep's wall time goes: seconds per host phase, summed over the threads that ran it
    (one a device, and the writer's), and the press kernels' time on the device.

    On CUDA the press time is the union of the intervals between events recorded around each
    chunk's press on its stream, read when the chunk's results are read (a synchronisation the sweep
    makes anyway); on the CPU, where launches are synchronous, it is the launches' wall time.
    """

    def __init__(self):
        self.t0 = time.perf_counter()
        self.seconds = dict.fromkeys(PHASES, 0.0)
        self.press_s = 0.0
        """Press kernels [s]: per device, the time it was pressing, summed over devices."""
        self.pressing: list[tuple[float, float]] = []
        """(begin, end) of each chunk's press [s since t0], on the host's clock (on CUDA the device's
        events moved by the host time of a synchronised origin event: within a few microseconds)."""
        self.marks: dict[str, float] = {}
        """When [s since t0] each milestone of the way to the first press was first reached (mark())."""
        self.region_steps = 0
        """Region-steps launched (each press's steps, substeps counted), summed over the devices."""
        self.host_per_chunk: list[float] = []
        """Host time [s] of each chunk on its device's thread (build, plan, launch, read-back, checks)."""
        self.device_spans: dict[str, tuple[float, float]] = {}
        """Each device's first press's start and last press's end [s since t0]."""
        self.repressed = 0
        """Presses that diverged at their planned substeps and were pressed again at more (BatchResult.substeps)."""
        self.near_ring = 0
        """Presses whose sphere came near their region's fixed ring on tets (sweep_lanes.near_ring)."""
        self._lock = threading.Lock()

    @contextmanager
    def phase(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - t0)

    def add(self, name: str, seconds: float) -> None:
        with self._lock:
            self.seconds[name] += seconds

    def add_steps(self, count: int) -> None:
        """`count` region-steps launched (presses x their steps)."""
        with self._lock:
            self.region_steps += int(count)

    def add_repressed(self, count: int) -> None:
        with self._lock:
            self.repressed += int(count)

    def add_near_ring(self, count: int) -> None:
        with self._lock:
            self.near_ring += int(count)

    def notes(self) -> list[str]:
        """The command line's notes: the presses pressed again, and those whose sphere came near their fixed ring."""
        out = []
        if self.repressed:
            out.append(f"{self.repressed} press(es) diverged at their planned substeps (0.9 of the critical step at rest) and were "
                       f"pressed again at twice or four times as many: each of their rows is that press's")
        if self.near_ring:
            out.append(f"{self.near_ring} press(es) brought the sphere within half its radius of their region's fixed ring at full "
                       f"depth (tets), which holds still tissue the press moves: their forces may be far off the global model's; "
                       f"more rings, or --rings auto")
        return out

    def mark(self, name: str) -> None:
        """Note the first time `name` is reached (the way to the first press: what it waits for)."""
        with self._lock:
            self.marks.setdefault(name, time.perf_counter() - self.t0)

    def add_press(self, intervals, device: str = "") -> None:
        """One device's presses, (begin, end) [s] on the host's clock (time.perf_counter)."""
        intervals = [(b - self.t0, e - self.t0) for b, e in intervals]
        with self._lock:
            self.press_s += union_length(intervals)
            self.pressing += intervals
            if intervals:
                span = self.device_spans.get(device, (math.inf, -math.inf))
                self.device_spans[device] = (min(span[0], *(b for b, _ in intervals)), max(span[1], *(e for _, e in intervals)))

    def timeline(self, wall_s: float) -> dict:
        """When the devices pressed [s]: the first press's start, the idle time between the first and the
        last press (no device pressing), and the time after the last press to `wall_s`."""
        if not self.pressing:
            return {}
        first, last = min(b for b, _ in self.pressing), max(e for _, e in self.pressing)
        return {"before_first_press_s": first, "idle_between_presses_s": last - first - union_length(self.pressing),
                "after_last_press_s": wall_s - last}

    def table(self, wall_s: float) -> str:
        """The breakdown as lines of text: each phase, the press kernels and the rest of `wall_s` [s]."""
        rows = [(name, s) for name, s in self.seconds.items() if s > 0]
        rows.append(("press kernels (device)", self.press_s))
        lines = [f"{name:<26}{s:10.3f} s{100 * s / wall_s:7.1f} %" for name, s in rows]
        lines.append(f"{'wall':<26}{wall_s:10.3f} s  (host phases of several threads may overlap the press)")
        for name, s in self.timeline(wall_s).items():
            lines.append(f"{name[:-2].replace('_', ' '):<26}{s:10.3f} s{100 * s / wall_s:7.1f} %")
        if self.marks:
            lines.append("on the way to the first press: " + ", ".join(f"{name} {s:.3f} s" for name, s in sorted(self.marks.items(), key=lambda m: m[1])))
        if len(self.device_spans) > 1:
            lines.append("each device pressed: " + ", ".join(f"{d} {b:.3f}..{e:.3f} s" for d, (b, e) in sorted(self.device_spans.items())))
        if self.host_per_chunk:
            h = np.array(self.host_per_chunk)
            lines.append(f"host time per chunk: median {np.median(h) * 1e3:.1f} ms, max {h.max() * 1e3:.1f} ms ({len(h)} chunks)")
        return "\n".join(lines)

    def as_dict(self, wall_s: float) -> dict:
        """The breakdown in seconds, JSON keys with their unit."""
        out = {f"{name.replace(' ', '_').replace('-', '_')}_s": s for name, s in self.seconds.items()}
        return {**out, "press_kernels_s": self.press_s, "wall_s": wall_s, **self.timeline(wall_s)}


def union_length(intervals) -> float:
    """Total length of the union of (begin, end) intervals."""
    total, reach = 0.0, -math.inf
    for b, e in sorted(intervals):
        if e > reach:
            total += e - max(b, reach)
            reach = e
    return total
