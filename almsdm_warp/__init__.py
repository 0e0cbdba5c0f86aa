"""almsdm_warp: the alterable local mass-spring/damper model (ALMSDM) of soft tissue, on NVIDIA Warp.

SI units inside (m, kg, s, N); millimetres where people read (command line, JSON keys ending _mm).
"""

import os as _os

# In a source checkout that is not installed, almsdm_warp.kernels lives in ../kernels; an installed
# package has it inside (pyproject maps kernels/ to almsdm_warp.kernels). Map only that package.
def _map_source_kernels():
    import importlib.util
    import sys

    here = _os.path.dirname(_os.path.abspath(__file__))
    src = _os.path.join(_os.path.dirname(here), "kernels", "__init__.py")
    if _os.path.isdir(_os.path.join(here, "kernels")) or not _os.path.isfile(src):
        return
    spec = importlib.util.spec_from_file_location(__name__ + ".kernels", src)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)


_map_source_kernels()

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

    value = getattr(importlib.import_module(f"{__name__}.{_PUBLIC[name]}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_PUBLIC))
