"""Writing results: nothing half-written (a temporary file beside the target, then a rename)."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from .errors import InputError


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


def atomic_write_text(path, text: str) -> Path:
    """Write `text` to `path` through a temporary file in the same folder and a rename."""
    p = check_writable(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent if str(p.parent) else ".")
    except OSError as exc:
        raise InputError(f"{p}: cannot write in folder {p.parent}: {exc.strerror or exc}") from exc
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, p)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError):
            raise InputError(f"{p}: cannot write: {exc.strerror or exc}") from exc
        raise
    return p


def write_json(path, data) -> Path:
    """Write `data` as indented JSON, atomically."""
    return atomic_write_text(path, json.dumps(data, indent=2) + "\n")
