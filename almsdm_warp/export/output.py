"""Writing results: nothing half-written (a temporary file beside the target, then a rename)."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

from ..errors import InputError


def check_writable(path) -> Path:
    """Fail early, before any work, when `path` cannot be written: its folder is missing or read-only."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if p.is_dir():
        raise InputError(f"{p}: is a folder, not a file")
    if not parent.is_dir():
        raise InputError(f"{p}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise InputError(f"{p}: folder {parent} is not writable")
    # os.access can say yes where creating a file fails (/proc, a read-only mount, a full disk,
    # another user's sticky folder): try it, and leave nothing behind
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=parent)
    except OSError as exc:
        raise InputError(f"{p}: cannot write in folder {parent}: {exc.strerror or exc}") from exc
    os.close(fd)
    os.unlink(tmp)
    return p


@contextlib.contextmanager
def atomic_path(path, suffix: str = ".tmp"):
    """Yield a temporary file's path beside `path`; when the block ends without an error it is
    renamed to `path` (with a new file's mode), otherwise removed: nothing is half-written."""
    p = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=suffix, dir=p.parent if str(p.parent) else ".")
    except OSError as exc:
        raise InputError(f"{p}: cannot write in folder {p.parent}: {exc.strerror or exc}") from exc
    os.close(fd)
    try:
        yield tmp
        publish(tmp, p)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise InputError(f"{p}: cannot write: {exc.strerror or exc}") from exc
        raise


def atomic_write_text(path, text: str) -> Path:
    """Write `text` to `path` through a temporary file in the same folder and a rename."""
    p = check_writable(path)
    with atomic_path(p) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return p


def write_json(path, data) -> Path:
    """Write `data` as indented JSON, atomically."""
    return atomic_write_text(path, json.dumps(data, indent=2) + "\n")


def publish(tmp, path) -> Path:
    """Rename the finished temporary file `tmp` to `path`, with the mode a new file gets (umask
    applied; mkstemp makes it owner-only)."""
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(tmp, 0o666 & ~mask)
    os.replace(tmp, path)
    return Path(path)
