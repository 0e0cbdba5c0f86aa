"""almsdm_warp: the alterable local mass-spring/damper model (ALMSDM) of soft tissue, on NVIDIA Warp.

SI units inside (m, kg, s, N); millimetres where people read (command line, JSON keys ending _mm).
"""

# almsdm_warp.kernels is the top-level kernels/ folder: installed there by pyproject's package-dir,
# and in a source checkout reached through the link almsdm_warp/kernels -> ../kernels, so that
# Python, editors and import tools all see the kernels' modules where the host imports them.

# The public names, each from the module that defines it; imported when first used (PEP 562), so
# that `import almsdm_warp` (and the command line's start, which must answer Ctrl-C at once) does
# not load Warp before it is needed.
_PUBLIC = {
    "BatchPalpation": "batch.batch_palpation",
    "ContactQuery": "region.contact",
    "Contacts": "region.contact",
    "DeviceMesh": "mesh.device_mesh",
    "InputError": "errors",
    "Material": "tissue.material",
    "Model": "sim.model",
    "Palpation": "protocol.palpation",
    "PressResult": "protocol.palpation",
    "PROBE_DISPLACEMENT": "sim.model",
    "PROBE_FORCE": "sim.model",
    "PROBE_OFF": "sim.model",
    "PRESETS": "tissue.presets",
    "Scene": "scene.loader",
    "TissuePreset": "tissue.presets",
    "load_scene": "scene.loader",
    "palpation": "scene.press",
    "resolve_scene_or_mesh": "scene.loader",
    "tissue_preset": "tissue.presets",
    "Region": "region.region",
    "TissueMesh": "mesh.tissue_mesh",
    "TissueParams": "tissue.params",
    "find_contacts": "region.contact",
    "load_mesh": "mesh.io",
    "ring_distances": "region.region",
}

__version__ = "0.1.0"

__all__ = sorted(_PUBLIC)


def __getattr__(name):
    if name not in _PUBLIC:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    if _PUBLIC[name] != "errors":  # Warp started quietly (warp_init: ALMSDM_VERBOSE=1 shows its messages)
        from .warp_init import init_warp

        init_warp()
    value = getattr(importlib.import_module(f"{__name__}.{_PUBLIC[name]}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_PUBLIC))
