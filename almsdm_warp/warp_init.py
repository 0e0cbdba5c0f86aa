"""Initialize Warp once, quietly: no banner, and no C-level warning about a missing CUDA driver
(the CPU device needs none); anything else Warp prints at start-up is kept."""

from __future__ import annotations

import os
import sys
import tempfile

_NO_DRIVER = "Could not find or load the NVIDIA CUDA driver"


def init_warp(quiet: bool = True) -> None:
    import warp as wp

    if quiet:
        wp.config.log_level = wp.LOG_WARNING
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no stderr to redirect
        wp.init()
        return
    with tempfile.TemporaryFile(mode="w+b") as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        for line in captured.read().decode(errors="replace").splitlines():
            if line.strip() and _NO_DRIVER not in line:
                print(line, file=sys.stderr)
