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

from .region.contact import ContactQuery, Contacts, find_contacts  # noqa: E402
from .mesh.device_mesh import DeviceMesh  # noqa: E402
from .errors import InputError  # noqa: E402
from .mesh.io import load_mesh  # noqa: E402
from .mesh.tissue_mesh import TissueMesh  # noqa: E402
from .region.region import Region, ring_distances  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "ContactQuery",
    "Contacts",
    "DeviceMesh",
    "InputError",
    "Region",
    "TissueMesh",
    "find_contacts",
    "load_mesh",
    "ring_distances",
]
