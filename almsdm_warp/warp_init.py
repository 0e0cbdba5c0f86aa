"""Initialize Warp once, quietly: no banner, no module-load lines, no Warp warning (a CUDA driver the
CPU device does not need, say), unless asked for with ALMSDM_VERBOSE=1 (or the command line's
--verbose): the command line's every error is then one line, and the Python API prints nothing."""

from __future__ import annotations

import os
import sys
import tempfile

VERBOSE_ENV = "ALMSDM_VERBOSE"
"""Set to 1 to see Warp's banner, module loads and warnings (the command line's --verbose sets it)."""


def verbose() -> bool:
    """True when ALMSDM_VERBOSE asks for Warp's own messages (1, true, yes)."""
    return os.environ.get(VERBOSE_ENV, "").strip().lower() in ("1", "true", "yes")


def init_warp(quiet: bool | None = None) -> None:
    """Initialize Warp (once: later calls do nothing). Quiet (the default, unless verbose()): Warp's
    log level is set to errors only and what its native library prints to stderr while it starts is
    dropped. A Warp the caller started already keeps its own settings."""
    import warp as wp
    import warp._src.context as wpc

    if wpc.runtime is not None:
        return
    if quiet is None:
        quiet = not verbose()
    if quiet:
        wp.config.log_level = wp.LOG_ERROR
    sys.stderr.flush()
    try:
        saved = os.dup(2) if quiet else None
    except OSError:  # no stderr to redirect
        saved = None
    if saved is None:
        wp.init()
        return
    with tempfile.TemporaryFile(mode="w+b") as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)


_device_start = []  # the threads of start_devices, while they run


def device_names(spec: str | None) -> list[str]:
    """The names in a --device value (cpu, cuda:N, a comma list, or all), stripped."""
    return [n.strip() for n in (spec or "").split(",") if n.strip()]


def names_a_gpu(spec: str | None) -> bool:
    """Whether a --device value names a CUDA device (cuda:N or all)."""
    return any(n == "all" or n.startswith("cuda") for n in device_names(spec))


def start_devices(spec: str | None) -> None:
    """Start the CUDA contexts that `spec` (a --device value: cpu, cuda:N, a comma list, or all) names
    on threads of their own, one a device: a context takes 0.12-0.15 s on an H200 the first time, which
    the caller's imports and mesh reading then overlap, and two devices' start at once. Warp is initialized
    here first (init_warp). Code that makes CUDA arrays of those devices calls devices_started() first
    (two threads must not start one context at once). A bad name is left to the command, which says what
    is wrong with it."""
    import threading

    names = device_names(spec)
    if not names_a_gpu(spec):
        return
    init_warp()
    import warp as wp

    devices = wp.get_cuda_devices() if "all" in names else []
    for name in names if "all" not in names else ():
        try:
            devices += [wp.get_device(name)] if name.startswith("cuda") else []
        except Exception:  # noqa: BLE001 (the command reports a bad --device)
            pass

    def start(device):
        try:
            device.context  # noqa: B018 (the property starts the context)
        except Exception:  # noqa: BLE001 (the command reports a device that does not start)
            pass

    for device in {d.alias: d for d in devices}.values():  # a device named twice starts once
        thread = threading.Thread(target=start, args=(device,), name=f"device-start-{device}", daemon=True)
        thread.start()
        _device_start.append(thread)


def devices_started() -> None:
    """Wait for start_devices' threads, if any run."""
    for thread in list(_device_start):
        thread.join()
