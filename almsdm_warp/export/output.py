"""Writing results: nothing half-written (a temporary file beside the target, then a rename)."""

from __future__ import annotations

import contextlib
import json
import os
import stat
import tempfile
from pathlib import Path

from ..errors import InputError


def check_regular(path) -> Path:
    """InputError when `path` exists and is not a regular file (a folder, a device such as
    /dev/null, a FIFO, a socket): a rename would replace it, so an output never goes there."""
    p = Path(path)
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError:
        return p
    except OSError as exc:
        raise InputError(f"{p}: cannot write: {exc.strerror or exc}") from exc
    if stat.S_ISDIR(mode):
        raise InputError(f"{p}: is a folder, not a file")
    if not stat.S_ISREG(mode):
        kind = "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else "not a regular file"
        raise InputError(f"{p}: is {kind}, not a regular file; outputs go only to regular files")
    return p


def check_writable(path) -> Path:
    """Fail early, before any work, when `path` cannot be written: it is not a regular file (a
    folder, a device, a FIFO), or its folder is missing or read-only."""
    p = check_regular(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"{p}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise InputError(f"{p}: folder {parent} is not writable")
    # os.access can say yes where creating a file fails (/proc, a read-only mount, a full disk,
    # another user's sticky folder): try it, and leave nothing behind
    discard(temp_path(p))
    return p


def temp_path(path, suffix: str = ".tmp") -> Path:
    """A new empty temporary file beside `path` (same folder, so the rename is atomic), for a
    writer that publishes it when complete (:func:`publish`) or removes it (:func:`discard`).
    Its name holds this process's id: the temporaries of `path` that a killed run left (their
    process gone) are removed here (remove_stale)."""
    p = Path(path)
    folder = p.parent if str(p.parent) else Path(".")
    remove_stale(p, suffix)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.{os.getpid()}.", suffix=suffix, dir=folder)
    except OSError as exc:
        raise InputError(f"{p}: cannot write in folder {folder}: {exc.strerror or exc}") from exc
    os.close(fd)
    return Path(tmp)


def remove_stale(path: Path, suffix: str) -> None:
    """Remove the temporaries of `path` (temp_path's names) whose process no longer runs: what a run
    killed outright (SIGKILL, a power cut) left, which no cleanup of its own could remove."""
    folder = path.parent if str(path.parent) else Path(".")
    prefix = f".{path.name}."
    try:
        names = [n for n in os.listdir(folder) if n.startswith(prefix) and n.endswith(suffix)]
    except OSError:
        return
    for name in names:
        pid = name[len(prefix):].split(".", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _running(int(pid)):
            with contextlib.suppress(OSError):
                os.unlink(folder / name)


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process: running
        return True
    return True


def publish(tmp, path, sync: bool = True) -> Path:
    """Rename the finished temporary file `tmp` to `path`, its data on disk first (fsync; not where `sync`
    is False: a file whose loss to a power cut costs only its work again, a sweep's parts) and with the
    mode a new file gets (0o666 less the umask; mkstemp makes it owner-only)."""
    check_regular(path)  # something else may have taken the name since the check before the run
    if sync:
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(tmp, 0o666 & ~mask)
    os.replace(tmp, path)
    return Path(path)


def discard(tmp) -> None:
    """Remove an unfinished temporary file (nothing if it is gone already)."""
    Path(tmp).unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_path(path, suffix: str = ".tmp", sync: bool = True):
    """Yield a temporary file's path beside `path`; when the block ends without an error it is
    published to `path` (:func:`publish`, fsynced unless `sync` is False), otherwise removed: nothing is
    half-written. An OSError becomes an InputError that names `path`."""
    p = Path(path)
    tmp = temp_path(p, suffix)
    try:
        yield str(tmp)
        publish(tmp, p, sync)
    except BaseException as exc:
        discard(tmp)
        if isinstance(exc, OSError):
            raise InputError(f"{p}: cannot write: {exc.strerror or exc}") from exc
        raise


def atomic_write(path, write, sync: bool = True) -> Path:
    """Call ``write(tmp)`` to write a temporary file beside `path`, then publish it as `path` (publish's `sync`)."""
    with atomic_path(path, sync=sync) as tmp:
        write(tmp)
    return Path(path)


def atomic_write_text(path, text: str) -> Path:
    """Write `text` to `path` through a temporary file in the same folder and a rename."""
    p = check_writable(path)
    with atomic_path(p) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return p


def write_json(path, data) -> Path:
    """Write `data` as indented JSON, atomically."""
    return atomic_write_text(path, json.dumps(data, indent=2) + "\n")
