"""The `almsdm` command line. Bad input ends with one line on stderr and exit code 2.

Commands: ``palpate`` (the default: press the probe into a scene, report force, recovery and
speed), ``touch`` (print the ring regions at the contact), ``sweep``, ``bench`` and ``evaluate``.
Each command's module adds its parser (``add_parser``) and runs it; this one only dispatches.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import InputError
from . import bench, evaluate, palpate, sweep, touch
from .args import Parser

EXIT_BAD_INPUT = 2

SUBCOMMANDS = {"touch": touch, "palpate": palpate, "evaluate": evaluate, "sweep": sweep, "bench": bench}
"""Command name -> its module, in the order `almsdm --help` lists them."""
COMMANDS = ("palpate", "touch", "evaluate", "sweep", "bench")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="almsdm", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", parser_class=Parser)
    for module in SUBCOMMANDS.values():
        module.add_parser(sub)
    return parser


def _default_command(argv) -> bool:
    """True when argv names no command but is meant for palpate: nothing, an option first, or a
    scene or mesh first (a path, a file name, a shipped scene's name); `almsdm frobnicate` is not."""
    if not argv:
        return True
    first = argv[0]
    if first in COMMANDS or first in ("-h", "--help"):
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
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if _default_command(argv):
        argv = ["palpate", *argv]  # `almsdm`, `almsdm --depth-mm 5`, `almsdm liver`, `almsdm my.obj`
    try:
        args = parser.parse_args(argv)
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
    except KeyboardInterrupt:
        print("almsdm: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
