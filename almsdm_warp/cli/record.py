"""`almsdm palpate --usd out.usda|.usdc --usd-every N --png out.png [--png-at-s S]`: record the presses.

USD (usd-core) and the picture (matplotlib) are imported only when asked for; without these flags
the presses run exactly as before (no per-step hook).
"""

from __future__ import annotations

from ..errors import InputError
from .args import count_arg, number_arg


def add_record_args(parser) -> None:
    """The recording flags of `palpate`."""
    g = parser.add_argument_group("recording")
    g.add_argument("--usd", default=None, metavar="PATH", help="record the presses to a USD stage (.usda text, .usdc or .usd crate)")
    g.add_argument("--usd-every", type=count_arg, default=1, metavar="N", help="record every Nth step (default 1)")
    g.add_argument("--normals", choices=("global", "search", "precomputed"), default="precomputed", help="how the recorded normals are updated (default precomputed: the region's vertices from the vertex-to-face incidence)")
    g.add_argument("--png", default=None, metavar="PATH", help="draw one frame to a PNG: displacement, region outline, probe")
    g.add_argument("--png-at-s", type=number_arg(">= 0"), default=None, metavar="S", help="time of that frame [s] from the first step (default: the end of the first press's hold, the deepest)")


def check_record_args(args) -> None:
    """Fail before any work when a recording path is unusable (suffix, folder)."""
    from ..export.writers import check_output

    if args.usd:
        check_output(args.usd, "stage", "--usd")
    if args.png:
        check_output(args.png, "image", "--png")
    elif args.png_at_s is not None:
        raise InputError("--png-at-s needs --png")


class Recording:
    """The `record` hook of Palpation.press for the command line: USD frames and one PNG snapshot.

    press_steps: steps of one press; deepest_step: the default PNG step (end of the first hold).
    """

    def __init__(self, args, pal, presses: int, press_steps: int, deepest_step: int, label: str):
        self.args, self.pal, self.label = args, pal, label
        self.total = presses * press_steps
        self.usd = None
        self.png_step = None
        self.snapshot = None
        self._base = 0
        if args.png:
            if args.png_at_s is not None and args.png_at_s > self.total * pal.dt:  # in seconds: 1e308 / dt overflows
                raise InputError(f"--png-at-s {args.png_at_s:g} is after the last step ({self.total * pal.dt:g} s)")
            step = deepest_step if args.png_at_s is None else min(int(round(args.png_at_s / pal.dt)), self.total)
            self.png_step = step
        if args.usd:
            from ..export.usd import UsdRecorder

            self.usd = UsdRecorder(args.usd, pal, every=args.usd_every, normals=args.normals)
            self.usd.frame(0)
        if self.png_step == 0:
            self._snap(0)

    @property
    def active(self) -> bool:
        return self.usd is not None or self.png_step is not None

    def press_kwargs(self) -> dict:
        """Keyword arguments for Palpation.press: the hook, called every step only for a PNG."""
        if not self.active:
            return {}
        every = 1 if self.png_step is not None else self.args.usd_every
        return {"record": self._record, "record_every": every}

    def _record(self, k, total):
        step = self._base + k
        if self.usd is not None and (k % self.args.usd_every == 0 or k == total):
            self.usd.on_press_step(k, total)
        if step == self.png_step:
            self._snap(step)
        if k == total:
            self._base += total

    def _snap(self, step):
        from ..export.preview import Snapshot

        self.snapshot = Snapshot.of(self.pal, step * self.pal.dt)

    def finish(self) -> list[str]:
        """Close the stage and draw the picture; returns the lines to print."""
        lines = []
        if self.usd is not None:
            usd, self.usd = self.usd, None
            frames = usd.frames
            path = usd.close()
            lines.append(f"wrote {path} ({frames} frames, every {self.args.usd_every} steps)")
        if self.png_step is not None:
            from ..export.preview import render_png

            render_png(self.args.png, self.pal.mesh, self.snapshot, title=self.label)
            t = self.png_step * self.pal.dt
            lines.append(f"wrote {self.args.png} (t = {t:.3f} s)")
        return lines

    def discard(self) -> None:
        """Remove the unfinished stage (an error or an interrupt)."""
        if self.usd is not None:
            self.usd.__exit__(RuntimeError, None, None)
            self.usd = None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None:
            self.discard()
        return False
