"""Tissue laws, one file each: the `wp.func`s a step kernel composes (kernels/laws/springs.py says which).

A kernel factory (kernels/explicit, kernels/implicit) takes a law from LAWS and builds its kernels
from the law's functions; the host's entry for the law (almsdm_warp/tissue/laws.py) adds its
critical step and its stiffness bound.
"""

from . import corotational, neo_hookean, springs

LAWS = {"springs": springs, "neo-hookean": neo_hookean, "corotational": corotational}
"""Law name -> its module of kernel functions (vertex_force; implicit_row and static_row where the law
has them) and the types of its entries (ENTRY_TOPOLOGY, ENTRY_PARAMS, and the struct of the three,
Entries: what a step kernel takes)."""
