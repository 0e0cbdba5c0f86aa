"""When an `almsdm` command's start-up steps happen: timestamps from this script's start around the
parser, Warp's start, the devices' start and the command, then the process's own start.

    python scripts/startup_timeline.py sweep paper_stomach --points 1000000 --device cuda:0 --out s.npz --profile

Runs the command in this process through the command line's main() (the same code as `almsdm`), and
prints the timeline to stderr when the interpreter exits (an atexit handler: this script calls
sys.exit, not the console script's fast exit, so the teardown that follows is not in it; time the
whole process from the shell for that). The command's own output is unchanged.
"""

import atexit
import importlib
import os
import sys
import threading
import time

T0 = time.perf_counter()
EVENTS = []


def event(name):
    EVENTS.append((time.perf_counter() - T0, threading.current_thread().name, name))


def since_exec():
    """Seconds from the process's start (from /proc) to this script's, or None off Linux."""
    try:
        with open("/proc/self/stat") as f:
            ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            up = float(f.read().split()[0])
    except OSError:
        return None
    return up - ticks / os.sysconf("SC_CLK_TCK") - (time.perf_counter() - T0)


def timed(module, name):
    m = importlib.import_module(module)
    f = getattr(m, name)

    def wrapper(*args, **kw):
        event(f"{name} begins")
        try:
            return f(*args, **kw)
        finally:
            event(f"{name} ends")

    setattr(m, name, wrapper)
    return f, wrapper


def report():
    event("exit")
    start = since_exec()
    if start is not None:
        print(f"# the process started {start * 1e3:.0f} ms before this script", file=sys.stderr)
    for t, thread, name in EVENTS:
        print(f"# {t * 1e3:9.1f} ms  {thread:16s} {name}", file=sys.stderr)


def main(argv):
    event("script starts")
    for module, name in (("almsdm_warp.warp_init", "init_warp"), ("almsdm_warp.warp_init", "start_devices"),
                         ("almsdm_warp.cli.main", "build_parser")):
        timed(module, name)
    command = argv[0] if argv else "palpate"
    cli = importlib.import_module(f"almsdm_warp.cli.{command}") if command in ("palpate", "sweep", "trace", "touch") else None
    if cli is not None:  # the command's function, as its parser's default names it
        original, wrapped = timed(cli.__name__, f"cmd_{command}")
        add_parser = cli.add_parser

        def add(sub):
            add_parser(sub)
            for p in sub.choices.values():
                if p.get_default("func") is original:
                    p.set_defaults(func=wrapped)

        cli.add_parser = add
    from almsdm_warp.cli.main import main as cli_main

    event("imports done")
    atexit.register(report)
    code = cli_main(argv)
    event("main returns")
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
