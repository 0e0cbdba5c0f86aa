"""Tissue laws, one file each: the `wp.func`s a step kernel composes (kernels/laws/springs.py says which).

A kernel factory (kernels/explicit, kernels/implicit) takes a law from LAWS and builds its kernels
from the law's functions; the host's entry for the law (almsdm_warp/tissue/laws.py) adds its
critical step and its stiffness bound.
"""

from . import springs

LAWS = {"springs": springs}
"""Law name -> its module of kernel functions (vertex_force, implicit_row)."""
