"""Shared pieces of the fuzz tests: hypothesis settings, file corruptions, and a checked CLI run.

CI runs a short, derandomized set of examples (reproducible); a campaign runs many more,
randomized, when ALMSDM_FUZZ_SCALE is set (an integer factor on every test's example count):

    ALMSDM_FUZZ_SCALE=50 ALMSDM_FUZZ_LOG=/tmp/fuzz.jsonl python -m pytest -q tests/test_fuzz_*.py

ALMSDM_FUZZ_LOG appends one JSON line per example (test, case, outcome, first words of the
message); `python scripts/fuzz_table.py /tmp/fuzz.jsonl` makes the table in docs/reliability.md.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import signal
from pathlib import Path

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

SCALE = int(os.environ.get("ALMSDM_FUZZ_SCALE", "0") or 0)
LOG = os.environ.get("ALMSDM_FUZZ_LOG")
HANG_S = 120
"""An example that runs longer than this is a hang (a failure), not a slow result."""
FUZZ_MAX_STEPS = 20_000
"""The command line's step limit while fuzzing (LIMITS["steps"] is 1e7): a drawn --hold-s 5000 on the
global implicit model is a legitimate hour-long run, not a hang; the same limit check refuses it."""


def fuzz_settings(examples: int):
    """CI: `examples`, derandomized (the same cases every run). Campaign: examples x SCALE, random."""
    return settings(
        max_examples=examples * SCALE if SCALE else examples,
        deadline=None,
        derandomize=not SCALE,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large],
    )


def record(test: str, case: str, outcome: str, message: str = "") -> None:
    """One line of the campaign log (no-op without ALMSDM_FUZZ_LOG)."""
    if not LOG:
        return
    head = re.sub(r"\S{41,}", "…", re.sub(r"/\S*/", "…/", " ".join(message.split())))[:160]
    with open(LOG, "a", encoding="utf-8") as f:
        f.write(json.dumps({"test": test, "case": case, "outcome": outcome, "message": head}) + "\n")


class Hang(AssertionError):
    """A run past HANG_S (not a TimeoutError: that is an OSError, which the command line turns
    into one line and exit code 2, and the hang would pass for a clear error)."""


@contextlib.contextmanager
def hang_guard(seconds: int = HANG_S):
    """Fail (Hang) instead of hanging when the body runs longer than `seconds`."""

    def alarm(signum, frame):
        raise Hang(f"no result within {seconds} s: a hang")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


# -- the command line, in-process ------------------------------------------------------------
def run_main(argv, fuzz_limits=False):
    """almsdm_warp.cli.main.main(argv) with stdout and stderr captured: (exit code, stdout, stderr).
    fuzz_limits: run under FUZZ_MAX_STEPS.

    Any exception that escapes main() is a bug (a traceback for the user): it propagates."""
    from unittest import mock

    from almsdm_warp.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    limit = mock.patch.dict("almsdm_warp.checks.LIMITS", steps=FUZZ_MAX_STEPS) if fuzz_limits else contextlib.nullcontext()
    with hang_guard(), limit, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def check_outcome(code, out, err, json_path=None, folder=None):
    """Either a result (0) or one clear line on stderr and exit code 2; never a traceback, and
    never a half-written output: the JSON is complete when written, absent otherwise, and
    `folder` holds no temporary file. Returns "ok" or "error"."""
    assert "Traceback" not in err and "Traceback" not in out, err
    if code == 0:
        if json_path is not None:
            json.loads(Path(json_path).read_text())  # complete and parseable
        outcome = "ok"
    else:
        assert code == 2, (code, err)
        lines = [ln for ln in err.splitlines() if not ln.startswith("note: ")]
        assert len(lines) == 1 and lines[0].startswith("almsdm: error: "), err
        assert len(lines[0]) > len("almsdm: error: ") + 5, err
        if json_path is not None:
            try:
                written = Path(json_path).is_file()
            except OSError:  # a name too long to exist
                written = False
            assert not written, f"{json_path} written by a run that failed"
        outcome = "error"
    if folder is not None:
        leftovers = [p.name for p in Path(folder).iterdir() if p.name.endswith(".tmp")]
        assert not leftovers, leftovers
    return outcome


# -- corrupting a file ------------------------------------------------------------------------
NUMBER = re.compile(rb"(?<![\w.])[-+]?\d+(\.\d*)?([eE][-+]?\d+)?(?![\w.])")
BAD_NUMBERS = [b"nan", b"NaN", b"inf", b"-inf", b"1e400", b"-1e39", b"3.4e38", b"1e-320", b"0", b"-1", b"2147483648",
               b"99999999999999999999", b"1.5", b"", b"x", b"0x10"]
CORRUPTIONS = ("truncate", "garbage", "number", "delete_line", "duplicate_line", "swap_suffix", "empty", "binary_noise")


@st.composite
def corruptions(draw, data: bytes, suffixes):
    """(description, new bytes, new suffix or None) for one random corruption of `data`."""
    kind = draw(st.sampled_from(CORRUPTIONS))
    n = len(data)
    if kind == "truncate":
        k = draw(st.integers(0, max(n - 1, 0)))
        return f"truncate at byte {k} of {n}", data[:k], None
    if kind == "garbage":
        at = draw(st.integers(0, max(n - 1, 0)))
        junk = draw(st.binary(min_size=1, max_size=64))
        return f"{len(junk)} garbage bytes at {at}", data[:at] + junk + data[at + len(junk):], None
    if kind == "binary_noise":
        junk = draw(st.binary(min_size=1, max_size=2048))
        return f"{len(junk)} random bytes", junk, None
    if kind == "number":
        spans = [m.span() for m in NUMBER.finditer(data[:200_000])]
        if not spans:
            return "no number to replace", data, None
        count = draw(st.integers(1, 3))
        out = data
        what = []
        for _ in range(count):
            i = draw(st.integers(0, len(spans) - 1))
            new = draw(st.sampled_from(BAD_NUMBERS))
            a, b = spans[i]
            if b <= len(out):
                what.append(f"{out[a:b].decode(errors='replace')}->{new.decode()}")
                out = out[:a] + new + out[b:]
                shift = len(new) - (b - a)
                spans = [(x + shift, y + shift) if x >= b else (x, y) for x, y in spans if (x, y) != (a, b)]
                if not spans:
                    break
        return "number " + ", ".join(what), out, None
    lines = data.split(b"\n")
    if kind == "delete_line":
        i = draw(st.integers(0, len(lines) - 1))
        return f"delete line {i + 1}", b"\n".join(lines[:i] + lines[i + 1:]), None
    if kind == "duplicate_line":
        i = draw(st.integers(0, len(lines) - 1))
        return f"duplicate line {i + 1}", b"\n".join(lines[: i + 1] + lines[i:]), None
    if kind == "swap_suffix":
        suffix = draw(st.sampled_from(sorted(suffixes)))
        return f"same bytes as {suffix}", data, suffix
    return "empty", b"", None
