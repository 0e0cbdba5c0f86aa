"""A small carriage-return progress bar on stderr, for runs long enough to want one (no dependency).

It draws nothing until the run is expected to take more than `min_expected_s` seconds (judged from
the rate so far), redraws at most every `interval_s` seconds, and erases itself when closed on a
terminal (a stream that is not a terminal, with the bar forced on, gets a final newline instead),
so the lines a program prints around it stay clean.
"""

from __future__ import annotations

import sys
import time


class Progress:
    """``with Progress(total, enabled=...) as bar: ... bar.advance()``; ``bar.label = "press 2/3"``."""

    def __init__(
        self,
        total: int,
        *,
        enabled: bool | None = None,
        stream=None,
        label: str = "",
        min_expected_s: float = 2.0,
        interval_s: float = 0.1,
        width: int = 30,
    ):
        """enabled: True (always, once the run is expected to be long), False (never), None (only
        when `stream` is a terminal). stream: default sys.stderr."""
        self.stream = sys.stderr if stream is None else stream
        if enabled is None:
            isatty = getattr(self.stream, "isatty", None)
            enabled = bool(isatty and isatty())
        self.enabled = bool(enabled)
        self.total = max(int(total), 1)
        self.label = label
        self.done = 0
        self.min_expected_s = float(min_expected_s)
        self.interval_s = float(interval_s)
        self.width = int(width)
        self.shown = False
        self._start = None
        self._next_draw = 0.0
        self._last_len = 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def advance(self, n: int = 1) -> None:
        """Count `n` units of work done; cheap (one clock read) unless it is time to redraw."""
        self.done += n
        if not self.enabled:
            return
        now = time.perf_counter()
        if self._start is None:
            # the clock starts at the first unit done, so one-off start-up costs (kernel
            # compilation) do not inflate the estimate of the remaining time
            self._start = now
            self._start_done = self.done
            self._next_draw = now + self.interval_s
            return
        if now < self._next_draw:
            return
        self._next_draw = now + self.interval_s
        if not self.shown:
            elapsed = now - self._start
            counted = self.done - self._start_done
            if elapsed < 0.25 or counted <= 0:
                return
            expected = elapsed / counted * (self.total - self._start_done)
            if expected < self.min_expected_s:
                return
            self.shown = True
        self._draw(now)

    def _draw(self, now: float) -> None:
        frac = min(self.done / self.total, 1.0)
        filled = int(round(frac * self.width))
        bar = "#" * filled + "." * (self.width - filled)
        text = f"{self.label} [{bar}] {frac * 100:3.0f}%"
        counted = self.done - self._start_done
        if counted > 0 and self.done < self.total:
            left = (now - self._start) / counted * (self.total - self.done)
            text += f"  {left:.0f} s left" if left >= 10 else f"  {left:.1f} s left"
        pad = " " * max(self._last_len - len(text), 0)
        self._last_len = len(text)
        try:
            self.stream.write("\r" + text + pad)
            self.stream.flush()
        except (OSError, ValueError):  # a closed or broken stream: stop drawing
            self.enabled = False

    def close(self) -> None:
        """Erase the bar on a terminal, or end its line elsewhere; nothing if it never showed."""
        if not self.shown:
            return
        self.shown = False
        try:
            isatty = getattr(self.stream, "isatty", None)
            if isatty and isatty():
                self.stream.write("\r" + " " * self._last_len + "\r")
            else:
                self.stream.write("\n")
            self.stream.flush()
        except (OSError, ValueError):
            pass
