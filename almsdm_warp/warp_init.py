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


_device_start = None  # the thread of start_devices, while it runs


def start_devices(spec: str | None) -> None:
    """Start the CUDA contexts that `spec` (a --device value: cpu, cuda:N, a comma list, or all) names
    on a thread of its own: a context takes 0.12-0.15 s on an H200 the first time, which the caller's
    imports and mesh reading then overlap. Warp is initialized here first (init_warp). Code that
    makes CUDA arrays of those devices calls devices_started() first (two threads must not start a
    context at once). A bad name is left to the command, which says what is wrong with it."""
    global _device_start
    import threading

    names = [n.strip() for n in (spec or "").split(",") if n.strip()]
    if not any(n == "all" or n.startswith("cuda") for n in names):
        return
    init_warp()

    def start():
        import warp as wp

        try:
            devices = wp.get_cuda_devices() if "all" in names else [wp.get_device(n) for n in names if n.startswith("cuda")]
            for device in devices:
                device.context  # noqa: B018 (the property starts the context)
        except Exception:  # noqa: BLE001 (the command reports a bad --device)
            pass

    _device_start = threading.Thread(target=start, name="device-start", daemon=True)
    _device_start.start()


def devices_started() -> None:
    """Wait for start_devices' thread, if one runs."""
    if _device_start is not None:
        _device_start.join()
