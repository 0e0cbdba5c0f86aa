"""The `almsdm` command line. Bad input ends with one line on stderr and exit code 2; Ctrl-C
(SIGINT) and SIGTERM end with one line and exit code 130 or 143 (128 + the signal, as a shell
reports a process the signal ended), every temporary file removed on the way out.

Commands: ``palpate`` (the default: press the probe into a scene, report force, recovery and
speed), ``touch`` (print the ring regions at the contact), ``sweep``, ``trace`` (a probe moved along a
path), ``bench`` and ``evaluate``.
Each command's module adds its parser (``add_parser``) and runs it; this one only dispatches.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import threading

from ..errors import InputError

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 128 + signal.SIGINT
"""130: Ctrl-C."""
EXIT_TERMINATED = 128 + signal.SIGTERM
"""143: SIGTERM (a batch system's or `kill`'s request to stop)."""

COMMANDS = ("palpate", "touch", "evaluate", "sweep", "trace", "bench")
"""The subcommands, each a module of this package with add_parser(sub), in the order `almsdm --help` lists them."""
OUTPUTS = ("json", "usd", "png", "out")
"""The arguments that name an output file (as argparse stores them); checked to be distinct."""
INPUTS = ("scene", "mesh", "extra_json", "path_csv")
"""The arguments that name an input file, which no output may replace."""
FOLDER_OUTPUTS = {"evaluate": ("out",)}
"""Outputs that are folders, not files: left out of the distinct-file check."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is, so that it unwinds as Ctrl-C does: every writer's
    cleanup (export.output.atomic_path, the USD recorder, a sweep's chunks) runs, nothing is left half-written."""


_TERMS = []
"""SIGTERMs received during the current run (a command that catches the interrupt itself, as a
sweep does to say where its chunks are, returns 130; main makes that 143 when SIGTERM it was)."""


def _terminate(signum, frame):
    _TERMS.append(signum)
    raise Terminated()


@contextlib.contextmanager
def signals_as_interrupts():
    """While the command runs, SIGTERM raises Terminated, and SIGINT KeyboardInterrupt (Python's
    default, set again in case the caller changed it), unless ignored when the command starts.
    Only the main thread can take signals."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    # a signal ignored when we start stays ignored (`nohup`, a shell's background job: SIGINT)
    wanted = ((signal.SIGTERM, _terminate), (signal.SIGINT, signal.default_int_handler))
    old = {s: signal.signal(s, h) for s, h in wanted if signal.getsignal(s) is not signal.SIG_IGN}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


SHIELDED_USD_IMPORTS = ("pxr.Tf", "pxr.Sdf", "pxr.Usd", "pxr.UsdGeom", "pxr.Vt")
"""With --usd, usd-core's modules, imported at start-up with signals held: its import turns an interrupt
into a warning and goes on. (trimesh, which swallows one in its import of scipy, is imported where it is
needed, on a thread of its own: mesh.io.import_trimesh.)"""


@contextlib.contextmanager
def signals_held():
    """SIGINT and SIGTERM that arrive in the block are held, and raised as soon as it ends."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held = []
    old = {s: signal.signal(s, lambda signum, frame: held.append(signum))
           for s in (signal.SIGINT, signal.SIGTERM) if signal.getsignal(s) is not signal.SIG_IGN}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if held:
        if held[0] == signal.SIGTERM:
            _terminate(signal.SIGTERM, None)
        raise KeyboardInterrupt


def require_usd() -> None:
    """InputError, one line, where --usd is asked for and usd-core (the `usd` extra) is not installed."""
    import importlib.util

    if importlib.util.find_spec("pxr") is None:
        raise InputError("--usd records a USD stage, which needs usd-core: pip install 'almsdm_warp[usd]'")


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__
    from .args import Parser

    parser = Parser(prog="almsdm", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"almsdm {__version__}")
    sub = parser.add_subparsers(dest="command", parser_class=Parser)
    for name in COMMANDS:
        importlib.import_module(f"{__package__}.{name}").add_parser(sub)
    for command in sub.choices.values():
        command.add_argument("--verbose", action="store_true", help="show Warp's own messages: its banner, module loads, "
                             "warnings (also ALMSDM_VERBOSE=1); without it every error is one line")
    return parser


def check_paths(args) -> None:
    """Before any work: no two outputs on one file, no output onto an input."""
    from ..export.writers import check_distinct

    folders = FOLDER_OUTPUTS.get(args.command, ())
    outputs = {f"--{a.replace('_', '-')}": getattr(args, a, None) for a in OUTPUTS if a not in folders}
    inputs = {a.replace("_", "-"): getattr(args, a, None) for a in INPUTS}
    check_distinct(outputs, inputs)


def _default_command(argv) -> bool:
    """True when argv names no command but is meant for palpate: nothing, an option first, or a
    scene or mesh first (a path, a file name, a shipped scene's name); `almsdm frobnicate` is not."""
    if not argv:
        return True
    first = argv[0]
    if first in COMMANDS or first in ("-h", "--help", "--version"):
        return False
    if first.startswith("-") or "/" in first or "\\" in first or "." in first:
        return True
    from pathlib import Path

    from ..scene.loader import scene_names

    try:
        return Path(first).exists() or first in scene_names()
    except (InputError, OSError):
        return False


def main(argv=None) -> int:
    _TERMS.clear()
    with signals_as_interrupts():
        try:
            code = _run(argv)
            return EXIT_TERMINATED if code == EXIT_INTERRUPTED and _TERMS else code
        except Terminated:
            print("almsdm: terminated", file=sys.stderr)
            return EXIT_TERMINATED
        except KeyboardInterrupt:
            print("almsdm: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED


def _start_warp(args) -> None:
    """Warp initialized once, before any command touches it: quiet unless --verbose or ALMSDM_VERBOSE=1."""
    from ..warp_init import init_warp, verbose

    with signals_held():
        init_warp(quiet=not (getattr(args, "verbose", False) or verbose()))


def _start_imports(names, device) -> None:
    """Import `names` (modules a command needs before its first result) on a thread of their own, begun
    before Warp's start, where `device` (a --device value) names a GPU: their import (scipy.spatial and
    scipy.sparse.linalg, 0.4-0.7 s each on an H200 host) overlaps Warp's native start (its libraries and
    the CUDA driver), and whoever imports them later waits only for what is left. Not for the CPU, where
    on two cores it made a sweep no shorter (six alternations each way)."""
    from ..warp_init import names_a_gpu

    if names and names_a_gpu(device):
        def imports():
            for name in names:
                try:
                    importlib.import_module(name)
                except Exception:  # noqa: BLE001 (the import where the module is needed says what is wrong, once)
                    return

        threading.Thread(target=imports, name="imports", daemon=True).start()


def _run(argv) -> int:
    try:
        argv = list(sys.argv[1:] if argv is None else argv)
        if _default_command(argv):
            argv = ["palpate", *argv]  # `almsdm`, `almsdm --depth-mm 5`, `almsdm liver`, `almsdm my.obj`
        args = build_parser().parse_args(argv)
        _start_imports(getattr(args, "preload", ()), getattr(args, "device", None))
        _start_warp(args)
        if getattr(args, "start_devices", False):  # their contexts start while the imports below run
            from ..warp_init import start_devices

            start_devices(getattr(args, "device", None))
        if getattr(args, "usd", None):
            require_usd()
        with signals_held():
            for name in SHIELDED_USD_IMPORTS if getattr(args, "usd", None) else ():
                importlib.import_module(name)
        check_paths(args)
        return args.func(args)
    except InputError as exc:
        message = " ".join(str(exc).split())  # one line, whatever the message holds
        print(f"almsdm: error: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:  # the reader of our output went away (`almsdm ... | head`): not an error
        sys.stderr.close()  # nothing more can be said, and Python's exit flush must not complain
        return 0
    except OSError as exc:  # the file system refused a path given (a name too long, a loop of links, ...)
        name = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"almsdm: error: {name}{exc.strerror or ' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_BAD_INPUT


def run() -> None:
    """The console script `almsdm` and `python -m almsdm_warp.cli.main`: main(), then the process ends
    at once where nothing is left to finish (fast_exit). The Python API calls main(), which returns."""
    code = main()
    fast_exit(code)
    sys.exit(code)


def fast_exit(code: int) -> None:
    """End the process now with exit status `code` (os._exit), stdout and stderr flushed, skipping the
    interpreter's teardown: after a 1M-point sweep on an H100 host, 0.35-0.44 s of a 3.4 s process (its
    modules, Warp's arrays and kernel modules, the CUDA context; docs/performance.md, "Start-up"). Every
    file a command writes is closed before main() returns. Not where something may still need the
    teardown: a thread other than the daemons still running, Ray (its exit stops the local cluster),
    a profiler or tracer (cProfile writes its file at exit); then it returns and the caller exits as usual."""
    if watched() or "ray" in sys.modules:
        return
    if any(t.is_alive() and not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
        return
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):  # a closed or broken stream: let the usual exit deal with it
        return
    os._exit(code)


def watched() -> bool:
    """Whether a profiler, tracer, debugger or coverage tool watches the process (sys.setprofile, sys.settrace,
    or from Python 3.12 a sys.monitoring tool: cProfile's there)."""
    monitoring = getattr(sys, "monitoring", None)
    tools = [monitoring.get_tool(i) for i in range(6)] if monitoring is not None else []
    return sys.getprofile() is not None or sys.gettrace() is not None or any(t is not None for t in tools)


if __name__ == "__main__":
    run()
